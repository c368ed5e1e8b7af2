"""One MuJoCo model per heap: the bin, a ground plane, and each object as a free body of convex mesh hulls.

Physics settings (`SettleSettings`, shared by both settling backends):

* timestep 4 ms (at 2 ms, 10-object heaps did not settle within 500 steps), implicit-fast integrator, Newton
  solver, pyramidal friction cones, condim 6 (sliding, torsional 5 mm and rolling 2 mm friction, so that
  round objects stop rolling; ``rolling_friction=0`` gives condim 3, sliding friction only);
* soft contacts with solref 0.01 s, damping ratio 1 (MuJoCo's default of 0.02 s let wedged objects rest up
  to 6 mm deep) and MuJoCo's default solimp (0.9 / 0.95 / 1 mm), with
  ``impratio`` 10 (friction 10x harder than the normal direction: objects stop creeping and rocking);
* friction: object geoms carry their heap state's friction and a higher contact priority than the bin, so an
  object-bin contact uses exactly the object's coefficient and an object-object contact the larger of the two
  (MuJoCo's rule for equal priorities);
* explicit body inertia from `HeapObject` (never from the hulls, which may overlap);
* collision geometry that nothing tunnels through: the bin floor is a ground plane at z = 0 (a half-space,
  so a thin disc landing flat at 1.7 m/s cannot pass through it as it did through a 1 cm floor slab), which
  also catches objects that leave the bin (they rest beside it and are flagged); the walls are boxes of the
  bin's wall thickness (objects meet them sideways and slowly, so they do not tunnel).

Drop poses: the seed drops each object at z = 0.15 m; all objects of a heap are released at once here, so two
sampled drop poses may intersect. `drop_poses` keeps every x, y and orientation and raises an object (in slot
order) until its world-axis-aligned bounding box clears the bin and every earlier object's box by
``settings.drop_gap``; objects that do not overlap anything keep z = 0.15 m exactly.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
from flax import struct

from dexjax.geometry.transforms import quat_to_matrix
from dexjax.sim.bodies import HeapObject
from dexjax.sim.heap import Bin, HeapState

_OBJECT_PRIORITY = 1


@struct.dataclass
class SettleSettings:
  """Scene physics, stopping criteria and backend options of `dexjax.sim.settle` (all static).

  Attributes:
    bin: the bin's geometry.
    timestep: physics step, seconds.
    max_steps: stop after this many steps even if objects still move (seed: 500).
    linear_speed_tol: an object rests when its centre-of-mass speed is below this, m/s (seed: 0.005) ...
    angular_speed_tol: ... and its angular speed below this, rad/s (seed: 0.1).
    chunk_steps: steps simulated between speed checks of the `rollout` backend (the step at which a heap first
      rests is found exactly from the per-step states of the chunk, so it changes speed, not results): 50 (was 25)
      halves the Python work per heap for up to 49 steps simulated past its rest; 1.0-1.25x faster measured
      (docs/heaps.md).
    solver_iterations, ls_iterations: constraint solver and line search iterations.
    impratio: ratio of frictional to normal constraint impedance; > 1 makes friction "harder" (less creep
      and jitter at rest) without deeper contacts. 10 settled all 64 benchmark heaps of 10 objects vs. 91 %
      at MuJoCo's default of 1, in 20 % fewer steps.
    drop_gap: vertical clearance between raised drop bounding boxes, metres.
    rolling_friction: rolling friction coefficient of object contacts, metres (MuJoCo's units: the resisting
      torque is this times the normal force); > 0 switches contacts to condim 6 (with ``torsional_friction``),
      so that spheres, cylinders and discs stop rolling; 0 keeps condim 3 (sliding friction only). Default
      2 mm: over 64 heaps of 30 procedural objects per level, heaps with an object still moving at 500 steps
      fell from 6 / 2 / 5 (levels 1 / 2 / 3) at 0 to 0 / 0 / 3, at the same cost.
    torsional_friction: torsional friction coefficient, metres (used only when ``rolling_friction`` > 0).
    contact_timeconst: time constant of every contact's soft constraint (MuJoCo ``solref[0]``), seconds, with
      damping ratio 1; keep it >= 2 timesteps. 0.01 s (MuJoCo's default is 0.02 s): over 64 heaps per object
      set the deepest resting penetration fell from 5.8 to 0.6 mm, at the same number of steps.
    sleep: let objects at rest sleep (MuJoCo's ``mjENBL_SLEEP``, the C engine only; MJX runs without it): a
      body whose velocity stays below ``sleep_tolerance`` is taken out of the simulation until a contact with a
      moving body wakes it, so the bottom of a heap stops costing time while the last objects still move.
    sleep_tolerance: MuJoCo's ``sleep_tolerance`` (its default, 1e-3).
    nthread: threads of the `rollout` backend (each settles one heap at a time, so at most this many models and
      `MjData` are in memory); None: ``os.cpu_count()``.
    mjx_batch_size: heaps per compiled `mjx` call (heaps are grouped by object set first).
    mjx_subprocess: run `mjx` settling in a child process (a guard against the batched-LAPACK deadlock seen on
      2-core CPUs, and the only way to enforce a timeout); None: on CPU only.
    mjx_timeout: seconds before the `mjx` child process is killed and `SettleTimeout` raised.
    mjx_single_core: pin the `mjx` child process to one CPU core before JAX starts (what avoided the deadlock).
  """

  bin: Bin = struct.field(pytree_node=False, default=Bin())
  timestep: float = struct.field(pytree_node=False, default=0.004)
  max_steps: int = struct.field(pytree_node=False, default=500)
  linear_speed_tol: float = struct.field(pytree_node=False, default=0.005)
  angular_speed_tol: float = struct.field(pytree_node=False, default=0.1)
  chunk_steps: int = struct.field(pytree_node=False, default=50)
  solver_iterations: int = struct.field(pytree_node=False, default=20)
  ls_iterations: int = struct.field(pytree_node=False, default=10)
  impratio: float = struct.field(pytree_node=False, default=10.0)
  drop_gap: float = struct.field(pytree_node=False, default=0.002)
  rolling_friction: float = struct.field(pytree_node=False, default=0.002)
  contact_timeconst: float = struct.field(pytree_node=False, default=0.01)
  torsional_friction: float = struct.field(pytree_node=False, default=0.005)
  sleep: bool = struct.field(pytree_node=False, default=True)
  sleep_tolerance: float = struct.field(pytree_node=False, default=1e-3)
  nthread: int | None = struct.field(pytree_node=False, default=None)
  mjx_batch_size: int = struct.field(pytree_node=False, default=64)
  mjx_subprocess: bool | None = struct.field(pytree_node=False, default=None)
  mjx_timeout: float = struct.field(pytree_node=False, default=1800.0)
  mjx_single_core: bool = struct.field(pytree_node=False, default=True)

  def validate(self) -> None:
    """Raises ValueError naming the field and the expected value."""
    self.bin.validate()
    for field in ('timestep', 'linear_speed_tol', 'angular_speed_tol', 'mjx_timeout', 'impratio',
                  'contact_timeconst', 'sleep_tolerance'):
      value = getattr(self, field)
      if not (np.isfinite(value) and value > 0):
        raise ValueError(f'SettleSettings.{field}: expected a finite number > 0, got {value!r}')
    for field in ('max_steps', 'chunk_steps', 'solver_iterations', 'ls_iterations', 'mjx_batch_size'):
      value = getattr(self, field)
      if not (isinstance(value, (int, np.integer)) and value >= 1):
        raise ValueError(f'SettleSettings.{field}: expected an int >= 1, got {value!r}')
    for field in ('drop_gap', 'rolling_friction', 'torsional_friction'):
      value = getattr(self, field)
      if not (np.isfinite(value) and value >= 0):
        raise ValueError(f'SettleSettings.{field}: expected a finite number >= 0 (metres), got {value!r}')


def bin_boxes(b: Bin) -> list[tuple[np.ndarray, np.ndarray]]:
  """(centre (3,), half size (3,)) of the floor slab and the four walls, world frame, metres.

  The floor slab is only used to clear drop poses; the model's floor is the ground plane at z = 0.
  """
  hx, hy = 0.5 * b.inner_size[0], 0.5 * b.inner_size[1]
  t, h = b.wall_thickness, b.wall_height
  return [
      (np.array([0.0, 0.0, -0.5 * t]), np.array([hx + t, hy + t, 0.5 * t])),
      (np.array([hx + 0.5 * t, 0.0, 0.5 * h]), np.array([0.5 * t, hy + t, 0.5 * h])),
      (np.array([-hx - 0.5 * t, 0.0, 0.5 * h]), np.array([0.5 * t, hy + t, 0.5 * h])),
      (np.array([0.0, hy + 0.5 * t, 0.5 * h]), np.array([hx, 0.5 * t, 0.5 * h])),
      (np.array([0.0, -hy - 0.5 * t, 0.5 * h]), np.array([hx, 0.5 * t, 0.5 * h])),
  ]


def heap_slots(state: HeapState) -> np.ndarray:
  """Slot indices (m,) of one (unbatched) heap's objects in model body order: sorted by object id.

  Every heap of the same object set gets the same model structure (what `mjx` batching needs).
  """
  mask = np.asarray(state.mask, bool)
  ids = np.asarray(state.object_ids)
  slots = np.flatnonzero(mask)
  return slots[np.argsort(ids[slots], kind='stable')]


def drop_poses(objects: Sequence[HeapObject], state: HeapState, settings: SettleSettings = SettleSettings()
               ) -> tuple[np.ndarray, np.ndarray]:
  """Initial object-frame poses of one (unbatched) heap, with intersecting drops raised (see module doc).

  Returns:
    (positions (P, 3), quaternions (P, 4) wxyz) float64 in slot order: the object frame's origin in the
    world frame, metres (its centre of mass is at the state's drop position, possibly raised); padded slots
    hold zeros and the identity.
  """
  pad = np.asarray(state.mask).shape[0]
  positions, quats = np.zeros((pad, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (pad, 1))
  boxes = bin_boxes(settings.bin)
  lows = [c - s for c, s in boxes]  # every placed box so far (bin parts, then the objects dropped before)
  highs = [c + s for c, s in boxes]
  ids, com_drop = np.asarray(state.object_ids), np.asarray(state.positions, np.float64)
  slots = np.flatnonzero(np.asarray(state.mask, bool))
  q_all = np.array([q / np.linalg.norm(q) for q in np.asarray(state.quaternions, np.float64)[slots]]).reshape(-1, 4)
  rotations = quat_to_matrix(q_all)  # one call for the heap
  gap = settings.drop_gap
  for slot, q, rot in zip(slots, q_all, rotations):
    obj = objects[int(ids[slot])]
    world = obj.vertices_about_com @ rot.T
    lo_rel, hi_rel = world.min(axis=0), world.max(axis=0)
    com = com_drop[slot].copy()
    blo, bhi = np.asarray(lows), np.asarray(highs)
    for _ in range(4 * len(lows) + 4):  # each pass clears at least one box; bounded for safety
      lo, hi = com + lo_rel, com + hi_rel
      hits = (np.all(lo[:2] < bhi[:, :2], axis=1) & np.all(hi[:2] > blo[:, :2], axis=1)
              & (lo[2] < bhi[:, 2] + gap) & (hi[2] > blo[:, 2] - gap))
      if not hits.any():
        break
      com[2] = bhi[hits, 2].max() + gap - lo_rel[2]
    lows.append(com + lo_rel)
    highs.append(com + hi_rel)
    positions[slot] = com - rot @ obj.center_of_mass
    quats[slot] = q
  return positions, quats


_ARENA_GEOMS = 320  # up to this many object geoms, MuJoCo sizes the arena itself (every dataset heap: 10 x 8 hulls)
_ARENA_BYTES_PER_GEOM = 96 * 1024  # above it: 96 KB per geom (25 objects of 64 hulls needed ~20-40 MB at 411 contacts)


def heap_spec(objects: Sequence[HeapObject], state: HeapState, settings: SettleSettings = SettleSettings()
              ) -> mujoco.MjSpec:
  """The MuJoCo spec (not compiled) of one (unbatched) heap: bin, ground plane and the heap's objects as free
  bodies, with the physics options of ``settings``; callers may add bodies (e.g. a gripper) before compiling.

  Bodies follow `heap_slots` order (sorted by object id) and are named ``obj{slot}``, their geoms
  ``obj{slot}_hull{j}``; geom friction is the state's per-object friction; the bin's geoms are ``ground`` and
  ``wall0``-``wall3``. The drop poses are not part of the model: see `initial_qpos`.

  Args:
    objects: the N available objects; ``state.object_ids`` index into it.
    state: one heap's `HeapState` (no batch axis; NumPy or JAX arrays).
    settings: physics settings.

  Raises:
    ValueError: an object id outside range(len(objects)), or invalid settings.
  """
  settings.validate()
  ids, friction = np.asarray(state.object_ids), np.asarray(state.friction, np.float64)
  slots = heap_slots(state)
  bad = [int(ids[s]) for s in slots if not 0 <= ids[s] < len(objects)]
  if bad:
    raise ValueError(f'HeapState.object_ids: expected ids in [0, {len(objects)}) (the available objects), got {bad}')
  spec = mujoco.MjSpec()
  spec.modelname = 'heap'
  geoms = sum(len(objects[int(ids[s])].hulls) for s in slots)
  if geoms > _ARENA_GEOMS:  # MuJoCo's default arena overflows with many hulls in contact (e.g. 25 decomposed objects)
    spec.memory = _ARENA_BYTES_PER_GEOM * geoms
  spec.default.geom.solref = [settings.contact_timeconst, 1.0]
  opt = spec.option
  opt.timestep = settings.timestep
  opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
  opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
  opt.cone = mujoco.mjtCone.mjCONE_PYRAMIDAL
  opt.iterations = settings.solver_iterations
  opt.ls_iterations = settings.ls_iterations
  opt.impratio = settings.impratio
  if settings.sleep:
    opt.enableflags |= mujoco.mjtEnableBit.mjENBL_SLEEP
    opt.sleep_tolerance = settings.sleep_tolerance
  world = spec.worldbody
  world.add_geom(name='ground', type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1], pos=[0, 0, 0])
  for k, (centre, half) in enumerate(bin_boxes(settings.bin)[1:]):
    world.add_geom(name=f'wall{k}', type=mujoco.mjtGeom.mjGEOM_BOX, pos=centre, size=half)
  for slot in slots:
    obj = objects[int(ids[slot])]
    body = world.add_body(name=f'obj{slot}')
    body.add_freejoint()
    body.explicitinertial = True
    body.mass = obj.mass
    body.ipos = obj.center_of_mass
    i = obj.inertia
    body.fullinertia = [i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]]
    mu = float(np.clip(friction[slot], mujoco.mjMINMU, None))
    for j, hull in enumerate(obj.hulls):
      spec.add_mesh(name=f'obj{slot}_hull{j}', uservert=hull.reshape(-1).tolist())
      body.add_geom(name=f'obj{slot}_hull{j}', type=mujoco.mjtGeom.mjGEOM_MESH, meshname=f'obj{slot}_hull{j}',
                    friction=[mu, settings.torsional_friction, settings.rolling_friction],
                    priority=_OBJECT_PRIORITY, condim=6 if settings.rolling_friction > 0 else 3)
  return spec


def compile_heap(spec: mujoco.MjSpec, objects: Sequence[HeapObject], state: HeapState) -> mujoco.MjModel:
  """``spec.compile()`` with MuJoCo's error turned into a ValueError naming the heap's objects."""
  try:
    return spec.compile()
  except ValueError as e:
    ids = np.asarray(state.object_ids)
    names = [objects[int(ids[s])].name for s in heap_slots(state)]
    raise ValueError(f'MuJoCo rejected the heap of objects {names}: {e}') from e


def build_heap_model(objects: Sequence[HeapObject], state: HeapState,
                     settings: SettleSettings = SettleSettings()) -> mujoco.MjModel:
  """The compiled `heap_spec` of one heap (see there; ValueError also when MuJoCo rejects a hull)."""
  return compile_heap(heap_spec(objects, state, settings), objects, state)


def initial_qpos(objects: Sequence[HeapObject], state: HeapState,
                 settings: SettleSettings = SettleSettings()) -> np.ndarray:
  """(7 m,) float64 free-joint positions (xyz, wxyz per body, `heap_slots` order) of the drop poses."""
  positions, quats = drop_poses(objects, state, settings)
  slots = heap_slots(state)
  return np.concatenate([positions[slots], quats[slots]], axis=1).reshape(-1)
