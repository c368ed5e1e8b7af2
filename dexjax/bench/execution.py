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
from dexjax.bench.grasp_scene import GraspScene, PhysicsSettings
from dexjax.bench.tool_path import PHASES, tool_path
from dexjax.contacts.suction import suction_seal
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp, parallel_jaw_pose, suction_pose
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.geometry.object_model import ObjectModel
from dexjax.quality.gripper_geometry import GripperGeometry
from dexjax.sim.bodies import HeapObject
from dexjax.sim.heap import HeapState

PHYSICS_FAILURES = ('none', 'collision_bin', 'no_object', 'no_seal', 'seal_lost', 'dropped', 'multiple_objects')
"""Failure reasons of the physics judge: the gripper pressed on the bin; nothing between the closed jaws (or under
the cup); the analytic seal test failed at the actual contact; a suction-ring limit broke the hold; the object was
lost during the lift, transport or shake; more than one object was lifted."""

RING_LIMITS = ('vacuum', 'friction', 'torsion', 'bending')


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


def _start(sim: GraspScene, grasp_origin: np.ndarray, approach: np.ndarray) -> np.ndarray:
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
  sim = GraspScene(objects, heap, np.asarray(poses, np.float64), pose, grasp, gripper, settings, geometry)
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


def _seal_on(sim: GraspScene, models: Sequence[ObjectModel], heap: HeapState, gripper: SuctionGripper,
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
  rel_pos = frame.T @ (origin - mouth)  # the weld's relative pose: the object's frame in the hand's frame
  hand_inverse, rel_quat = np.zeros(4), np.zeros(4)
  mujoco.mju_negQuat(hand_inverse, d.xquat[sim.hand])
  mujoco.mju_mulQuat(rel_quat, hand_inverse, d.xquat[body])
  m.eq_data[eq, 3:6], m.eq_data[eq, 6:10] = rel_pos, rel_quat
  d.eq_active[eq] = 1
  sim.contact_offset = frame.T @ (sim.contact_point - mouth)  # the contact in the hand's frame (it moves with it)
  return None, eq, slot


__all__ = ['PHYSICS_FAILURES', 'PhysicsOutcome', 'PhysicsSettings', 'RING_LIMITS', 'execute_grasp', 'ring_violation']
