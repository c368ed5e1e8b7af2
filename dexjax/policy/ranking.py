"""One-shot policies of one gripper: rank a sampled candidate set by a scorer (gqcnn's `RobustGraspingPolicy`),
or take a candidate uniformly at random (`UniformRandomGraspingPolicy`).

A ranking policy with a heuristic scorer is a heuristic baseline (`dexjax.policy.heuristics`); with a GQ-CNN it is
the CEM policy without refinement, at the cost of N network evaluations.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.policy.actions import GraspAction, action_from_grasp, samples_of
from dexjax.policy.candidates import Sampler, sample_candidates, sampler_gripper
from dexjax.policy.observation import Observation
from dexjax.policy.scorers import refined_candidates


@struct.dataclass
class RankingPolicy:
  """Sample ``sampler.num_grasps`` candidates, return the best by ``scorer``.

  Attributes:
    scorer: the quality function (`dexjax.policy.scorers`, `dexjax.policy.heuristics`); its optional ``refine``
      method turns the candidates before they are scored (`dexjax.policy.scorers.refined_candidates`).
    sampler: the gripper's image sampler (its ``num_grasps`` is N).
  """

  scorer: Any
  sampler: Sampler

  @property
  def gripper(self) -> str:
    return sampler_gripper(self.sampler)

  def __call__(self, key: jax.Array, observation: Observation, samples: bool = False) -> GraspAction:
    return ranking_policy(key, observation, self, samples)


@struct.dataclass
class RandomPolicy:
  """A candidate drawn uniformly among the valid ones of ``sampler``; scored by ``scorer`` for the record only.

  Attributes:
    sampler: the gripper's image sampler.
    scorer: optional quality function reported as the action's probability (NaN without one).
  """

  sampler: Sampler
  scorer: Any = None

  @property
  def gripper(self) -> str:
    return sampler_gripper(self.sampler)

  def __call__(self, key: jax.Array, observation: Observation, samples: bool = False) -> GraspAction:
    return random_policy(key, observation, self, samples)


def ranking_policy(key: jax.Array, observation: Observation, policy: RankingPolicy,
                   samples: bool = False) -> GraspAction:
  """The best of N sampled candidates by the policy's scorer (``valid`` False when there is none). ``samples``
  (static) keeps the N candidates and their scores (one round) in ``action.samples``."""
  grasps, valid = sample_candidates(key, observation, policy.sampler)
  grasps = refined_candidates(policy.scorer, observation, grasps)  # e.g. a heuristic's fitted suction approaches
  quality = jnp.where(valid, policy.scorer(observation, grasps), -jnp.inf)
  best = jnp.argmax(quality)
  ok = jnp.isfinite(quality[best])
  action = action_from_grasp(observation, jax.tree.map(lambda x: x[best], grasps),
                             jnp.where(ok, quality[best], 0.0), ok)
  return action.replace(samples=samples_of(grasps, quality, valid)) if samples else action


def random_policy(key: jax.Array, observation: Observation, policy: RandomPolicy,
                  samples: bool = False) -> GraspAction:
  """A uniformly random valid candidate (``valid`` False when there is none)."""
  k_sample, k_pick = jax.random.split(key)
  grasps, valid = sample_candidates(k_sample, observation, policy.sampler)
  pick = jax.random.categorical(k_pick, jnp.where(valid, 0.0, -jnp.inf))
  grasp = jax.tree.map(lambda x: x[pick], grasps)
  if policy.scorer is None:
    probability = jnp.float32(jnp.nan)
  else:
    probability = policy.scorer(observation, jax.tree.map(lambda x: x[None], grasp))[0]
  action = action_from_grasp(observation, grasp, probability, valid[pick])
  if not samples:
    return action
  quality = jnp.where(valid, jnp.where(jnp.arange(valid.shape[0]) == pick, probability, jnp.nan), -jnp.inf)
  return action.replace(samples=samples_of(grasps, quality, valid))


__all__ = ['RandomPolicy', 'RankingPolicy', 'random_policy', 'ranking_policy']
