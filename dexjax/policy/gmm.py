"""Gaussian mixture models with full covariances fitted by expectation-maximisation (EM), jittable and vmappable.

The Cross-Entropy Method (`dexjax.policy.cem`) refits a K-component mixture to the z-scored feature vectors of
its elite grasps every iteration and draws the next grasps from it. Everything here is float32 with static shapes:
``num_components``, ``iterations`` and ``init`` are static, the number of EM iterations is fixed (no tolerance).

* Weighted rows: row i counts w_i = ``sample_weight[i]`` times (only ratios matter: weights are rescaled to
  mean 1 over the kept rows, so a 0/1 validity mask counts rows exactly as scikit-learn does). Rows of weight 0,
  negative or non-finite weight, or with a non-finite feature are ignored entirely: their features are replaced by
  0 before any arithmetic, so the fit equals the fit on the kept rows alone up to the randomness of the
  initialisation.
* M-step as scikit-learn's ``GaussianMixture(covariance_type='full')``: component mass m_k = sum_i w_i r_ik,
  weights (m_k + 10 eps) / sum_j (m_j + 10 eps), means and covariances weighted by w_i r_ik / m_k (scikit-learn
  divides by m_k + 10 eps, which drags nearly empty components to the origin), plus ``reg_covar * I`` on every
  covariance (which must then be > 0 for duplicate rows or fewer rows than dimensions to stay positive definite).
* E-step and `gaussian_mixture_log_likelihood`: Cholesky factors, triangular solves and log-sum-exp.
* Initialisation (``init``), then one M-step from the hard assignment of every row to its nearest centre (one-hot
  responsibilities, scikit-learn's ``init_params='kmeans'``):
  - ``'kmeans++'`` (default): weighted k-means++ seeding (the first centre drawn with probability proportional
    to w_i, each next one proportional to w_i D_i^2, D_i the distance to the nearest chosen centre; proportional
    to w_i again once every kept row is a centre), then 5 weighted Lloyd iterations (an empty cluster keeps its
    centre). Spread-out seeds make EM land in the right optimum on separated clusters at little cost.
  - ``'random'``: K distinct kept rows drawn with probability proportional to w_i (Gumbel top-k; cycled when
    fewer than K rows are kept), no Lloyd iterations: cheaper, more prone to local optima. Rows rather than
    per-dimension quantiles are used because quantile centres of several dimensions may lie off the data.
* Degenerate inputs stay finite: a component whose responsibility mass falls below 1e-6 rows (more components
  than kept rows, duplicate rows, a component left without data) keeps its previous mean and covariance (after
  the initialisation: its centre and the pooled covariance of the data + reg_covar I) while its weight goes to
  ~0 (never exactly 0). With no kept row at all the result is the standard normal (K equal components N(0, I)).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from flax import struct

_LLOYD_ITERATIONS = 5
_DEAD_MASS = 1e-6  # responsibility mass (rows) below which a component keeps its previous parameters
_MASS_EPS = 10.0 * float(jnp.finfo(jnp.float32).eps)  # added to every component mass, as scikit-learn
_HIGHEST = jax.lax.Precision.HIGHEST


@struct.dataclass
class GaussianMixture:
  """A Gaussian mixture with full covariances.

  Attributes:
    weights: (K,) mixture weights, positive, summing to 1.
    means: (K, D) component means.
    covariances: (K, D, D) component covariances, symmetric positive definite.
  """

  weights: jax.Array
  means: jax.Array
  covariances: jax.Array


def fit_gaussian_mixture(key: jax.Array, x: jax.Array, sample_weight: jax.Array | None = None, *,
                         num_components: int, iterations: int = 20, reg_covar: float = 1e-2,
                         init: str = 'kmeans++') -> GaussianMixture:
  """Fit a K-component full-covariance mixture to weighted rows by EM (see the module doc).

  Args:
    key: PRNG key of the initialisation.
    x: (N, D) rows (cast to float32).
    sample_weight: (N,) non-negative row weights (None: all 1); rows of weight 0 do not influence the fit.
    num_components: static, K (may exceed the number of kept rows).
    iterations: static, EM iterations after the initialisation.
    reg_covar: added to the diagonal of every covariance.
    init: static, 'kmeans++' or 'random'.

  Returns:
    The fitted `GaussianMixture` with (K,), (K, D), (K, D, D) leaves; the standard normal when no row is kept.
  """
  if init not in _INITS:
    raise ValueError(f"init must be one of {sorted(_INITS)}, got {init!r}")
  if num_components < 1:
    raise ValueError(f"num_components must be >= 1, got {num_components}")
  x, w = _clean_rows(x, sample_weight)
  centres = _INITS[init](key, x, w, num_components)
  k, d = num_components, x.shape[1]
  covariance = _pooled_covariance(x, w) + reg_covar * jnp.eye(d, dtype=jnp.float32)
  prior = GaussianMixture(weights=jnp.full((k,), 1.0 / k), means=centres,
                          covariances=jnp.broadcast_to(covariance, (k, d, d)))
  hard = jax.nn.one_hot(jnp.argmin(_squared_distances(x, centres), axis=1), k)
  gmm = _m_step(x, w, hard, reg_covar, prior)
  gmm = jax.lax.fori_loop(0, iterations, lambda _, g: _m_step(x, w, _responsibilities(g, x), reg_covar, g), gmm)
  standard = _standard_normal(k, d)
  return jax.tree.map(lambda a, b: jnp.where(jnp.any(w > 0), a, b), gmm, standard)


def gaussian_mixture_log_likelihood(gmm: GaussianMixture, x: jax.Array) -> jax.Array:
  """(N,) log density log sum_k w_k N(x_i | mu_k, Sigma_k) of rows x (N, D)."""
  return jax.nn.logsumexp(_joint_log_prob(gmm, jnp.asarray(x, jnp.float32)), axis=1)


def sample_gaussian_mixture(key: jax.Array, gmm: GaussianMixture, num_samples: int) -> jax.Array:
  """(num_samples, D) draws: a component k ~ Categorical(weights), then mu_k + L_k z, L_k L_k^T = Sigma_k, z ~ N(0, I).

  ``num_samples`` is static.
  """
  k_component, k_noise = jax.random.split(key)
  component = jax.random.categorical(k_component, jnp.log(gmm.weights), shape=(num_samples,))
  z = jax.random.normal(k_noise, (num_samples, gmm.means.shape[1]), jnp.float32)
  chol = jnp.linalg.cholesky(gmm.covariances)[component]
  return gmm.means[component] + jnp.einsum('nde,ne->nd', chol, z, precision=_HIGHEST)


def _clean_rows(x: jax.Array, sample_weight: jax.Array | None) -> tuple[jax.Array, jax.Array]:
  """(x (N, D) with ignored rows zeroed, w (N,) with mean 1 over the kept rows and 0 elsewhere)."""
  x = jnp.asarray(x, jnp.float32)
  w = jnp.ones(x.shape[:1], jnp.float32) if sample_weight is None else jnp.asarray(sample_weight, jnp.float32)
  keep = jnp.isfinite(w) & (w > 0) & jnp.all(jnp.isfinite(x), axis=1)
  w = jnp.where(keep, w, 0.0)
  w = w / jnp.maximum(jnp.max(w), jnp.finfo(jnp.float32).tiny)
  w = w * jnp.sum(keep) / jnp.maximum(jnp.sum(w), 1.0)
  return jnp.where(keep[:, None], x, 0.0), w


def _pooled_covariance(x: jax.Array, w: jax.Array) -> jax.Array:
  """(D, D) weighted covariance of all rows (x (N, D), w (N,))."""
  total = jnp.maximum(jnp.sum(w), 1.0)
  diff = x - jnp.sum(w[:, None] * x, axis=0) / total
  return jnp.einsum('n,nd,ne->de', w, diff, diff, precision=_HIGHEST) / total


def _squared_distances(x: jax.Array, centres: jax.Array) -> jax.Array:
  """(N, K) squared Euclidean distances of rows x (N, D) to centres (K, D)."""
  return jnp.sum((x[:, None, :] - centres[None, :, :]) ** 2, axis=-1)


def _draw(key: jax.Array, p: jax.Array, fallback: jax.Array) -> jax.Array:
  """Index drawn with probability proportional to p (N,) >= 0, else to ``fallback``, else uniformly."""
  p = jnp.where(jnp.sum(p) > 0, p, fallback)
  p = jnp.where(jnp.sum(p) > 0, p, 1.0)
  return jax.random.categorical(key, jnp.log(p))


def _init_kmeans_plus_plus(key: jax.Array, x: jax.Array, w: jax.Array, k: int) -> jax.Array:
  """(K, D) centres: weighted k-means++ seeding then `_LLOYD_ITERATIONS` weighted Lloyd iterations."""
  keys = jax.random.split(key, k)
  first = x[_draw(keys[0], w, w)]

  def add(i, carry):
    centres, d2 = carry
    centre = x[_draw(keys[i], w * d2, w)]
    return centres.at[i].set(centre), jnp.minimum(d2, jnp.sum((x - centre) ** 2, axis=1))

  start = (jnp.zeros((k, x.shape[1]), jnp.float32).at[0].set(first), jnp.sum((x - first) ** 2, axis=1))
  centres, _ = jax.lax.fori_loop(1, k, add, start)
  return jax.lax.fori_loop(0, _LLOYD_ITERATIONS, lambda _, c: _lloyd_step(x, w, c), centres)


def _lloyd_step(x: jax.Array, w: jax.Array, centres: jax.Array) -> jax.Array:
  """(K, D) weighted means of the rows nearest to each centre; an empty cluster keeps its centre."""
  assign = jax.nn.one_hot(jnp.argmin(_squared_distances(x, centres), axis=1), centres.shape[0]) * w[:, None]
  count = jnp.sum(assign, axis=0)
  means = jnp.einsum('nk,nd->kd', assign, x, precision=_HIGHEST) / jnp.maximum(count, 1e-30)[:, None]
  return jnp.where(count[:, None] > 0, means, centres)


def _init_random(key: jax.Array, x: jax.Array, w: jax.Array, k: int) -> jax.Array:
  """(K, D) centres: distinct kept rows drawn with probability proportional to w (cycled if fewer than K)."""
  scores = jnp.where(w > 0, jnp.log(jnp.where(w > 0, w, 1.0)) + jax.random.gumbel(key, w.shape), -jnp.inf)
  order = jnp.argsort(-scores)
  return x[order[jnp.arange(k) % jnp.maximum(jnp.sum(w > 0), 1)]]


def _m_step(x: jax.Array, w: jax.Array, resp: jax.Array, reg_covar: float,
            previous: GaussianMixture) -> GaussianMixture:
  """Mixture maximising the expected weighted log-likelihood given responsibilities (N, K); components of mass
  below `_DEAD_MASS` keep the means and covariances of ``previous``."""
  r = jnp.where(w[:, None] > 0, resp, 0.0) * w[:, None]
  mass = jnp.sum(r, axis=0)
  safe = jnp.maximum(mass, _DEAD_MASS)
  means = jnp.einsum('nk,nd->kd', r, x, precision=_HIGHEST) / safe[:, None]
  diff = x[:, None, :] - means[None, :, :]
  cov = jnp.einsum('nk,nkd,nke->kde', r, diff, diff, precision=_HIGHEST) / safe[:, None, None]
  cov = 0.5 * (cov + jnp.swapaxes(cov, 1, 2)) + reg_covar * jnp.eye(x.shape[1], dtype=jnp.float32)
  alive = mass > _DEAD_MASS
  nk = mass + _MASS_EPS
  return GaussianMixture(weights=nk / jnp.sum(nk), means=jnp.where(alive[:, None], means, previous.means),
                         covariances=jnp.where(alive[:, None, None], cov, previous.covariances))


def _log_gaussians(gmm: GaussianMixture, x: jax.Array) -> jax.Array:
  """(N, K) log N(x_i | mu_k, Sigma_k) by Cholesky factors and triangular solves."""
  chol = jnp.linalg.cholesky(gmm.covariances)
  diff = jnp.swapaxes(x[None, :, :] - gmm.means[:, None, :], 1, 2)
  z = jax.scipy.linalg.solve_triangular(chol, diff, lower=True)
  log_det = 2.0 * jnp.sum(jnp.log(jnp.diagonal(chol, axis1=1, axis2=2)), axis=1)
  return -0.5 * (x.shape[1] * math.log(2.0 * math.pi) + log_det[:, None] + jnp.sum(z ** 2, axis=1)).T


def _joint_log_prob(gmm: GaussianMixture, x: jax.Array) -> jax.Array:
  """(N, K) log w_k + log N(x_i | mu_k, Sigma_k)."""
  return jnp.log(gmm.weights) + _log_gaussians(gmm, x)


def _responsibilities(gmm: GaussianMixture, x: jax.Array) -> jax.Array:
  """(N, K) posterior component probabilities of rows x (N, D) (the E-step)."""
  joint = _joint_log_prob(gmm, x)
  return jnp.exp(joint - jax.nn.logsumexp(joint, axis=1, keepdims=True))


def _standard_normal(k: int, d: int) -> GaussianMixture:
  """K equal components N(0, I) in D dimensions."""
  return GaussianMixture(weights=jnp.full((k,), 1.0 / k), means=jnp.zeros((k, d), jnp.float32),
                         covariances=jnp.broadcast_to(jnp.eye(d, dtype=jnp.float32), (k, d, d)))


_INITS = {'kmeans++': _init_kmeans_plus_plus, 'random': _init_random}

__all__ = ['GaussianMixture', 'fit_gaussian_mixture', 'gaussian_mixture_log_likelihood', 'sample_gaussian_mixture']
