"""What a policy returns: the planned grasp of either gripper in one pytree, its 3-D pose, and (when asked) the
samples the policy scored on the way, for plots.

`GraspAction` holds a grasp of either gripper so that a choice between grippers is a `jnp.where` (the ambidextrous
policy): ``gripper`` indexes `GRIPPERS`; a parallel-jaw action has ``approach_angle`` 0, a suction action
``width`` 0. ``pose`` is the 4 x 4 gripper pose in the camera frame (metres), as `dexjax.grasps`: x = approach,
y = jaw axis (suction: a fixed perpendicular), z = x cross y; for the parallel jaw the origin is the grasp centre
at the gripper depth, for suction the target point on the surface.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.grasps import ParallelJawGrasp, SuctionGrasp, parallel_jaw_pose, suction_pose
from dexjax.policy.observation import Observation
from dexjax.policy.scorers import GRIPPERS, PARALLEL_JAW
from dexjax.sampling.image_grasps import (ImageParallelJawGrasp, ImageSuctionGrasp, approach_from_angles,
                                          camera_point)


@struct.dataclass
class PolicySamples:
  """The grasps a policy scored, per round (round 0: the initial candidates; CEM round i: the i-th resampled set).

  Attributes:
    center: (R, N, 2) pixels (u, v).
    angle: (R, N) in-plane angle, radians.
    depth: (R, N) gripper depth, metres.
    quality: (R, N) score of each grasp (-inf where invalid).
    valid: (R, N) bool; sets smaller than N are padded with invalid entries.
    width: (R, N) jaw opening, metres (0 for suction grasps).
    approach_angle: (R, N) suction approach angle psi from the optical axis, radians (0 for jaw grasps).
  """

  center: jax.Array
  angle: jax.Array
  depth: jax.Array
  quality: jax.Array
  valid: jax.Array
  width: jax.Array
  approach_angle: jax.Array


@struct.dataclass
class GraspAction:
  """A planned grasp (leading axes when batched or stacked per gripper).

  Attributes:
    gripper: () int32 index into `GRIPPERS` (0 parallel jaw, 1 suction).
    center: (2,) grasp centre pixel (u, v) = (column, row).
    angle: () in-plane angle, radians (parallel jaw: the jaw axis; suction: the crop angle of its approach).
    depth: () camera-frame z of the grasp centre (parallel jaw) or target point (suction), metres.
    approach_angle: () angle between the suction approach and the optical axis, radians (0 for the parallel jaw).
    width: () jaw opening, metres (0 for suction).
    pose: (4, 4) gripper pose in the camera frame, metres.
    probability: () the policy's score of the grasp (p(success) for learned scorers).
    valid: () bool; False when the policy found no valid grasp ("no grasp": the other fields are meaningless).
    samples: optional `PolicySamples` (stacked per gripper for multi-gripper policies), when asked for.
    per_gripper: optional `GraspAction` stacked over the grippers a composite policy planned for (leading axis 2,
      in `GRIPPERS` order; ``valid`` False for a gripper it did not plan).
  """

  gripper: jax.Array
  center: jax.Array
  angle: jax.Array
  depth: jax.Array
  approach_angle: jax.Array
  width: jax.Array
  pose: jax.Array
  probability: jax.Array
  valid: jax.Array
  samples: PolicySamples | None = None
  per_gripper: GraspAction | None = None

  @property
  def gripper_name(self) -> str:
    """``'parallel_jaw'`` or ``'suction'`` (concrete, unbatched actions only)."""
    return GRIPPERS[int(self.gripper)]


def action_from_grasp(observation: Observation, grasp: ImageParallelJawGrasp | ImageSuctionGrasp,
                      probability: jax.Array, valid: jax.Array) -> GraspAction:
  """The `GraspAction` of one image grasp (unbatched) with its camera-frame pose."""
  point = camera_point(observation.camera, grasp.center, grasp.depth)
  zero = jnp.zeros((), jnp.float32)
  if isinstance(grasp, ImageSuctionGrasp):
    pose = suction_pose(SuctionGrasp(center=point, approach=approach_from_angles(grasp.angle, grasp.approach_angle)))
    return GraspAction(gripper=jnp.int32(1), center=grasp.center, angle=grasp.angle, depth=grasp.depth,
                       approach_angle=grasp.approach_angle, width=zero, pose=pose, probability=probability,
                       valid=valid)
  axis = jnp.stack([jnp.cos(grasp.angle), jnp.sin(grasp.angle), zero])
  pose = parallel_jaw_pose(ParallelJawGrasp(center=point, axis=axis, approach=jnp.array([0.0, 0.0, 1.0]),
                                            width=grasp.width))
  return GraspAction(gripper=jnp.int32(GRIPPERS.index(PARALLEL_JAW)), center=grasp.center, angle=grasp.angle,
                     depth=grasp.depth, approach_angle=zero, width=jnp.asarray(grasp.width, jnp.float32), pose=pose,
                     probability=probability, valid=valid)


def _core(action: GraspAction) -> GraspAction:
  return action.replace(samples=None, per_gripper=None)


def stack_actions(actions: list[GraspAction]) -> GraspAction:
  """The actions' fields (without samples or per-gripper actions) stacked along a new leading axis."""
  return jax.tree.map(lambda *xs: jnp.stack(xs), *[_core(a) for a in actions])


def select_action(actions: list[GraspAction], index: jax.Array) -> GraspAction:
  """``actions[index]`` for a traced int ``index`` (fields without samples or per-gripper actions)."""
  return jax.tree.map(lambda x: x[index], stack_actions(actions))


def best_action(actions: list[GraspAction]) -> tuple[GraspAction, jax.Array]:
  """The valid action of highest probability (the first on ties; the first action if none is valid) and its index."""
  stacked = stack_actions(actions)
  index = jnp.argmax(jnp.where(stacked.valid, stacked.probability, -jnp.inf))
  return jax.tree.map(lambda x: x[index], stacked), index


def samples_of(grasps, quality: jax.Array, valid: jax.Array) -> PolicySamples:
  """One round (R = 1) of N scored image grasps (leading axis N) as `PolicySamples`."""
  zeros = jnp.zeros_like(grasps.depth)
  return PolicySamples(center=grasps.center[None], angle=grasps.angle[None], depth=grasps.depth[None],
                       quality=quality[None], valid=valid[None], width=getattr(grasps, 'width', zeros)[None],
                       approach_angle=getattr(grasps, 'approach_angle', zeros)[None])


def pad_samples(samples: PolicySamples, rounds: int, size: int) -> PolicySamples:
  """``samples`` padded with invalid entries to R = ``rounds`` rounds of N = ``size`` grasps."""
  r, n = samples.valid.shape
  pad = lambda x, fill: jnp.pad(x, [(0, rounds - r), (0, size - n)] + [(0, 0)] * (x.ndim - 2), constant_values=fill)
  return PolicySamples(center=pad(samples.center, 0.0), angle=pad(samples.angle, 0.0), depth=pad(samples.depth, 0.0),
                       quality=pad(samples.quality, -jnp.inf), valid=pad(samples.valid, False),
                       width=pad(samples.width, 0.0), approach_angle=pad(samples.approach_angle, 0.0))


__all__ = ['GraspAction', 'PolicySamples', 'action_from_grasp', 'best_action', 'pad_samples', 'samples_of',
           'select_action', 'stack_actions']
