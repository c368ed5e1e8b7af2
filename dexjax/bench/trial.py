"""One benchmark trial: fill the bin, then look, plan, judge and pick until the protocol says stop.

Every attempt: render the bin from the trial's camera with sensor noise (`PickingWorld.observe`), turn the image
into the policy's `Observation` as a real cell would (holes inpainted, objects segmented against the empty-bin
image: `dexjax.policy.prepare_observation`), plan (timed), ask every judge for a verdict, and advance the trial
by the chosen judge's: on success the lifted object leaves the bin and the rest settle again; a judge that
disturbed the heap returns its new state. Each attempt is appended to the attempt log with the state after it, so
a trial killed at any point resumes from its last logged attempt with identical verdicts (keys are functions of
the seed, trial and attempt number; only measured times differ).

Judges: `dexjax.bench.judges` (``judge(key, action, camera, state) -> (Verdict, state_after or None)``); a
*planner* is ``planner(key, observation) -> GraspAction`` (concrete), or a policy with ``privileged = True`` (the
supervisor, `dexjax.bench.SupervisorPolicy`) that also reads the true bin.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import jax
import numpy as np

from dexjax.bench.analytic_judge import world_grasp
from dexjax.bench.attempt_log import append_attempt
from dexjax.bench.failure_memory import FailureMemory, aim_point, excluded_pixels, remembered_failures
from dexjax.bench.judges import Judge, Verdict
from dexjax.bench.picking_metrics import MotionModel
from dexjax.bench.protocol import Protocol, stop_reason
from dexjax.bench.world import BinState, PickingWorld
from dexjax.generate.cameras import run_camera
from dexjax.policy.actions import GraspAction
from dexjax.policy.observation import Observation
from dexjax.policy.preprocess import prepare_observation
from dexjax.render.camera import Camera

NO_GRASP = 'no_grasp'
"""Failure reason of an attempt whose policy found no valid grasp (or saw no object), and the stop reason of its
trial."""


Planner = Callable[[jax.Array, Observation], GraspAction]


def trial_key(seed: int, trial: int) -> jax.Array:
  """The key of trial ``trial`` of a benchmark seeded with ``seed`` (the same bins for every policy)."""
  return jax.random.fold_in(jax.random.key(seed), trial)


def trial_camera(world: PickingWorld, key: jax.Array) -> Camera:
  """The camera of the trial of key ``key`` (`trial_key`): drawn from the world's camera distribution."""
  return run_camera(jax.random.fold_in(key, 1), world.config)


def trial_fill(world: PickingWorld, key: jax.Array, count: int,
               object_ids: Sequence[int] | None = None) -> BinState:
  """The bin the trial of key ``key`` (`trial_key`) starts from: ``count`` objects (``object_ids``, default drawn
  from the set) dropped and settled (`PickingWorld.fill`)."""
  return world.fill(jax.random.fold_in(key, 0), count, object_ids=object_ids)


def attempt_keys(key: jax.Array, attempt: int) -> tuple[jax.Array, jax.Array, jax.Array]:
  """The keys of attempt ``attempt`` of the trial of key ``key``: sensor noise, planning and judging (judge ``j``
  of the trial's judges, in their order, draws with ``jax.random.fold_in(judging, j)``)."""
  noise, plan, judge = jax.random.split(jax.random.fold_in(jax.random.fold_in(key, 2), attempt), 3)
  return noise, plan, judge


def _aimed_slot(action: GraspAction, segmentation: np.ndarray) -> int:
  """The slot of the object under the grasp centre in the true segmentation (-1: the bin or nothing)."""
  u, v = (int(round(float(x))) for x in np.asarray(action.center))
  h, w = segmentation.shape
  return int(segmentation[v, u]) if 0 <= v < h and 0 <= u < w and segmentation[v, u] >= 0 else -1


def _plan(planner: Planner, key: jax.Array, depth: np.ndarray, camera: Camera, background: np.ndarray,
          excluded: np.ndarray) -> tuple[GraspAction | None, float]:
  """(the planned action, or None when nothing could be planned; planning seconds incl. preprocessing). No grasp
  is centred on an ``excluded`` (H, W) pixel (the failure memory)."""
  start = time.perf_counter()
  try:
    obs, _ = prepare_observation(depth, camera, background=background)
  except ValueError:  # no object pixel left (or no valid pixel): nothing to plan on
    return None, time.perf_counter() - start
  if excluded.any():
    obs = obs.replace(mask=obs.mask & ~jax.numpy.asarray(excluded))
  action = jax.device_get(planner(key, obs))
  return (action if bool(action.valid) else None), time.perf_counter() - start


def _planner_of(planner: Any, world: PickingWorld, state: BinState, camera: Camera,
                segmentation: np.ndarray) -> Planner:
  """``planner`` itself, or, for a policy that reads the true bin (``privileged``, the supervisor), the planner
  of this attempt's state."""
  if not getattr(planner, 'privileged', False):
    return planner
  from dexjax.bench.supervisor_policy import plan_privileged  # pylint: disable=g-import-not-at-top
  return lambda key, obs: plan_privileged(planner, world, key, obs, state, camera, segmentation)


def _action_fields(action: GraspAction | None) -> dict[str, Any]:
  if action is None:
    return {'gripper': None, 'q': None, 'center': None, 'angle': None, 'depth': None, 'approach_angle': None,
            'width': None}
  return {'gripper': action.gripper_name, 'q': float(action.probability), 'center': np.asarray(action.center).tolist(),
          'angle': float(action.angle), 'depth': float(action.depth), 'approach_angle': float(action.approach_angle),
          'width': float(action.width)}


def run_trial(world: PickingWorld, planner: Planner, judges: Mapping[str, Judge], *, policy: str, trial: int,
              seed: int = 0, advance_by: str = 'analytic', protocol: Protocol = Protocol(),
              motion: MotionModel = MotionModel(), log_path: str | os.PathLike[str] | None = None,
              logged: Sequence[Mapping[str, Any]] = (), memory: FailureMemory = FailureMemory(),
              start: BinState | None = None) -> list[dict[str, Any]]:
  """Runs (or resumes) trial ``trial`` of ``policy``; returns all its attempt records.

  Args:
    world: the bin's objects, physics and renderer.
    planner: the policy, ``planner(key, observation) -> GraspAction``.
    judges: name -> judge; every judge rules on every attempt (its verdict is recorded as ``verdicts[name]``).
    policy: the policy's name (recorded).
    trial: the trial's index; with ``seed``, it fixes the bin, the camera and every attempt's keys.
    advance_by: the judge whose verdict advances the trial (a key of ``judges``).
    protocol: trial settings (objects per trial, stopping rules).
    motion: robot motion-time model (recorded per attempt for picks per hour).
    log_path: attempts are appended here as they end (`dexjax.bench.append_attempt`); None: not logged.
    logged: this trial's records already in the log (from a killed run); the trial continues after them.
    memory: the policy's memory of failed grasps (`FailureMemory`; off by default).
    start: the bin at the trial's start; None (default): ``protocol.objects_per_trial`` objects drawn and dropped
      with the trial's key (`PickingWorld.fill`).

  Raises:
    ValueError: ``advance_by`` is not a judge, or the protocol is invalid.
  """
  protocol.validate()
  if advance_by not in judges:
    raise ValueError(f'advance_by: expected one of the judges {sorted(judges)}, got {advance_by!r}')
  records = [dict(r) for r in logged]
  if records and records[-1]['stop'] is not None:
    return records
  key = trial_key(seed, trial)
  camera = trial_camera(world, key)
  background = world.empty_bin(camera)
  if records:
    state = BinState.from_json(records[-1]['state'])
    failures, start_count = records[-1]['consecutive_failures'], records[-1]['objects_at_start']
  else:
    state = trial_fill(world, key, protocol.objects_per_trial) if start is None else start
    failures = 0
    start_count = state.count
  memory.validate()
  attempt = len(records)
  stop = stop_reason(state.count, attempt, failures, protocol)
  while stop is None:
    k_noise, k_plan, k_judge = attempt_keys(key, attempt)
    clock = time.perf_counter()
    depth, segmentation = world.observe(k_noise, state, camera)
    stages = {'render': time.perf_counter() - clock}
    excluded = excluded_pixels(depth, camera, remembered_failures(records, memory), memory.radius)
    visible = np.where(excluded, -1, segmentation)  # what a privileged planner may aim at
    action, plan_seconds = _plan(_planner_of(planner, world, state, camera, visible), k_plan, depth, camera,
                                 background, excluded)
    stages['plan'] = plan_seconds
    verdicts: dict[str, Verdict] = {}
    after: BinState | None = None
    for name, judge in judges.items():
      if action is None:
        verdicts[name] = Verdict(success=False, target_slot=-1, reason=NO_GRASP)
        continue
      clock = time.perf_counter()
      verdict, disturbed = judge(jax.random.fold_in(k_judge, len(verdicts)), action, camera, state)
      stages[f'judge_{name}'] = time.perf_counter() - clock
      verdicts[name] = verdict
      if name == advance_by:
        after = disturbed
    chosen = verdicts[advance_by]
    aimed = chosen.target_slot if chosen.target_slot >= 0 else (_aimed_slot(action, segmentation) if action else -1)
    object_id = int(state.object_ids[aimed]) if aimed >= 0 else -1
    level = world.levels[object_id] if object_id >= 0 else _bin_level(world, state)
    clock = time.perf_counter()
    if chosen.success:
      base = after if after is not None else state
      state = world.remove(base, chosen.target_slot) if base.mask[chosen.target_slot] else world.settle_again(base)
      failures = 0
    else:
      state = world.settle_again(after) if after is not None else state
      failures += 1
    stages['settle'] = time.perf_counter() - clock
    attempt += 1
    stop = stop_reason(state.count, attempt, failures, protocol) or (NO_GRASP if action is None else None)
    record = {'policy': policy, 'trial': trial, 'attempt': attempt - 1, **_action_fields(action),
              'world_center': None if action is None else np.asarray(world_grasp(action, camera).center).tolist(),
              'aim_point': None if action is None else aim_point(depth, camera, np.asarray(action.center)),
              'objects_at_start': start_count,
              'judge': advance_by, 'success': chosen.success, 'reason': chosen.reason,
              'verdicts': {n: {'success': v.success, 'reason': v.reason, 'target_slot': v.target_slot, **v.detail}
                           for n, v in verdicts.items()},
              'object': world.names[object_id] if object_id >= 0 else None,
              'level': level,
              'plan_seconds': plan_seconds, 'motion_seconds': motion.attempt_seconds(), 'stage_seconds': stages,
              'objects_left': state.count, 'consecutive_failures': failures, 'stop': stop,
              'state': state.to_json()}
    for name in ('analytic', 'physics'):
      record[name] = verdicts[name].success if name in verdicts else None
    if log_path is not None:
      append_attempt(log_path, record)
    records.append(record)
  return records


def _bin_level(world: PickingWorld, state: BinState) -> int | None:
  """The level of an attempt that aimed at no object: the bin's, when all its objects share one, else None."""
  levels = {world.levels[int(i)] for i in state.object_ids[state.mask]}
  return levels.pop() if len(levels) == 1 else None


__all__ = ['NO_GRASP', 'Planner', 'attempt_keys', 'run_trial', 'trial_camera', 'trial_fill', 'trial_key']
