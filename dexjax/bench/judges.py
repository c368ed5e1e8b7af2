"""The judges of a benchmark attempt: did the planned grasp lift exactly one object?

A judge is a callable ``judge(key, action, camera, state) -> (Verdict, state_after or None)``: the action planned
on ``camera``'s image of the bin in ``state``; ``state_after`` is the bin after the attempt when the judge moved
objects (None: untouched).

* `analytic_judge`: the seed's reward S(x, u) on the true bin (`dexjax.bench.analytic_verdict`): the labels' own
  definition; it never disturbs the heap.
* `physics_judge`: the grasp executed in MuJoCo (`dexjax.bench.execute_grasp`): the labels' collision rule, then
  approach, grip, lift, transport to the receptacle, release; it pushes objects around, and what it leaves is the
  next state.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import jax

from dexjax.bench.analytic_judge import analytic_verdict, world_grasp
from dexjax.bench.execution import PhysicsSettings, execute_grasp
from dexjax.bench.world import BinState, PickingWorld
from dexjax.policy.actions import GraspAction
from dexjax.quality.heap_reward import REWARD_FAILURES
from dexjax.render.camera import Camera


@dataclasses.dataclass(frozen=True)
class Verdict:
  """A judge's decision on one attempt.

  Attributes:
    success: exactly one object was lifted and held.
    target_slot: the bin slot of the object the grasp took (or would take); -1 for none.
    reason: ``'none'`` on success, else the failure's name (one of `REWARD_FAILURES` or `PHYSICS_FAILURES`).
    detail: JSON-able numbers of the judge (e.g. the robust probability).
  """

  success: bool
  target_slot: int
  reason: str
  detail: Mapping[str, Any] = dataclasses.field(default_factory=dict)


Judge = Callable[[jax.Array, GraspAction, Camera, BinState], tuple[Verdict, BinState | None]]


def analytic_judge(world: PickingWorld, known_mass: bool = False) -> Judge:
  """The analytic judge of ``world``: the labels' reward on the true bin; it never disturbs the heap.

  The robust quality draws each object's mass as the labels do (labels version 8: the Gamma law centred on the
  object's simulated mass with the seed's relative spread); with ``known_mass`` it uses the simulated mass as it
  is. Default False: the labels' own definition.
  """
  def judge(key: jax.Array, action: GraspAction, camera: Camera, state: BinState):
    scene = world.scene(state, known_mass=known_mass)
    record = jax.device_get(analytic_verdict(key, action, camera, scene, world.params))
    verdict = Verdict(success=bool(record.reward == 1), target_slot=int(record.target_slot),
                      reason=REWARD_FAILURES[int(record.failure)],
                      detail={'robust_probability': float(record.robust_probability)})
    return verdict, None
  return judge


def physics_judge(world: PickingWorld, settings: PhysicsSettings = PhysicsSettings()) -> Judge:
  """The physics judge of ``world``: the grasp executed in MuJoCo with the world's grippers, objects and bin, the
  labels' collision rule and tolerance; the held object is carried to the receptacle beside the bin (a dropped
  one falls back into the bin). A collision leaves the bin untouched (state None)."""
  def judge(key: jax.Array, action: GraspAction, camera: Camera, state: BinState):
    del key  # deterministic
    grasp = jax.device_get(world_grasp(action, camera))
    params = world.params
    gripper = params.suction if action.gripper_name == 'suction' else params.parallel_jaw
    out = execute_grasp(world.bodies, world.models, world.heap_state(state), state.poses, grasp, gripper, settings,
                        params.reward, params.bin, world.scene(state), world.grip_hulls)
    verdict = Verdict(success=out.success, target_slot=out.target_slot, reason=out.reason, detail=out.detail)
    moved = out.detail['sim_seconds'] > 0
    return verdict, (dataclasses.replace(state, poses=out.poses) if moved else None)
  return judge


__all__ = ['Judge', 'Verdict', 'analytic_judge', 'physics_judge']
