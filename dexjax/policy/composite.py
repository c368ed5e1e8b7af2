"""Policies over several grippers: the ambidextrous (greedy) choice of Dex-Net 4.0 and a uniformly random one.

* `GreedyComposite` (gqcnn's `GreedyCompositeGraspingPolicy`, which crashes in the original, done as intended):
  plan with every gripper's policy and execute the grasp of highest predicted probability. With a CEM policy per
  gripper on GQ-CNNs trained on the same reward, this is the Dex-Net 4.0 ambidextrous policy (`ambidextrous`).
* `RandomComposite`: a gripper drawn uniformly among those with a valid candidate, then a uniform candidate.
* `HeuristicComposite` (the benchmark's "Composite Heuristic"): the suction planarity-centroid and parallel-jaw
  force-closure-centroid rankings, one of them chosen by `dexjax.policy.heuristics.composite_heuristic_choice`
  (heuristic scores are not probabilities, so no greedy comparison).

Each returned action carries ``per_gripper``: the sub-policies' actions stacked in `GRIPPERS` order (a gripper
without a sub-policy has ``valid`` False), and with ``samples=True`` their samples stacked per gripper.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.policy.heuristics import composite_heuristic_choice
from dexjax.policy.actions import GraspAction, best_action, pad_samples, select_action, stack_actions
from dexjax.policy.instances import depth_instances
from dexjax.policy.observation import Observation
from dexjax.policy.scorers import GRIPPERS


def _check_grippers(policies: tuple[Any, ...]) -> None:
  grippers = [p.gripper for p in policies]
  if not policies or len(set(grippers)) != len(grippers):
    raise ValueError(f'policies: expected one sub-policy per gripper (at least one), got grippers {grippers}')


def _invalid_like(action: GraspAction) -> GraspAction:
  return jax.tree.map(jnp.zeros_like, action.replace(samples=None, per_gripper=None))


def _per_gripper(names: list[str], actions: list[GraspAction]) -> GraspAction:
  """The actions of grippers ``names`` stacked in `GRIPPERS` order; a gripper without one gets an all-zero action
  (``valid`` False)."""
  by_name = dict(zip(names, actions))
  filler = _invalid_like(actions[0])
  return stack_actions([by_name.get(name, filler.replace(gripper=jnp.int32(i))) for i, name in enumerate(GRIPPERS)])


def _stacked_samples(actions: list[GraspAction]):
  rounds = max(a.samples.valid.shape[0] for a in actions)
  size = max(a.samples.valid.shape[1] for a in actions)
  padded = [pad_samples(a.samples, rounds, size) for a in actions]
  return jax.tree.map(lambda *xs: jnp.stack(xs), *padded)


def _plan_all(key: jax.Array, observation: Observation, policies: tuple[Any, ...],
              samples: bool) -> tuple[list[str], list[GraspAction]]:
  """(gripper names, actions) of every sub-policy, in `GRIPPERS` order (so samples stack in that order)."""
  keys = jax.random.split(key, len(policies))
  ordered = sorted(range(len(policies)), key=lambda i: GRIPPERS.index(policies[i].gripper))
  return [policies[i].gripper for i in ordered], [policies[i](keys[i], observation, samples) for i in ordered]


def _finish(action: GraspAction, names: list[str], actions: list[GraspAction], samples: bool) -> GraspAction:
  action = action.replace(per_gripper=_per_gripper(names, actions))
  return action.replace(samples=_stacked_samples(actions)) if samples else action


@struct.dataclass
class GreedyComposite:
  """Plan with each sub-policy, take the action of highest probability.

  Attributes:
    policies: tuple of single-gripper policies (`CEMPolicy`, `RankingPolicy`), one per gripper.
  """

  policies: tuple[Any, ...]

  def __call__(self, key: jax.Array, observation: Observation, samples: bool = False) -> GraspAction:
    return greedy_composite_policy(key, observation, self, samples)


@struct.dataclass
class RandomComposite:
  """A gripper uniformly among those with a valid action of its `RandomPolicy`, and that action.

  Attributes:
    policies: tuple of `RandomPolicy`, one per gripper.
  """

  policies: tuple[Any, ...]

  def __call__(self, key: jax.Array, observation: Observation, samples: bool = False) -> GraspAction:
    return random_composite_policy(key, observation, self, samples)


@struct.dataclass
class HeuristicComposite:
  """The Composite Heuristic: rank with both heuristics, choose the gripper by a fixed rule.

  Attributes:
    suction: a `RankingPolicy` with a `SuctionPlanarityCentroid` scorer.
    parallel_jaw: a `RankingPolicy` with a `ParallelJawForceClosureCentroid` scorer.
    suction_threshold: smallest suction score that takes priority over the jaws (`composite_heuristic_choice`).
  """

  suction: Any
  parallel_jaw: Any
  suction_threshold: float = 0.5

  @property
  def policies(self) -> tuple[Any, ...]:
    return (self.parallel_jaw, self.suction)

  def __call__(self, key: jax.Array, observation: Observation, samples: bool = False) -> GraspAction:
    return heuristic_composite_policy(key, observation, self, samples)


def greedy_composite_policy(key: jax.Array, observation: Observation, policy: GreedyComposite,
                            samples: bool = False) -> GraspAction:
  """The sub-policies' action of highest probability (see the module doc); ``valid`` False if none has one."""
  _check_grippers(policy.policies)
  names, actions = _plan_all(key, observation, policy.policies, samples)
  action, _ = best_action(actions)
  return _finish(action, names, actions, samples)


def random_composite_policy(key: jax.Array, observation: Observation, policy: RandomComposite,
                            samples: bool = False) -> GraspAction:
  """A uniformly random gripper with a valid action, and its uniformly random action."""
  _check_grippers(policy.policies)
  k_plan, k_pick = jax.random.split(key)
  names, actions = _plan_all(k_plan, observation, policy.policies, samples)
  valid = jnp.stack([a.valid for a in actions])
  index = jax.random.categorical(k_pick, jnp.where(valid, 0.0, -jnp.inf))
  index = jnp.where(jnp.any(valid), index, 0)
  return _finish(select_action(actions, index), names, actions, samples)


def _shared_instances(observation: Observation, policy: HeuristicComposite) -> HeuristicComposite:
  """``policy`` whose two scorers share one depth-instance segmentation of ``observation`` (each would segment it
  again), when both segment it with the same jump and neither has its own labels."""
  suction, jaws = policy.suction.scorer, policy.parallel_jaw.scorer
  if suction.labels is not None or jaws.labels is not None or suction.instance_jump is None or (
      suction.instance_jump != jaws.instance_jump):
    return policy
  labels = depth_instances(observation.depth, observation.mask, suction.instance_jump)
  return policy.replace(suction=policy.suction.replace(scorer=suction.replace(labels=labels)),
                        parallel_jaw=policy.parallel_jaw.replace(scorer=jaws.replace(labels=labels)))


def heuristic_composite_policy(key: jax.Array, observation: Observation, policy: HeuristicComposite,
                               samples: bool = False) -> GraspAction:
  """The Composite Heuristic's action: the gripper by `composite_heuristic_choice` on the two rankings' best
  scores (0 where a ranking found no valid candidate), and that ranking's best grasp."""
  _check_grippers(policy.policies)
  policy = _shared_instances(observation, policy)
  names, actions = _plan_all(key, observation, policy.policies, samples)
  best = {name: jnp.where(a.valid, a.probability, 0.0) for name, a in zip(names, actions)}
  index = composite_heuristic_choice(best[GRIPPERS[1]], best[GRIPPERS[0]], policy.suction_threshold)
  return _finish(select_action(actions, index), names, actions, samples)


def plan_grasp(key: jax.Array, observation: Observation, policy: Any, samples: bool = False) -> GraspAction:
  """Any policy of `dexjax.policy` on one observation: ``policy(key, observation, samples)``. Jit with
  ``static_argnames='samples'``; `vmap` over keys and observations to plan many images at once."""
  return policy(key, observation, samples)


__all__ = ['GreedyComposite', 'HeuristicComposite', 'RandomComposite', 'greedy_composite_policy',
           'heuristic_composite_policy', 'plan_grasp', 'random_composite_policy']
