"""The physics judge of a benchmark attempt: the grasp executed in MuJoCo on the simulated bin.

The heap's MuJoCo model (`dexjax.sim.heap_spec`: the bin and every object as a free body of convex hulls, with the
heap's own contact settings) gets the gripper (`dexjax.bench.gripper_bodies`), and the tool follows the pick's path
(`dexjax.bench.tool_path`): from a pre-grasp pose ``standoff`` behind the grasp along the approach (further back, in
5 cm steps, while the tool would start inside an object), to the grasp, grip, lift 0.2 m, transport to above the
bin's centre, shake, hold. The approach is force-guarded, as a real cell's: it stops where the contact force
pushing the gripper back (objects or bin) first exceeds ``guard_force`` (a suction approach may go on
``press_depth`` past the planned point, to press the compliant cup onto the surface). Collisions with other objects and the bin are real: objects
are pushed, and a gripper pressing on the bin harder than ``bin_force_limit`` during the approach or the grip
fails the attempt (``collision_bin``: a real robot would stop).

* **Parallel jaw**: the pads close with force-limited servos (the gripper's ``force_limit``); friction is the
  object's Coulomb coefficient with the soft-finger torsional friction (2/3) mu r_f (condim 4).
* **Suction**: MuJoCo cannot model the compliant lip, so the seal is the analytic one (`dexjax.contacts.
  suction_seal`, Dex-Net 3.0's spring model) at the actual contact: where the cup's axis meets the first object
  (a ray from inside the cup; the mouth may have pressed up to the bellows' height into it, or stopped up to the
  contact tolerance short), in the object's simulated pose, along the cup's simulated axis after the guarded
  approach. A sealed cup holds
  the object with a weld whose wrench is checked every step against the suction-ring limits of the same contact
  model (spec "Linear constraint set"): the pull at most the vacuum force V, the shear and the torsion within
  friction of the lip load (f_z + V), the bending torque within pi r kappa / sqrt 2. A limit exceeded for
  ``seal_break_steps`` consecutive steps breaks the seal (the weld lets go): at most the vacuum force holds.

The verdict: success when exactly one object ends the path at least ``min_lift`` above where it started, held
(between both pads, or sealed). Failure reasons: `PHYSICS_FAILURES`. The returned state holds every object's pose at
the end (or where the attempt stopped): the judge disturbs the heap, and the trial lets it settle again.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import jax
import mujoco
import numpy as np

from dexjax.bench import gripper_bodies as gb
from dexjax.bench.tool_path import PHASES, PathSettings, tool_path
from dexjax.contacts.suction import suction_seal
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp, parallel_jaw_pose, suction_pose
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.geometry.object_model import ObjectModel
from dexjax.quality.gripper_geometry import GripperGeometry
from dexjax.sim.bodies import HeapObject
from dexjax.sim.heap import HeapState
from dexjax.sim.scene import SettleSettings, compile_heap, heap_slots, heap_spec

PHYSICS_FAILURES = ('none', 'collision_bin', 'no_object', 'no_seal', 'seal_lost', 'dropped', 'multiple_objects')
"""Failure reasons of the physics judge: the gripper pressed on the bin; nothing between the closed jaws (or under
the cup); the analytic seal test failed at the actual contact; a suction-ring limit broke the hold; the object was
lost during the lift, transport or shake; more than one object was lifted."""

RING_LIMITS = ('vacuum', 'friction', 'torsion', 'bending')
_BIN_GEOMS = ('ground', 'wall0', 'wall1', 'wall2', 'wall3')


@dataclasses.dataclass(frozen=True)
class PhysicsSettings:
  """Settings of the physics judge (SI units).

  Attributes:
    timestep: physics step, s (2 ms).
    solver_iterations: constraint solver iterations (Newton).
    noslip_iterations: MuJoCo noslip iterations (friction without creep: a held object does not slide out).
    impratio: frictional-to-normal constraint impedance ratio (elliptic cones).
    standoff: distance of the pre-grasp pose behind the grasp along the approach, m (the analytic reward's sweep).
    max_standoff: the tool starts at most this far back when the pre-grasp pose is inside an object, m.
    guard_force: the approach stops once contacts push the gripper back along the approach with this force, N.
    guard_retract: when the guard stops the approach, the tool backs off this much along it, m.
    press_depth: the suction approach may go on this far past the planned point, m.
    bin_force_limit: contact force of the gripper on the bin (floor or walls) that fails the attempt, N (a
      fingertip may touch the floor: the analytic reward allows 1 mm; a robot's collision detection stops it
      at a few tens of newtons).
    min_lift: an object counts as lifted when its centre of mass ends this much higher than it started, m.
    seal_break_steps: consecutive steps over a suction-ring limit that break the seal.
    path: the tool's motions (`PathSettings`).
    tool: the tool bodies' constants (`ToolSettings`).
  """

  timestep: float = 0.002
  solver_iterations: int = 50
  noslip_iterations: int = 5
  impratio: float = 10.0
  standoff: float = 0.05
  max_standoff: float = 0.3
  guard_force: float = 10.0
  guard_retract: float = 0.001
  press_depth: float = 0.005
  bin_force_limit: float = 50.0
  min_lift: float = 0.1
  seal_break_steps: int = 5
  path: PathSettings = PathSettings()
  tool: gb.ToolSettings = gb.ToolSettings()


@dataclasses.dataclass(frozen=True)
class PhysicsOutcome:
  """What happened to one executed grasp.

  Attributes:
    success: exactly one object lifted and held.
    reason: ``'none'`` or one of `PHYSICS_FAILURES`.
    target_slot: the slot of the object held (or gripped and lost; -1 for none).
    poses: (P, 7) float64 object-frame poses of every slot at the end (unused slots unchanged).
    detail: JSON-able numbers: ``phase`` where the attempt ended, ``lifted`` slots, for suction ``sealed``,
      ``max_strain`` and the ``limit`` that broke the hold, ``sim_seconds`` simulated.
  """

  success: bool
  reason: str
  target_slot: int
  poses: np.ndarray
  detail: dict[str, Any]


_seal = jax.jit(suction_seal)


def _quat(matrix: np.ndarray) -> np.ndarray:
  q = np.zeros(4)
  mujoco.mju_mat2Quat(q, np.ascontiguousarray(matrix, np.float64).reshape(-1))
  return q


class _Sim:
  """One heap with one tool in MuJoCo, and the bookkeeping the verdict needs."""

  def __init__(self, objects: Sequence[HeapObject], heap: HeapState, poses: np.ndarray, pose: np.ndarray,
               grasp: ParallelJawGrasp | SuctionGrasp, gripper, settings: PhysicsSettings,
               geometry: GripperGeometry):
    self.settings, self.suction = settings, isinstance(grasp, SuctionGrasp)
    self.contact_point, self.contact_offset = None, np.zeros(3)  # suction: the sealed contact (world, hand frame)
    spec = heap_spec(objects, heap, SettleSettings(timestep=settings.timestep, impratio=settings.impratio,
                                                   solver_iterations=settings.solver_iterations))
    opt = spec.option
    opt.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    opt.noslip_iterations = settings.noslip_iterations
    self.slots = heap_slots(heap)
    friction = np.asarray(heap.friction, np.float64)
    ids = np.asarray(heap.object_ids)
    hulls = [(f'obj{s}_hull{j}', max(float(friction[s]), mujoco.mjMINMU))
             for s in self.slots for j in range(len(objects[int(ids[s])].hulls))]
    if self.suction:
      gb.add_suction_cup(spec, pose, gripper, geometry, settings.tool)
      gb.add_vacuum(spec, [f'obj{s}' for s in self.slots], settings.tool)
      tool_geoms = [gb.CUP, gb.SHAFT]
    else:
      self.stroke = 0.5 * float(grasp.width) + settings.tool.close_overtravel
      gb.add_parallel_jaw(spec, pose, float(grasp.width), gripper, settings.tool)
      tool_geoms = [gb.PALM, *gb.FINGERS]
    gb.add_gripper_pairs(spec, tool_geoms, hulls, _BIN_GEOMS,
                         (2.0 / 3.0) * float(getattr(gripper, 'finger_radius', 0.0)), settings.tool)
    self.model = compile_heap(spec, objects, heap)
    self.data = mujoco.MjData(self.model)
    m = self.model
    self.hand = m.body(gb.HAND).id
    self.tool_geoms = np.array([m.geom(g).id for g in tool_geoms])
    self.finger_geoms = [m.geom(g).id for g in gb.FINGERS] if not self.suction else []
    self.bin_geoms = np.array([m.geom(g).id for g in _BIN_GEOMS])
    self.body_slot = np.full(m.nbody, -1)
    for s in self.slots:
      self.body_slot[m.body(f'obj{s}').id] = s
    self.geom_slot = self.body_slot[m.geom_bodyid]
    self.qpos_adr = {int(s): int(m.jnt_qposadr[m.body_jntadr[m.body(f'obj{s}').id]]) for s in self.slots}
    for s, adr in self.qpos_adr.items():
      self.data.qpos[adr:adr + 7] = poses[s]
    self.poses = np.array(poses, np.float64)
    self.hand_adr = int(m.jnt_qposadr[m.body_jntadr[self.hand]])
    self.quat = _quat(pose[:3, :3])
    mujoco.mj_forward(m, self.data)
    self.start_z = {s: float(self.data.xipos[m.body(f'obj{s}').id][2]) for s in self.slots}

  def place_tool(self, position: np.ndarray) -> None:
    """Tool and target at ``position`` with the grasp's orientation, at rest."""
    d = self.data
    d.mocap_pos[0], d.mocap_quat[0] = position, self.quat
    d.qpos[self.hand_adr:self.hand_adr + 3], d.qpos[self.hand_adr + 3:self.hand_adr + 7] = position, self.quat
    d.qvel[:] = 0.0
    mujoco.mj_forward(self.model, d)

  def contacts(self, geoms_a: np.ndarray, geoms_b: np.ndarray | None = None, depth: float = 0.0):
    """(geom of ``geoms_a``, other geom, normal force) of contacts deeper than ``-depth`` (other in ``geoms_b``)."""
    d = self.data
    n = d.ncon
    if not n:
      return np.zeros(0, int), np.zeros(0, int), np.zeros(0)
    g = d.contact.geom[:n]
    dist, adr = d.contact.dist[:n], d.contact.efc_address[:n]
    first = np.isin(g[:, 0], geoms_a)
    mine = np.where(first, g[:, 0], g[:, 1])
    other = np.where(first, g[:, 1], g[:, 0])
    keep = (first | np.isin(g[:, 1], geoms_a)) & (dist < depth)
    if geoms_b is not None:
      keep &= np.isin(other, geoms_b)
    force = np.where(adr >= 0, d.efc_force[np.maximum(adr, 0)], 0.0)
    return mine[keep], other[keep], force[keep]

  def pushback(self, approach: np.ndarray) -> float:
    """Force (N) with which objects and the bin push the tool back along ``approach`` (normal forces only): what
    a wrist force sensor would feel."""
    d = self.data
    n = d.ncon
    g = d.contact.geom[:n]
    tool = np.isin(g, self.tool_geoms)
    keep = (tool[:, 0] ^ tool[:, 1]) & (d.contact.efc_address[:n] >= 0)
    normal = d.contact.frame[:n, :3][keep]
    force = d.efc_force[d.contact.efc_address[:n][keep]]
    return float(np.sum(force * np.abs(normal @ approach)))

  def bin_force(self) -> float:
    return float(np.sum(self.contacts(self.tool_geoms, self.bin_geoms)[2]))

  def between_pads(self) -> set[int]:
    """Slots touching both jaw pads."""
    touching = []
    for pad in self.finger_geoms:
      _, other, _ = self.contacts(np.array([pad]), depth=1e-4)
      touching.append({int(self.geom_slot[o]) for o in other if self.geom_slot[o] >= 0})
    return touching[0] & touching[1]

  def lifted(self) -> set[int]:
    m = self.model
    return {int(s) for s in self.slots
            if self.data.xipos[m.body(f'obj{s}').id][2] - self.start_z[s] >= self.settings.min_lift}

  def current_poses(self) -> np.ndarray:
    poses = self.poses.copy()
    for s, adr in self.qpos_adr.items():
      poses[s] = self.data.qpos[adr:adr + 7]
    return poses

  def hand_frame(self) -> tuple[np.ndarray, np.ndarray]:
    return self.data.xpos[self.hand].copy(), self.data.xmat[self.hand].reshape(3, 3).copy()

  def ray_slot(self, reach: float) -> tuple[int, float]:
    """(slot of the object the tool's axis meets first from ``reach`` behind the mouth, its distance past the
    mouth (negative: behind it, the bellows compressed), m); (-1, inf) when it meets no object."""
    origin, rot = self.hand_frame()
    geom = np.zeros(1, np.int32)
    dist = mujoco.mj_ray(self.model, self.data, origin - reach * rot[:, 0], rot[:, 0], None, 1, self.hand, geom)
    if dist < 0 or geom[0] < 0 or self.geom_slot[geom[0]] < 0:
      return -1, math.inf
    return int(self.geom_slot[geom[0]]), float(dist - reach)

  def weld_wrench(self, eq: int, slot: int, contact: np.ndarray) -> np.ndarray:
    """(6,) force (N) and torque about ``contact`` (N m), world frame, that weld ``eq`` exerts on ``slot``."""
    m, d = self.model, self.data
    rows = np.flatnonzero((d.efc_type[:d.nefc] == mujoco.mjtConstraint.mjCNSTR_EQUALITY) & (d.efc_id[:d.nefc] == eq))
    gen = np.zeros(m.nv)
    if mujoco.mj_isSparse(m):
      for r in rows:
        a, n = d.efc_J_rowadr[r], d.efc_J_rownnz[r]
        gen[d.efc_J_colind[a:a + n]] += d.efc_J[a:a + n] * d.efc_force[r]
    else:
      gen = d.efc_J[:d.nefc * m.nv].reshape(d.nefc, m.nv)[rows].T @ d.efc_force[rows]
    body = m.body(f'obj{slot}').id
    adr = m.jnt_dofadr[m.body_jntadr[body]]
    force = gen[adr:adr + 3].copy()
    torque = d.xmat[body].reshape(3, 3) @ gen[adr + 3:adr + 6] + np.cross(d.xpos[body] - contact, force)
    # The lip's contacts with the object are part of the cup's wrench too.
    local = np.zeros(6)
    for k in np.flatnonzero(self._cup_contacts(slot)):
      mujoco.mj_contactForce(m, d, int(k), local)
      frame = d.contact.frame[k].reshape(3, 3)  # rows: normal (geom1 -> geom2), tangents
      f = frame.T @ local[:3]
      if self.geom_slot[d.contact.geom[k, 0]] == slot:  # the force acts on geom2: flip it for the object
        f = -f
      force += f
      torque += np.cross(d.contact.pos[k] - contact, f)
    return np.concatenate([force, torque])

  def _cup_contacts(self, slot: int) -> np.ndarray:
    """(ncon,) bool: active contacts between the tool and the object in ``slot``."""
    d = self.data
    g = d.contact.geom[:d.ncon]
    tool = np.isin(g, self.tool_geoms)
    obj = self.geom_slot[g] == slot
    return ((tool[:, 0] & obj[:, 1]) | (tool[:, 1] & obj[:, 0])) & (d.contact.efc_address[:d.ncon] >= 0)


def ring_violation(wrench: np.ndarray, frame: np.ndarray, friction: float, gripper: SuctionGripper) -> str | None:
  """The first suction-ring limit (`RING_LIMITS`) the cup's wrench on the object violates, or None.

  The limits are those of Dex-Net 3.0's ring contact (spec, suction wrench space) without the inscribed box the
  analytic quality linearises them with: the lip's normal load is N = f_z + V (f_z the push along the approach,
  V the vacuum force) and must stay >= 0 (``vacuum``); the shear |f_t| <= mu N (``friction``); the torsion
  |tau_z| <= r mu N (``torsion``); the bending torque |tau_t| <= pi r kappa (``bending``: the first harmonic of the
  lip pressure bounded by the elastic limit kappa).

  Args:
    wrench: (6,) force (N) and torque about the contact (N m), world frame, exerted by the cup on the object.
    frame: (3, 3) contact frame columns (x_c, y_c, z_c = approach into the object).
    friction: Coulomb friction of the lip on the object.
    gripper: vacuum force V, cup radius r and elastic limit kappa.
  """
  f, t = frame.T @ wrench[:3], frame.T @ wrench[3:]
  v, r = float(gripper.vacuum_force), float(gripper.cup_radius)
  load = f[2] + v
  if load < 0.0:
    return 'vacuum'
  if math.hypot(f[0], f[1]) > friction * load:
    return 'friction'
  if abs(t[2]) > friction * r * load:
    return 'torsion'
  if math.hypot(t[0], t[1]) > math.pi * r * float(gripper.elastic_limit):
    return 'bending'
  return None


def _start(sim: _Sim, grasp_origin: np.ndarray, approach: np.ndarray) -> np.ndarray:
  """The pre-grasp position: ``standoff`` back along the approach, further while the tool starts in an object."""
  s = sim.settings
  back = s.standoff
  while True:
    start = grasp_origin - back * approach
    sim.place_tool(start)
    _, other, _ = sim.contacts(sim.tool_geoms, depth=-1e-3)
    if not np.any(sim.geom_slot[other] >= 0) or back >= s.max_standoff:
      return start
    back = min(back + 0.05, s.max_standoff)


def execute_grasp(objects: Sequence[HeapObject], models: Sequence[ObjectModel], heap: HeapState, poses: np.ndarray,
                  grasp: ParallelJawGrasp | SuctionGrasp, gripper: ParallelJawGripper | SuctionGripper,
                  settings: PhysicsSettings = PhysicsSettings(), geometry: GripperGeometry = GripperGeometry(),
                  transport_to: tuple[float, float] = (0.0, 0.0)) -> PhysicsOutcome:
  """Executes one world-frame grasp on a heap in MuJoCo (see the module doc).

  Args:
    objects: the N available objects' bodies (``heap.object_ids`` index into it).
    models: the N objects' `ObjectModel` (suction: the seal test at the actual contact).
    heap: the heap (slots, ids, mask, friction); its positions are not used.
    poses: (P, 7) object-frame poses of the slots, world frame (xyz metres, wxyz).
    grasp: the world-frame grasp (concrete NumPy/JAX values).
    gripper: the gripper of the grasp's type.
    settings: judge settings; geometry: the suction shaft's size.
    transport_to: (x, y) above which the held object is carried, m (the bin's centre).
  """
  grasp = jax.tree.map(np.asarray, grasp)
  pose = np.asarray(suction_pose(grasp) if isinstance(grasp, SuctionGrasp) else parallel_jaw_pose(grasp), np.float64)
  sim = _Sim(objects, heap, np.asarray(poses, np.float64), pose, grasp, gripper, settings, geometry)
  approach, origin = pose[:3, 0], pose[:3, 3]
  start = _start(sim, origin, approach)
  target = origin + (settings.press_depth * approach if sim.suction else 0.0)
  path = tool_path(start, target, np.asarray(transport_to, np.float64), settings.timestep, settings.path)
  d, m = sim.data, sim.model
  detail: dict[str, Any] = {}
  guarded = None  # where the guard stopped the approach
  approach_end = path.phase_end('approach')
  weld, slot, violations = -1, -1, 0
  phase_ends = {PHASES.index(p): path.phase_end(p) for p in ('grip', 'lift', 'transport', 'shake', 'hold')}
  reason = None
  for i in range(len(path.positions)):
    phase = int(path.phase[i])
    if guarded is None and phase <= 1 and sim.pushback(approach) > settings.guard_force:
      # The approach stops where the tool is, backed off by ``guard_retract`` (the force sensor's reaction); the
      # rest of the path starts there.
      guarded = d.xpos[sim.hand] - settings.guard_retract * approach
    if guarded is None:
      d.mocap_pos[0] = path.positions[i]
    else:
      d.mocap_pos[0] = guarded if phase <= 1 else path.positions[i] + guarded - path.positions[approach_end]
    if not sim.suction:
      d.ctrl[:] = path.grip[i] * sim.stroke
    elif phase == 1 and 'sealed' not in detail:  # the cup has come to rest on the surface: seal or not
      reason, weld, slot = _seal_on(sim, models, heap, gripper, detail)
      if reason:
        break
    mujoco.mj_step(m, d)
    if phase <= 1 and sim.bin_force() > settings.bin_force_limit:
      reason = 'collision_bin'
      break
    if sim.suction and weld >= 0 and phase >= 2:
      mouth, rot = sim.hand_frame()
      contact = mouth + rot @ sim.contact_offset
      broke = ring_violation(sim.weld_wrench(weld, slot, contact), rot[:, [1, 2, 0]], float(heap.friction[slot]),
                             gripper)
      violations = violations + 1 if broke else 0
      if violations >= settings.seal_break_steps:
        d.eq_active[weld] = 0
        weld, detail['limit'] = -1, broke
        reason = 'seal_lost'
        break
    if i == phase_ends[1] and not sim.suction:
      gripped = sim.between_pads()
      if not gripped:
        reason = 'no_object'
        break
      slot = min(gripped)
    if phase >= 2 and i == phase_ends[phase] and not sim.lifted():
      reason = 'dropped'
      break
  detail['phase'] = PHASES[int(path.phase[min(i, len(path.phase) - 1)])]
  detail['sim_seconds'] = round((i + 1) * settings.timestep, 6)
  lifted = sim.lifted()
  detail['lifted'] = sorted(lifted)
  if reason is None:
    held = {slot} if sim.suction else sim.between_pads()
    if len(lifted) > 1:
      reason = 'multiple_objects'
    elif not lifted or not (held & lifted):
      reason = 'dropped'
    else:
      slot = next(iter(lifted))
  return PhysicsOutcome(success=reason is None, reason=reason or 'none', target_slot=int(slot),
                        poses=sim.current_poses(), detail=detail)


def _seal_on(sim: _Sim, models: Sequence[ObjectModel], heap: HeapState, gripper: SuctionGripper,
             detail: dict[str, Any]) -> tuple[str | None, int, int]:
  """The seal test at the cup's actual contact; activates the vacuum weld when it seals.

  Returns (failure reason or None, the weld's id or -1, the object's slot or -1).
  """
  reach = gripper.cone_height + gripper.contact_tolerance
  slot, distance = sim.ray_slot(reach=reach)
  if slot < 0 or not -gripper.cone_height <= distance <= gripper.contact_tolerance:
    return 'no_object', -1, slot
  m, d = sim.model, sim.data
  body = m.body(f'obj{slot}').id
  rot, origin = d.xmat[body].reshape(3, 3), d.xpos[body]
  mouth, frame = sim.hand_frame()
  sim.contact_point = mouth + distance * frame[:, 0]  # where the cup's axis meets the surface
  local = SuctionGrasp(center=np.asarray((sim.contact_point - origin) @ rot, np.float32),
                       approach=np.asarray(frame[:, 0] @ rot, np.float32))
  seal = jax.device_get(_seal(models[int(heap.object_ids[slot])], local, gripper))
  detail['sealed'], detail['max_strain'] = bool(seal.sealed), float(seal.max_strain)
  if not seal.sealed:
    return 'no_seal', -1, slot
  eq = m.equality(f'{gb.VACUUM}_obj{slot}').id
  hand_rot = frame
  rel_pos = hand_rot.T @ (origin - mouth)
  rel_quat = np.zeros(4)
  mujoco.mju_mulQuat(rel_quat, _conjugate(d.xquat[sim.hand]), d.xquat[body])
  m.eq_data[eq, 3:6], m.eq_data[eq, 6:10] = rel_pos, rel_quat
  d.eq_active[eq] = 1
  sim.contact_offset = frame.T @ (sim.contact_point - mouth)  # the contact in the hand's frame (it moves with it)
  return None, eq, slot


def _conjugate(q: np.ndarray) -> np.ndarray:
  return np.array([q[0], -q[1], -q[2], -q[3]])


__all__ = ['PHYSICS_FAILURES', 'PhysicsOutcome', 'PhysicsSettings', 'RING_LIMITS', 'execute_grasp', 'ring_violation']
