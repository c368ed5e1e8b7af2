"""The Cross-Entropy Method grasping policy of one gripper (seed, "Parameters of Grasping Policy"; spec 4.3).

    G <- n candidates from the gripper's image sampler; Q <- scorer(G)
    repeat m times:
      E <- the top ceil(gamma |G|) grasps by Q (the elite set)
      F <- their feature vectors (`dexjax.policy.candidates`), z-scored per dimension
      fit a k-component Gaussian mixture to F by EM (`dexjax.policy.gmm`: full covariances + reg_covar I)
      G <- c grasps drawn from the mixture (un-z-scored, decoded, invalid ones rejected); Q <- scorer(G)
    return argmax_Q of the last G                (``select='best'``: of every G scored)
    optionally polish it and the next best of the last G by gradient ascent on Q (``polish``:
    `dexjax.policy.polish`, learned scorers only) and return the best polished grasp

Defaults are the seed's, the same for both grippers: m = 3, n = 250, c = 50, k = 5, gamma = 0.25
(`CEMParams()`); gqcnn's Dex-Net 4.0 configs (PJ: n = 128, c = 64; suction: n = 200, c = 50; k =
ceil(0.4 |E|)) are `CEMParams.gqcnn_dexnet4(gripper)`. Shapes are static: rejection of invalid mixture samples
draws ``oversample * c`` samples and keeps the first c valid ones (the rest of the set is marked invalid);
invalid grasps score -inf and carry no weight in the fit. When the last set holds no valid grasp (the mixture
drifted off the mask) the best grasp of the earlier rounds is returned instead; when no round holds one, the action
is invalid ("no grasp"). z-scoring divides by max(std, 1e-6) (gqcnn's guard).
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.policy.actions import GraspAction, action_from_grasp, pad_samples, samples_of
from dexjax.policy.candidates import (Sampler, grasp_features, grasps_from_features, sample_candidates,
                                      sampler_gripper)
from dexjax.policy.gmm import fit_gaussian_mixture, sample_gaussian_mixture
from dexjax.policy.observation import Observation
from dexjax.policy.polish import PolishParams, polish_grasps
from dexjax.policy.scorers import PARALLEL_JAW
from dexjax.sampling.image_samplers import surface_normals


@struct.dataclass
class CEMParams:
  """Cross-Entropy Method settings (all static: they fix the shapes).

  Attributes:
    num_iterations: m, refits of the mixture.
    num_seed: n, initial candidates.
    num_resample: c, grasps drawn from the mixture per iteration.
    num_components: k, mixture components (capped by the elite set's size).
    component_fraction: if set, k = max(1, ceil(fraction |E|)) per iteration instead (gqcnn's gmm_component_frac).
    elite_fraction: gamma, the elite share of each set.
    em_iterations: EM iterations per fit.
    reg_covar: ridge added to each covariance of the z-scored features.
    oversample: mixture samples drawn per grasp kept (rejection with a fixed budget).
    select: ``'last'`` returns the best grasp of the last set (gqcnn, the seed's "identical implementation");
      ``'best'`` the best of every grasp scored (no extra evaluations; better with few iterations).
  """

  num_iterations: int = struct.field(pytree_node=False, default=3)
  num_seed: int = struct.field(pytree_node=False, default=250)
  num_resample: int = struct.field(pytree_node=False, default=50)
  num_components: int = struct.field(pytree_node=False, default=5)
  component_fraction: float | None = struct.field(pytree_node=False, default=None)
  elite_fraction: float = struct.field(pytree_node=False, default=0.25)
  em_iterations: int = struct.field(pytree_node=False, default=20)
  reg_covar: float = struct.field(pytree_node=False, default=0.01)
  oversample: int = struct.field(pytree_node=False, default=4)
  select: str = struct.field(pytree_node=False, default='last')

  @classmethod
  def gqcnn_dexnet4(cls, gripper: str) -> CEMParams:
    """gqcnn's released Dex-Net 4.0 policy configs (spec 4.3): PJ n = 128, c = 64; suction n = 200, c = 50;
    k = ceil(0.4 |E|)."""
    seed, resample = (128, 64) if gripper == PARALLEL_JAW else (200, 50)
    return cls(num_seed=seed, num_resample=resample, component_fraction=0.4)

  def elite_size(self, set_size: int) -> int:
    """|E| for a set of ``set_size`` grasps: max(1, ceil(gamma |G|))."""
    return max(1, math.ceil(self.elite_fraction * set_size))

  def components(self, set_size: int) -> int:
    """k for a set of ``set_size`` grasps."""
    elite = self.elite_size(set_size)
    k = self.num_components if self.component_fraction is None else math.ceil(self.component_fraction * elite)
    return max(1, min(k, elite))

  def validate(self) -> CEMParams:
    """Checks the fields; raises ValueError naming the field and the expected value."""
    for name in ('num_seed', 'num_resample', 'num_components', 'em_iterations', 'oversample'):
      value = getattr(self, name)
      if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f'CEMParams.{name}: expected an integer >= 1, got {value!r}')
    if isinstance(self.num_iterations, bool) or not isinstance(self.num_iterations, int) or self.num_iterations < 0:
      raise ValueError(f'CEMParams.num_iterations: expected an integer >= 0, got {self.num_iterations!r}')
    if not 0.0 < self.elite_fraction <= 1.0:
      raise ValueError(f'CEMParams.elite_fraction: expected a fraction in (0, 1], got {self.elite_fraction!r}')
    if self.component_fraction is not None and not 0.0 < self.component_fraction <= 1.0:
      raise ValueError(f'CEMParams.component_fraction: expected None or a fraction in (0, 1], got '
                       f'{self.component_fraction!r}')
    if self.select not in ('last', 'best'):
      raise ValueError(f"CEMParams.select: expected 'last' or 'best', got {self.select!r}")
    if not self.reg_covar > 0:
      raise ValueError(f'CEMParams.reg_covar: expected a positive number, got {self.reg_covar!r}')
    return self


@struct.dataclass
class CEMPolicy:
  """A CEM policy of one gripper.

  Attributes:
    scorer: the quality function (`dexjax.policy.scorers`), of the sampler's gripper.
    sampler: the gripper's image sampler; its ``num_grasps`` is replaced by ``cem.num_seed``.
    cem: `CEMParams`.
    polish: None, or `PolishParams`: the chosen grasp and the next best of the last set (``num_grasps`` in all)
      are polished by gradient ascent on the scorer (a `GQCNNScorer`), and the best of them is returned.
  """

  scorer: Any
  sampler: Sampler
  cem: CEMParams = CEMParams()
  polish: PolishParams | None = None

  @property
  def gripper(self) -> str:
    return sampler_gripper(self.sampler)

  def __call__(self, key: jax.Array, observation: Observation, samples: bool = False) -> GraspAction:
    return cem_policy(key, observation, self, samples)


def _scores(scorer, observation: Observation, grasps, valid: jax.Array) -> jax.Array:
  return jnp.where(valid, scorer(observation, grasps), -jnp.inf)


def _zscore(features: jax.Array, weight: jax.Array) -> tuple[jax.Array, jax.Array]:
  """Weighted per-dimension (mean, std) of features (E, D) over rows of positive weight (std >= 1e-6)."""
  total = jnp.maximum(jnp.sum(weight), 1.0)
  mean = jnp.sum(weight[:, None] * features, axis=0) / total
  var = jnp.sum(weight[:, None] * (features - mean) ** 2, axis=0) / total
  return mean, jnp.maximum(jnp.sqrt(var), 1e-6)


def _take(tree, index: jax.Array):
  return jax.tree.map(lambda x: x[index], tree)


def _first_valid(valid: jax.Array, k: int) -> tuple[jax.Array, jax.Array]:
  """Indices (k,) of the first k True entries of ``valid`` (M,), in order, and which of them exist."""
  order = jnp.where(valid, -jnp.arange(valid.shape[0]), -valid.shape[0] - jnp.arange(valid.shape[0]))
  _, index = jax.lax.top_k(order, k)
  return index, valid[index]


def _resample(key: jax.Array, observation: Observation, grasps, quality: jax.Array, policy: CEMPolicy,
              normals: jax.Array | None):
  """One CEM iteration: the elite of (grasps, quality) -> c new grasps and their validity."""
  cem = policy.cem
  k_fit, k_draw = jax.random.split(key)
  elite_q, elite = jax.lax.top_k(quality, cem.elite_size(quality.shape[0]))
  weight = jnp.isfinite(elite_q).astype(jnp.float32)
  features = grasp_features(observation, _take(grasps, elite))
  mean, std = _zscore(features, weight)
  mixture = fit_gaussian_mixture(k_fit, (features - mean) / std, weight,
                                 num_components=cem.components(quality.shape[0]), iterations=cem.em_iterations,
                                 reg_covar=cem.reg_covar)
  draws = sample_gaussian_mixture(k_draw, mixture, cem.oversample * cem.num_resample) * std + mean
  new, ok = grasps_from_features(observation, draws, policy.sampler, normals)
  index, kept = _first_valid(ok & jnp.any(weight > 0), cem.num_resample)
  return _take(new, index), kept


def _polished(observation: Observation, grasps, quality: jax.Array, chosen, chosen_q: jax.Array, policy: CEMPolicy,
              normals: jax.Array | None):
  """(grasp, score) after polishing ``chosen`` and the next best grasps of the last set (`polish_grasps`)."""
  k = min(policy.polish.num_grasps, quality.shape[0])
  top_q, top = jax.lax.top_k(quality, k)
  starts = jax.tree.map(lambda a, c: a.at[0].set(c), _take(grasps, top), chosen)
  polished, q = polish_grasps(observation, starts, top_q.at[0].set(chosen_q), policy.scorer, policy.sampler,
                              policy.polish, normals)
  best = jnp.argmax(q)
  return _take(polished, best), q[best]


def cem_policy(key: jax.Array, observation: Observation, policy: CEMPolicy, samples: bool = False) -> GraspAction:
  """Plans one gripper's grasp on one observation by the Cross-Entropy Method (see the module doc).

  Args:
    key: PRNG key.
    observation: the `Observation`.
    policy: `CEMPolicy` (scorer, sampler, settings).
    samples: static; also return every round's grasps and scores in ``action.samples`` (R = m + 1 rounds of
      N = max(n, c) grasps).

  Returns:
    The `GraspAction` of highest score in the last set (polished, with ``policy.polish``); ``valid`` False when no
    valid grasp was found.
  """
  cem = policy.cem
  sampler = policy.sampler.replace(num_grasps=cem.num_seed)
  policy = policy.replace(sampler=sampler)
  k_seed, k_iter = jax.random.split(key)
  grasps, valid = sample_candidates(k_seed, observation, sampler)
  quality = _scores(policy.scorer, observation, grasps, valid)
  normals = None if policy.gripper == PARALLEL_JAW else surface_normals(observation.camera, observation.depth)
  size = max(cem.num_seed, cem.num_resample)
  rounds = [pad_samples(samples_of(grasps, quality, valid), 1, size)]
  best_before = jnp.argmax(quality)
  earlier = (_take(grasps, best_before), quality[best_before])
  for key_i in jax.random.split(k_iter, cem.num_iterations):
    grasps, valid = _resample(key_i, observation, grasps, quality, policy, normals)
    quality = _scores(policy.scorer, observation, grasps, valid)
    rounds.append(pad_samples(samples_of(grasps, quality, valid), 1, size))
    if len(rounds) < cem.num_iterations + 1:
      i = jnp.argmax(quality)
      better = quality[i] > earlier[1]
      earlier = jax.tree.map(lambda a, b: jnp.where(better, a, b), (_take(grasps, i), quality[i]), earlier)
  best = jnp.argmax(quality)
  last_ok = jnp.isfinite(quality[best])
  if cem.select == 'best':
    last_ok &= quality[best] >= earlier[1]
  grasp, q = jax.tree.map(lambda a, b: jnp.where(last_ok, a, b), (_take(grasps, best), quality[best]), earlier)
  if policy.polish is not None:
    grasp, q = _polished(observation, grasps, quality, grasp, q, policy, normals)
  action = action_from_grasp(observation, grasp, jnp.where(jnp.isfinite(q), q, 0.0), jnp.isfinite(q))
  if samples:
    action = action.replace(samples=jax.tree.map(lambda *xs: jnp.concatenate(xs), *rounds))
  return action


__all__ = ['CEMParams', 'CEMPolicy', 'cem_policy']
