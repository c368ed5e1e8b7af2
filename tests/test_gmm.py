"""Gaussian mixture EM (`dexjax.policy.gmm`) against scikit-learn, closed forms and sampling statistics."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import optimize, stats
from sklearn import mixture

from dexjax.policy.gmm import (GaussianMixture, fit_gaussian_mixture, gaussian_mixture_log_likelihood,
                               sample_gaussian_mixture)

REG = 1e-2
ITERATIONS = 30  # one value everywhere, so that fits of equal shapes share one compilation
_jit_fit = jax.jit(fit_gaussian_mixture, static_argnames=('num_components', 'iterations', 'init'))
_log_likelihood = jax.jit(gaussian_mixture_log_likelihood)
_sample = jax.jit(sample_gaussian_mixture, static_argnames='num_samples')


def _fit(key, x, w=None, *, num_components: int, init: str = 'kmeans++') -> GaussianMixture:
  """Jitted fit with ITERATIONS iterations and all-one weights when ``w`` is None."""
  w = np.ones(len(x), np.float32) if w is None else w
  return _jit_fit(key, x, w, num_components=num_components, iterations=ITERATIONS, init=init)


def _blobs(seed: int, dim: int, num_clusters: int = 3, per_cluster: int = 80) -> np.ndarray:
  """(num_clusters * per_cluster, dim) float32 rows of well-separated clusters with random full covariances."""
  rng = np.random.default_rng(seed)
  rows = []
  for c in range(num_clusters):
    centre = np.zeros(dim)
    centre[c % dim] = 8.0 * (1 + c // dim)
    mixing = rng.normal(0.0, 0.5, (dim, dim)) + 0.4 * np.eye(dim)
    rows.append(centre + rng.normal(size=(per_cluster, dim)) @ mixing)
  return np.concatenate(rows).astype(np.float32)


def _sklearn_fit(x: np.ndarray, k: int) -> mixture.GaussianMixture:
  return mixture.GaussianMixture(k, covariance_type='full', reg_covar=REG, max_iter=300, tol=1e-7, n_init=3,
                                 random_state=0).fit(x.astype(np.float64))


def _from_sklearn(sk: mixture.GaussianMixture) -> GaussianMixture:
  return GaussianMixture(weights=jnp.asarray(sk.weights_, jnp.float32), means=jnp.asarray(sk.means_, jnp.float32),
                         covariances=jnp.asarray(sk.covariances_, jnp.float32))


def _match(a: GaussianMixture, b: GaussianMixture) -> tuple[np.ndarray, np.ndarray]:
  """Component permutation of b closest to a (by means): (rows of a, rows of b)."""
  cost = np.linalg.norm(np.asarray(a.means)[:, None] - np.asarray(b.means)[None], axis=-1)
  return optimize.linear_sum_assignment(cost)


def _assert_same_fit(a: GaussianMixture, b: GaussianMixture, atol: float) -> None:
  ia, ib = _match(a, b)
  np.testing.assert_allclose(np.asarray(a.weights)[ia], np.asarray(b.weights)[ib], atol=atol)
  np.testing.assert_allclose(np.asarray(a.means)[ia], np.asarray(b.means)[ib], atol=atol)
  np.testing.assert_allclose(np.asarray(a.covariances)[ia], np.asarray(b.covariances)[ib], atol=atol)


def _assert_valid(gmm: GaussianMixture) -> None:
  for leaf in (gmm.weights, gmm.means, gmm.covariances):
    assert np.all(np.isfinite(np.asarray(leaf)))
  assert np.all(np.asarray(gmm.weights) > 0)
  np.testing.assert_allclose(np.sum(np.asarray(gmm.weights)), 1.0, atol=1e-5)
  cov = np.asarray(gmm.covariances)
  np.testing.assert_allclose(cov, np.swapaxes(cov, 1, 2), atol=1e-6)
  assert np.all(np.linalg.eigvalsh(cov) > 0)


@pytest.mark.parametrize('dim', [2, 5])
def test_log_likelihood_matches_sklearn_score_samples(dim):
  x = _blobs(1, dim)
  sk = _sklearn_fit(x, 3)
  far = np.random.default_rng(2).uniform(-10.0, 25.0, (40, dim)).astype(np.float32)
  points = np.concatenate([x, far])
  ours = np.asarray(_log_likelihood(_from_sklearn(sk), points))
  np.testing.assert_allclose(ours, sk.score_samples(points.astype(np.float64)), rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize('dim', [2, 5])
def test_fit_matches_sklearn(dim):
  x = _blobs(3, dim)
  sk = _sklearn_fit(x, 3)
  gmm = _fit(jax.random.key(0), x, num_components=3)
  _assert_valid(gmm)
  assert abs(float(jnp.mean(_log_likelihood(gmm, x))) - sk.score(x.astype(np.float64))) < 0.02
  _assert_same_fit(gmm, _from_sklearn(sk), atol=0.05)


def test_random_init_reaches_sklearn_optimum_from_some_key():
  x = _blobs(3, 2)
  fit = functools.partial(fit_gaussian_mixture, num_components=3, iterations=ITERATIONS, init='random')
  fits = jax.jit(jax.vmap(fit, in_axes=(0, None)))(jax.random.split(jax.random.key(1), 6), x)
  scores = np.asarray(jax.vmap(_log_likelihood, in_axes=(0, None))(fits, x)).mean(axis=1)
  assert np.all(np.isfinite(scores))
  assert abs(scores.max() - _sklearn_fit(x, 3).score(x.astype(np.float64))) < 0.02


def test_single_component_is_the_weighted_mean_and_covariance():
  x = _blobs(4, 3)
  w = np.random.default_rng(4).uniform(0.0, 3.0, x.shape[0]).astype(np.float32)
  w[::7] = 0.0
  gmm = _fit(jax.random.key(0), x, w, num_components=1)
  mean = np.sum(w[:, None] * x, axis=0) / np.sum(w)
  cov = np.einsum('n,nd,ne->de', w, x - mean, x - mean) / np.sum(w) + REG * np.eye(3)
  np.testing.assert_allclose(np.asarray(gmm.weights), [1.0])
  np.testing.assert_allclose(np.asarray(gmm.means[0]), mean, atol=1e-4)
  np.testing.assert_allclose(np.asarray(gmm.covariances[0]), cov, rtol=1e-4, atol=1e-4)
  np.testing.assert_allclose(np.asarray(_log_likelihood(gmm, x[:20])),
                             stats.multivariate_normal(mean, cov).logpdf(x[:20]), atol=1e-4)


def test_zero_weight_rows_do_not_influence_the_fit():
  x = _blobs(5, 2, per_cluster=70)
  outliers = np.random.default_rng(5).normal([30.0, -30.0], 3.0, (30, 2)).astype(np.float32)
  outliers[::10] = np.nan  # invalid features of masked rows must not poison the fit either
  both = np.concatenate([x, outliers])
  mask = np.concatenate([np.ones(len(x)), np.zeros(len(outliers))]).astype(np.float32)
  clean = _fit(jax.random.key(0), x, num_components=3)
  masked = _fit(jax.random.key(1), both, mask, num_components=3)
  _assert_valid(masked)
  _assert_same_fit(masked, clean, atol=2e-3)
  counted = _fit(jax.random.key(1), both, np.ones_like(mask), num_components=3)  # NaN rows dropped, others kept
  assert np.max(np.abs(np.asarray(_log_likelihood(counted, x)) - np.asarray(_log_likelihood(clean, x)))) > 0.1


def test_integer_weights_equal_duplicated_rows_and_scale_does_not_matter():
  x = _blobs(6, 2, per_cluster=60)
  padded = np.concatenate([x, np.full((60, 2), 1e3, np.float32)])  # 240 rows, as the duplicated set below
  w = np.concatenate([np.ones(len(x)), np.zeros(60)]).astype(np.float32)
  w[:len(x):3] = 2.0
  weighted = _fit(jax.random.key(0), padded, w, num_components=3)
  _assert_same_fit(weighted, _fit(jax.random.key(2), np.concatenate([x, x[::3]]), num_components=3), atol=2e-3)
  _assert_same_fit(weighted, _fit(jax.random.key(0), padded, 250.0 * w, num_components=3), atol=1e-5)


def _mixture_2d() -> GaussianMixture:
  return GaussianMixture(
      weights=jnp.array([0.2, 0.5, 0.3]), means=jnp.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]]),
      covariances=jnp.array([[[1.0, 0.6], [0.6, 0.5]], [[0.3, -0.2], [-0.2, 0.8]], [[2.0, 0.9], [0.9, 1.0]]]))


def test_samples_follow_the_mixture():
  gmm, n = _mixture_2d(), 20000
  raw = _sample(jax.random.key(7), gmm, n)
  assert raw.shape == (n, 2) and raw.dtype == jnp.float32
  samples = np.asarray(raw, np.float64)
  weights, means, covs = (np.asarray(a, np.float64) for a in (gmm.weights, gmm.means, gmm.covariances))
  label = np.argmin(np.linalg.norm(samples[:, None] - means[None], axis=-1), axis=1)
  counts = np.bincount(label, minlength=3)
  assert stats.chisquare(counts, n * weights).pvalue > 1e-3
  for k in range(3):
    own = samples[label == k]
    np.testing.assert_allclose(own.mean(axis=0), means[k], atol=4.0 * np.sqrt(covs[k].diagonal().max() / len(own)))
    np.testing.assert_allclose(np.cov(own.T), covs[k], atol=0.12)
  mean = weights @ means
  cov = np.einsum('k,kde->de', weights, covs + np.einsum('kd,ke->kde', means, means)) - np.outer(mean, mean)
  np.testing.assert_allclose(samples.mean(axis=0), mean, atol=0.1)
  np.testing.assert_allclose(np.cov(samples.T), cov, rtol=0.05)


def test_more_components_than_rows_stays_on_the_rows():
  x = _blobs(8, 2)
  w = np.zeros(len(x), np.float32)
  w[[3, 100]] = 1.0
  gmm = _fit(jax.random.key(0), x, w, num_components=5)
  _assert_valid(gmm)
  lo, hi = x[[3, 100]].min(axis=0) - 1e-3, x[[3, 100]].max(axis=0) + 1e-3
  assert np.all((np.asarray(gmm.means) >= lo) & (np.asarray(gmm.means) <= hi))
  assert np.all(np.isfinite(np.asarray(_log_likelihood(gmm, x))))
  assert np.all(np.isfinite(np.asarray(_sample(jax.random.key(1), gmm, 64))))


@pytest.mark.parametrize('init', ['kmeans++', 'random'])
def test_duplicate_rows_give_the_row_and_the_ridge(init):
  x = np.tile(np.array([[1.5, -2.0]], np.float32), (20, 1))
  gmm = _jit_fit(jax.random.key(0), x, num_components=3, iterations=ITERATIONS, init=init)  # no sample_weight
  _assert_valid(gmm)
  np.testing.assert_allclose(np.asarray(gmm.means), np.broadcast_to(x[0], (3, 2)), atol=1e-5)
  np.testing.assert_allclose(np.asarray(gmm.covariances), np.broadcast_to(REG * np.eye(2), (3, 2, 2)), atol=1e-6)


def test_components_without_data_stay_finite():
  x = np.repeat(np.array([[0.0, 0.0], [4.0, 4.0]], np.float32), 10, axis=0)
  gmm = _fit(jax.random.key(0), x, num_components=3)
  _assert_valid(gmm)
  assert np.all(np.min(np.linalg.norm(np.asarray(gmm.means)[:, None] - x[None], axis=-1), axis=1) < 1e-4)
  heavy = np.asarray(gmm.weights) > 0.1
  np.testing.assert_allclose(np.sort(np.asarray(gmm.weights)[heavy]), [0.5, 0.5], atol=1e-4)


def test_all_zero_weights_give_the_standard_normal():
  x = _blobs(8, 2)
  gmm = _fit(jax.random.key(0), x, np.zeros(len(x), np.float32), num_components=5)
  _assert_valid(gmm)
  np.testing.assert_array_equal(np.asarray(gmm.means), 0.0)
  np.testing.assert_array_equal(np.asarray(gmm.covariances), np.broadcast_to(np.eye(2), (5, 2, 2)))
  np.testing.assert_allclose(np.asarray(_log_likelihood(gmm, x[:5])),
                             stats.multivariate_normal(np.zeros(2), np.eye(2)).logpdf(x[:5]), atol=1e-4)


def test_unknown_init_is_rejected():
  with pytest.raises(ValueError, match='init'):
    fit_gaussian_mixture(jax.random.key(0), np.zeros((4, 2), np.float32), num_components=2, init='quantile')


def test_jit_vmap_and_plain_calls_agree():
  keys = jax.random.split(jax.random.key(9), 3)
  xs = np.stack([_blobs(s, 2, num_clusters=2, per_cluster=30) for s in range(3)])
  ws = np.ones(xs.shape[:2], np.float32)
  ws[:, ::5] = 0.0
  fit = functools.partial(fit_gaussian_mixture, num_components=2, iterations=10)
  batched = jax.jit(jax.vmap(fit))(keys, xs, ws)
  draws = jax.vmap(functools.partial(sample_gaussian_mixture, num_samples=16))(keys, batched)
  plain = fit(keys[0], xs[0], ws[0])  # eager and slow: one dataset
  _assert_valid(plain)
  np.testing.assert_allclose(draws[0], sample_gaussian_mixture(keys[0], plain, 16), rtol=1e-4, atol=1e-4)
  jitted = [jax.jit(fit)(keys[i], xs[i], ws[i]) for i in range(3)]
  close = lambda a, b: jax.tree.map(lambda u, v: np.testing.assert_allclose(u, v, rtol=1e-4, atol=1e-4), a, b)
  close(jitted[0], plain)
  for i in range(3):
    close(jax.tree.map(lambda a: a[i], batched), jitted[i])
