"""The analytic judge of a benchmark attempt: the seed's reward S(x, u) on the true simulated heap.

The policy plans on a (noisy) depth image; the judge takes its action to the world frame with the camera that
took the image and scores it on the heap's true object models and poses with the reward the training labels were
made with (`dexjax.quality.heap_reward`): collision-free, exactly one object between the jaws or under the cup,
robust probability over 0.5 (M Monte-Carlo draws). ``target_slot`` names the object the attempt would lift.
"""

from __future__ import annotations

import functools

import jax

from dexjax.generate.labels import LabelParams
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp
from dexjax.policy.actions import GraspAction
from dexjax.quality.heap_reward import HeapScene, RewardRecord, parallel_jaw_heap_reward, suction_heap_reward
from dexjax.render.camera import Camera
from dexjax.sampling.image_grasps import (ImageParallelJawGrasp, ImageSuctionGrasp, parallel_jaw_grasp_3d,
                                          suction_grasp_3d)


def world_grasp(action: GraspAction, camera: Camera) -> ParallelJawGrasp | SuctionGrasp:
  """The world-frame grasp of a concrete (unbatched, host) action planned on ``camera``'s image."""
  if action.gripper_name == 'suction':
    return suction_grasp_3d(camera, ImageSuctionGrasp(center=action.center, angle=action.angle, depth=action.depth,
                                                      approach_angle=action.approach_angle))
  return parallel_jaw_grasp_3d(camera, ImageParallelJawGrasp(center=action.center, angle=action.angle,
                                                             depth=action.depth, width=action.width))


@functools.partial(jax.jit, static_argnames='suction')
def _reward(key: jax.Array, grasp, scene: HeapScene, params: LabelParams, suction: bool) -> RewardRecord:
  if suction:
    return suction_heap_reward(key, grasp, scene, params.bin, params.suction, params.reward,
                               params.suction_perturbations)
  return parallel_jaw_heap_reward(key, grasp, scene, params.bin, params.parallel_jaw, params.reward,
                                  params.parallel_jaw_perturbations)


def analytic_verdict(key: jax.Array, action: GraspAction, camera: Camera, scene: HeapScene,
                     params: LabelParams = LabelParams()) -> RewardRecord:
  """The reward of a planned action on the true heap (one jitted function per gripper and heap size).

  Args:
    key: key of the robust-quality draws.
    action: a valid, concrete `GraspAction` (an invalid one, "no grasp", is a failure decided by the caller).
    camera: the camera of the image the action was planned on.
    scene: the heap's true objects and poses (`HeapScene`).
    params: the grippers, their perturbations, the reward settings and the bin of the labels.

  Returns:
    `RewardRecord`: reward (1 success), robust probability, target slot (-1: no object), failure code.
  """
  grasp = world_grasp(action, camera)
  return _reward(key, grasp, scene, params, action.gripper_name == 'suction')


__all__ = ['analytic_verdict', 'world_grasp']
