"""Physics settling of dropped heaps: one interface, two backends.

`settle` simulates each heap from its drop poses until every object rests (centre-of-mass speed below
0.005 m/s and angular speed below 0.1 rad/s, checked after every step) or 500 steps have run (seed, "State
Distribution"), and returns the final poses with per-object flags: *left the bin* and *never settled*. Objects
are flagged, never dropped.

Backends:

* ``'rollout'``: the MuJoCo C engine through `mujoco.rollout`, one `MjData` per heap (heaps with different
  meshes must not share an `MjData`: that silently produced NaN states), each of ``nthread`` Python threads
  (MuJoCo releases the GIL) taking the next heap and simulating it ``chunk_steps`` steps per call until it rests;
  the solver warm start is carried across calls, so chunking does not change the trajectory. Each heap is
  simulated on its own, so the same states give bitwise the same result whatever the thread count. Objects at
  rest sleep (``SettleSettings.sleep``).
* ``'mjx'``: MuJoCo MJX, ``jax.jit(jax.vmap(...))`` over heaps that share one object set (see
  `dexjax.sim.mjx_backend`), run in a pinned child process on CPU.
* ``'auto'``: ``'rollout'`` when ``jax.default_backend() == 'cpu'`` (the C engine is ~100x faster there),
  ``'mjx'`` on GPU/TPU.

The rest test of both backends (`resting`, `object_speeds`, `rotate`) lives in `dexjax.sim.rest` and the MJX
child's `SettleTimeout` in `dexjax.sim.mjx_backend` (which imports `mujoco.mjx` only when it compiles); both are
re-exported here.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import jax
import mujoco
import numpy as np
from flax import struct
from mujoco import rollout as mj_rollout

from dexjax.sim import mjx_backend
from dexjax.sim.bodies import HeapObject
from dexjax.sim.heap import HeapState, select_heap
from dexjax.sim.mjx_backend import SettleTimeout
from dexjax.sim.rest import cross, object_speeds, resting, rotate
from dexjax.sim.scene import SettleSettings, build_heap_model, drop_poses, heap_slots

BACKENDS = ('auto', 'rollout', 'mjx')
_BAD_STATE_WARNINGS = (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
                       mujoco.mjtWarning.mjWARN_BADQACC)


@struct.dataclass
class SettleResult:
  """Settled heaps, padded like the input states: B heaps of P slots (NumPy arrays).

  Attributes:
    poses: (B, P, 7) float64 final object-frame poses in the world frame: position (metres) then unit
      quaternion (w, x, y, z); padded slots hold zeros and the identity quaternion.
    centers: (B, P, 3) float64 final centre-of-mass positions, world frame, metres.
    velocities: (B, P, 6) float64 final centre-of-mass velocity (m/s) and angular velocity (rad/s), world frame.
    initial_poses: (B, P, 7) float64 drop poses actually simulated (intersecting drops raised, see
      `dexjax.sim.drop_poses`).
    mask: (B, P) bool, the heap's objects (a copy of ``states.mask``).
    left_bin: (B, P) bool, the centre of mass ended outside the bin's inner box or below its floor.
    never_settled: (B, P) bool, the object still moved when its heap stopped at ``max_steps`` (or the heap
      diverged).
    steps: (B,) int32 steps simulated per heap (the first step at which every object rested, or max_steps).
    settled: (B,) bool, every object of the heap rested (``steps <= max_steps`` and no ``never_settled``).
    diverged: (B,) bool, the simulation produced NaN or MuJoCo's bad-state warnings (poses are not valid).
    backend: the backend that ran (``'rollout'`` or ``'mjx'``).
  """

  poses: np.ndarray
  centers: np.ndarray
  velocities: np.ndarray
  initial_poses: np.ndarray
  mask: np.ndarray
  left_bin: np.ndarray
  never_settled: np.ndarray
  steps: np.ndarray
  settled: np.ndarray
  diverged: np.ndarray
  backend: str = struct.field(pytree_node=False, default='rollout')

  def summary(self) -> dict[str, Any]:
    """Counts over the batch (plain Python numbers, JSON-ready): heaps, objects, settled heaps, objects that
    left the bin or never settled, diverged heaps, and the mean and largest steps."""
    return {'backend': self.backend, 'heaps': int(len(self.steps)), 'objects': int(self.mask.sum()),
            'settled_heaps': int(self.settled.sum()), 'left_bin': int(self.left_bin.sum()),
            'never_settled': int(self.never_settled.sum()), 'diverged_heaps': int(self.diverged.sum()),
            'mean_steps': float(np.mean(self.steps)) if len(self.steps) else 0.0,
            'max_steps': int(np.max(self.steps)) if len(self.steps) else 0}


def _first_rest(qpos: np.ndarray, qvel: np.ndarray, centers_of_mass: np.ndarray, settings: SettleSettings) -> int:
  """Index of the first step (rows of ``qpos`` (n, m, 7), ``qvel`` (n, m, 6)) at which every object rests
  (`resting`), or -1. Steps are screened first with a necessary condition (a third of `resting`'s time on a
  chunk of 50 steps in which nothing rests, most chunks of a heap): the angular speed test itself, and
  ``|v| - |omega| |c| < linear_speed_tol`` (the centre of mass moves at least that fast, since
  ``|omega x c| <= |omega| |c|``, with ``c`` the (m, 3) ``centers_of_mass``; a 1e-9 m/s margin covers rounding);
  `resting` then decides on the steps that pass, so the result is `resting`'s, bit for bit."""
  omega = np.linalg.norm(qvel[..., 3:], axis=-1)
  slowest = np.linalg.norm(qvel[..., :3], axis=-1) - omega * np.linalg.norm(centers_of_mass, axis=-1)
  candidates = np.flatnonzero(np.all((omega < settings.angular_speed_tol)
                                     & (slowest < settings.linear_speed_tol + 1e-9), axis=1))
  if not candidates.size:
    return -1
  rest = np.all(resting(qpos[candidates], qvel[candidates], centers_of_mass, settings), axis=1)
  return int(candidates[np.argmax(rest)]) if rest.any() else -1


def _batched(states: HeapState) -> HeapState:
  """NumPy copy of ``states`` with a leading batch axis (added when a single heap is given)."""
  states = jax.device_get(states)
  states = jax.tree.map(np.asarray, states)
  if states.mask.ndim == 1:
    states = jax.tree.map(lambda x: x[None], states)
  if states.mask.ndim != 2:
    raise ValueError(f'settle: states.mask: expected shape (P,) or (B, P), got {states.mask.shape}')
  return states


def _coms(objects: Sequence[HeapObject], state: HeapState) -> np.ndarray:
  """(m, 3) centres of mass of one heap's bodies, object frames, in `heap_slots` order."""
  ids = np.asarray(state.object_ids)
  return np.stack([objects[int(ids[s])].center_of_mass for s in heap_slots(state)])


def _check_ids(objects: Sequence[HeapObject], states: HeapState) -> None:
  ids = states.object_ids[states.mask]
  bad = sorted(set(int(i) for i in ids if not 0 <= i < len(objects)))
  if bad:
    raise ValueError(f'settle: states.object_ids: expected ids in [0, {len(objects)}) (the available objects), '
                     f'got {bad}')


def finish(objects: Sequence[HeapObject], states: HeapState, qpos: list[np.ndarray], qvel: list[np.ndarray],
           steps: np.ndarray, diverged: np.ndarray, settings: SettleSettings, backend: str,
           drops: Sequence[np.ndarray] | None = None) -> SettleResult:
  """Pads per-heap final states into a `SettleResult` and computes the flags (shared by both backends).

  Args:
    objects, states: as given to `settle` (states batched, NumPy).
    qpos, qvel: per heap, (m_b, 7) and (m_b, 6) final free-joint states in `heap_slots` order.
    steps: (B,) steps simulated; diverged: (B,) bool.
    settings, backend: as `settle` ran.
    drops: per heap, the (P, 7) drop poses (`drop_poses` as position and quaternion) if already computed.
  """
  batch, pad = states.mask.shape
  poses = np.zeros((batch, pad, 7))
  poses[..., 3] = 1.0
  centers = np.zeros((batch, pad, 3))
  velocities = np.zeros((batch, pad, 6))
  initial = np.zeros((batch, pad, 7))
  never = np.zeros((batch, pad), bool)
  diverged = np.asarray(diverged, bool).copy()
  hx, hy = 0.5 * settings.bin.inner_size[0], 0.5 * settings.bin.inner_size[1]
  for b in range(batch):
    state = select_heap(states, b)
    slots, coms = heap_slots(state), _coms(objects, state)
    q, v = np.asarray(qpos[b], np.float64).reshape(-1, 7), np.asarray(qvel[b], np.float64).reshape(-1, 6)
    diverged[b] |= not (np.all(np.isfinite(q)) and np.all(np.isfinite(v)))
    quat = q[:, 3:] / np.maximum(np.linalg.norm(q[:, 3:], axis=1, keepdims=True), 1e-12)
    poses[b, slots] = np.concatenate([q[:, :3], quat], axis=1)
    centers[b, slots] = q[:, :3] + rotate(quat, coms)
    velocities[b, slots, :3] = v[:, :3] + rotate(quat, cross(v[:, 3:], coms))
    velocities[b, slots, 3:] = rotate(quat, v[:, 3:])
    never[b, slots] = diverged[b] | ~resting(q, v, coms, settings)
    initial[b] = _drop_vector(objects, state, settings) if drops is None else drops[b]
  mask = states.mask.astype(bool)
  left = mask & ((np.abs(centers[..., 0]) > hx) | (np.abs(centers[..., 1]) > hy) | (centers[..., 2] < 0.0)
                 | ~np.all(np.isfinite(centers), axis=-1))
  never &= mask
  settled = ~np.any(never, axis=1) & ~diverged
  return SettleResult(poses=poses, centers=centers, velocities=velocities, initial_poses=initial, mask=mask,
                      left_bin=left, never_settled=never, steps=np.asarray(steps, np.int32), settled=settled,
                      diverged=diverged, backend=backend)


def _drop_vector(objects: Sequence[HeapObject], state: HeapState, settings: SettleSettings) -> np.ndarray:
  """(P, 7) `drop_poses` of one heap as position and quaternion per slot."""
  positions, quats = drop_poses(objects, state, settings)
  return np.concatenate([positions, quats], axis=1)


class _RolloutHeap:
  """One heap on the C engine: its own model, `MjData`, state vector and warm start."""

  def __init__(self, objects: Sequence[HeapObject], state: HeapState, settings: SettleSettings,
               start: np.ndarray | None = None):
    self.model = build_heap_model(objects, state, settings)
    self.data = mujoco.MjData(self.model)
    self.drop = _drop_vector(objects, state, settings)
    poses = self.drop if start is None else np.asarray(start, np.float64)  # (P, 7) in slot order
    self.data.qpos[:] = poses[heap_slots(state)].reshape(-1)
    self.coms = _coms(objects, state)
    self.spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    self.state = np.empty(mujoco.mj_stateSize(self.model, self.spec))
    mujoco.mj_getState(self.model, self.data, self.state, self.spec)
    self.warmstart = np.zeros(self.model.nv)
    self.steps, self.done, self.diverged = 0, False, False

  def advance(self, nstep: int, settings: SettleSettings) -> None:
    """Simulates up to ``nstep`` steps, stopping at the first step at which every object rests."""
    m = self.model
    traj, _ = mj_rollout.rollout(m, self.data, self.state[None], nstep=nstep,
                                 initial_warmstart=self.warmstart[None])
    traj = traj[0]
    qpos = traj[:, 1:1 + m.nq].reshape(nstep, -1, 7)
    qvel = traj[:, 1 + m.nq:1 + m.nq + m.nv].reshape(nstep, -1, 6)
    warnings = sum(self.data.warning[w].number for w in _BAD_STATE_WARNINGS)
    if warnings or not np.all(np.isfinite(traj)):
      self.diverged, self.done = True, True
      self.state, self.steps = traj[-1], self.steps + nstep
      return
    first = _first_rest(qpos, qvel, self.coms, settings)
    if first >= 0:
      self.state, self.steps, self.done = traj[first], self.steps + first + 1, True
    else:
      self.state, self.steps = traj[-1], self.steps + nstep
      self.warmstart = np.array(self.data.qacc_warmstart)

  def final(self) -> tuple[np.ndarray, np.ndarray]:
    m = self.model
    return self.state[1:1 + m.nq], self.state[1 + m.nq:1 + m.nq + m.nv]


def _settle_one(objects: Sequence[HeapObject], state: HeapState, settings: SettleSettings,
                start: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, int, bool, np.ndarray]:
  """One heap from its drop (or ``start``) poses until it rests or ``max_steps``, ``chunk_steps`` at a time:
  (final qpos, final qvel, steps, diverged, drop poses); its model and `MjData` are freed on return."""
  heap = _RolloutHeap(objects, state, settings, start)
  while not heap.done and heap.steps < settings.max_steps:  # steps: simulated so far, until the heap is done
    heap.advance(min(settings.chunk_steps, settings.max_steps - heap.steps), settings)
  return (*heap.final(), heap.steps, heap.diverged, heap.drop)


def _settle_rollout(objects: Sequence[HeapObject], states: HeapState, settings: SettleSettings,
                    start_poses: np.ndarray | None = None) -> SettleResult:
  """Each thread takes the next heap and settles it to the end, so that one thread's model building and resting
  checks (Python, holding the GIL) overlap the other threads' MuJoCo steps (which release it); a heap's model and
  `MjData` live only while it is simulated."""
  nthread = settings.nthread or os.cpu_count() or 1
  with ThreadPoolExecutor(max_workers=nthread) as pool:
    out = list(pool.map(lambda b: _settle_one(objects, select_heap(states, b), settings,
                                              None if start_poses is None else start_poses[b]),
                        range(states.mask.shape[0])))
  qpos, qvel, steps, diverged, drops = zip(*out) if out else ((), (), (), (), ())
  return finish(objects, states, list(qpos), list(qvel), np.array(steps, np.int32), np.array(diverged, bool),
                settings, 'rollout', list(drops))


def _start_poses(states: HeapState, start_poses: Any) -> np.ndarray:
  """``start_poses`` as (B, P, 7) float64 with unit quaternions; ValueError if its shape or values are wrong."""
  poses = np.asarray(start_poses, np.float64)
  if poses.ndim == 2:
    poses = poses[None]
  if poses.shape != (*states.mask.shape, 7):
    raise ValueError(f'settle: start_poses: expected shape {(*states.mask.shape, 7)} (heaps, slots, xyz + wxyz), '
                     f'got {np.shape(start_poses)}')
  used = poses[states.mask.astype(bool)]
  if not np.all(np.isfinite(used)) or np.any(np.linalg.norm(used[:, 3:], axis=1) < 1e-9):
    raise ValueError('settle: start_poses: expected finite poses with non-zero quaternions in every used slot')
  poses = poses.copy()
  poses[..., 3:] /= np.maximum(np.linalg.norm(poses[..., 3:], axis=-1, keepdims=True), 1e-12)
  return poses


def default_backend() -> str:
  """The backend ``'auto'`` resolves to: ``'rollout'`` on CPU, ``'mjx'`` on an accelerator."""
  return 'rollout' if jax.default_backend() == 'cpu' else 'mjx'


def settle(objects: Sequence[HeapObject], states: HeapState, *, backend: str = 'auto',
           settings: SettleSettings = SettleSettings(), start_poses: Any = None) -> SettleResult:
  """Drops and settles heaps; returns final poses and per-object flags.

  With ``start_poses`` the heaps start at rest from those poses instead of their drop poses: a heap that was
  disturbed (an object removed, a failed grasp) settles again (``initial_poses`` of the result are then the
  start poses).

  Args:
    objects: the N available objects (``states.object_ids`` index into this sequence).
    states: `HeapState` with a leading batch axis B (e.g. from ``jax.vmap(sample_heap_state)``), or a single
      heap (then B = 1).
    backend: ``'auto'``, ``'rollout'`` (MuJoCo C engine, threads) or ``'mjx'`` (MuJoCo MJX).
    settings: physics, stopping criteria and backend options.
    start_poses: optional (B, P, 7) (or (P, 7) for a single heap) object-frame poses (xyz, wxyz) to start from,
      padded like ``states``; the ``'rollout'`` backend only.

  Returns:
    A `SettleResult` (NumPy arrays, padded like ``states``).

  Raises:
    ValueError: unknown backend, bad settings, object ids outside range(len(objects)), or ``start_poses`` of
      the wrong shape, not finite, or with the ``'mjx'`` backend.
    SettleTimeout: the ``mjx`` child process exceeded ``settings.mjx_timeout``.
  """
  if backend not in BACKENDS:
    raise ValueError(f"settle: backend: expected one of {', '.join(map(repr, BACKENDS))}, got {backend!r}")
  settings.validate()
  states = _batched(states)
  _check_ids(objects, states)
  if backend == 'auto':
    backend = default_backend()
  if start_poses is not None:
    start_poses = _start_poses(states, start_poses)
    if backend != 'rollout':
      raise ValueError(f"settle: start_poses: supported by the 'rollout' backend only, got backend {backend!r}")
  if backend == 'rollout':
    result = _settle_rollout(objects, states, settings, start_poses)
    return result if start_poses is None else result.replace(initial_poses=np.where(
        states.mask[..., None], start_poses, result.initial_poses))
  settings = settings.replace(sleep=False)  # MJX does not put bodies to sleep: say so in the settings it ran
  raw = mjx_backend.run(objects, states, settings)
  return finish(objects, states, raw['qpos'], raw['qvel'], raw['steps'], raw['diverged'], settings, 'mjx')


__all__ = ['BACKENDS', 'SettleResult', 'SettleTimeout', 'default_backend', 'finish', 'object_speeds', 'resting',
           'rotate', 'settle']
