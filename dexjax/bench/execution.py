"""The physics judge of a benchmark attempt: the grasp executed in MuJoCo on the simulated bin.

The seed's success: the robot "lifts and transports exactly one object from the heap to a receptacle". The judge:

1. **Collisions** (`dexjax.bench.collision_rule`, on by default): the labels' own collision test on the bin
   (`dexjax.quality.parallel_jaw_collisions` / `suction_collisions`): where the gripper's swept solids enter an
   object or the bin by more than the collision tolerance, the attempt fails (``collision_object`` /
   ``collision_bin``) before anything moves, as it does in the labels.
2. **Execution** in the heap's MuJoCo model (`dexjax.sim.heap_spec`: the bin and every object as a free body of
   convex hulls) with the gripper (`dexjax.bench.gripper_bodies`) and a receptacle beside the bin: the tool follows
   the pick's path (`dexjax.bench.tool_path`): from a pre-grasp pose ``standoff`` behind the grasp along the
   approach, to the grasp, grip, lift, transport to above the receptacle at the robot model's speed and
   acceleration, release, let fall. The approach is force-guarded, as a real cell's: it stops where the contact
   force pushing the gripper back first exceeds ``guard_force`` (the grip's own contact forces, a tapered object
   pushing the closing jaws up, do not move the tool; a suction approach may go on ``press_depth``
   past the planned point, to press the compliant cup onto the surface). The bin is an obstacle like the objects
   (optionally, ``bin_force_limit`` fails an attempt whose gripper presses on it harder: ``collision_bin``).

* **The gripper's solids** are the labels' (`dexjax.quality.gripper_geometry`), shrunk by the labels' collision
  tolerance on every face not meant to touch: the labels let them overlap an object or the bin by up to the
  tolerance, and so does the simulation (a palm 0.5 mm over a wall's top would otherwise stop the approach).
* **Parallel jaw**: the pads close with force-limited servos (the gripper's ``force_limit``) and open together at
  the release; friction is the object's Coulomb coefficient with the soft-finger torsional friction
  (2/3) mu r_f (condim 4).
* **Suction**: MuJoCo cannot model the compliant lip, so the seal is the analytic one (`dexjax.contacts.
  suction_seal`, Dex-Net 3.0's spring model) at the actual contact: where the cup's axis meets the first object
  (a ray from inside the cup; the mouth may have pressed up to the bellows' height into it, or stopped up to the
  contact tolerance short), in the object's simulated pose, along the cup's simulated axis after the guarded
  approach. A sealed cup holds the object with a weld to the bellows' lip, which is hinged to the hand with the
  sealed bellows' bending stiffness (`ToolSettings.sealed_stiffness`): the held object swings on the compliant
  bellows as on a real cup. Every step the lip's wrench on the object is checked against the labels' suction-ring
  limits and the seal breaks on a sustained violation (`dexjax.bench.suction_hold`); venting the cup at the
  receptacle releases the object.

The verdict: success when exactly one object, the one gripped, ends in the receptacle. Failure reasons:
`PHYSICS_FAILURES`. The returned state holds every object's pose at the end (or where the attempt stopped): the
judge disturbs the heap, and the trial lets it settle again (objects in the receptacle have left the bin).
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
from dexjax.bench.collision_rule import label_collision
from dexjax.bench.grasp_scene import GraspScene, PhysicsSettings
from dexjax.bench.suction_hold import SealHold, seal_hold
from dexjax.bench.tool_path import PHASES, tool_path
from dexjax.contacts.suction import suction_seal
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp, parallel_jaw_pose, suction_pose
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.geometry.object_model import ObjectModel
from dexjax.quality.heap_reward import HeapScene, RewardParams, heap_scene
from dexjax.sim.bodies import HeapObject
from dexjax.sim.heap import Bin, HeapState

PHYSICS_FAILURES = ('none', 'collision_object', 'collision_bin', 'no_object', 'no_seal', 'seal_lost', 'dropped',
                    'multiple_objects')
"""Failure reasons of the physics judge: the gripper's swept solids enter an object (the labels' rule); the
gripper enters or presses on the bin; nothing between the closed jaws (or under the cup); the analytic seal test
failed at the actual contact; a suction-ring limit broke the hold; the object was lost before it reached the
receptacle; more than one object reached the receptacle."""

_APPROACH, _GRIP, _LIFT, _TRANSPORT, _SHAKE, _RELEASE = (
    PHASES.index(p) for p in ('approach', 'grip', 'lift', 'transport', 'shake', 'release'))


@dataclasses.dataclass(frozen=True)
class PhysicsOutcome:
  """What happened to one executed grasp.

  Attributes:
    success: exactly one object, the gripped one, reached the receptacle.
    reason: ``'none'`` or one of `PHYSICS_FAILURES`.
    target_slot: the slot of the object gripped (-1 for none, and for collisions).
    poses: (P, 7) float64 object-frame poses of every slot at the end (unused slots unchanged).
    detail: JSON-able numbers: ``phase`` where the attempt ended, ``lifted`` slots (raised ``min_lift`` when
      it ended), ``delivered`` (slots in the receptacle), ``guard_short`` (how far short of the planned grasp the
      force guard stopped the approach, m; absent when it did not), for suction ``sealed``, ``max_strain`` and the
      ``limit`` that broke the hold, ``sim_seconds`` simulated.
  """

  success: bool
  reason: str
  target_slot: int
  poses: np.ndarray
  detail: dict[str, Any]


_seal = jax.jit(suction_seal)


def receptacle_centre(settings: PhysicsSettings) -> np.ndarray:
  """(2,) the receptacle's centre beside the bin (whose centre is the origin): the motion model's transport
  distance along +x."""
  return np.array([settings.path.motion.transport_distance, 0.0])


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
                  settings: PhysicsSettings = PhysicsSettings(), reward: RewardParams = RewardParams(),
                  bin_: Bin = Bin(), scene: HeapScene | None = None,
                  grip_hulls: Sequence[Sequence[np.ndarray]] | None = None) -> PhysicsOutcome:
  """Executes one world-frame grasp on a heap in MuJoCo (see the module doc).

  Args:
    objects: the N available objects' bodies (``heap.object_ids`` index into it).
    models: the N objects' `ObjectModel` (suction: the seal test at the actual contact).
    heap: the heap (slots, ids, mask, friction); its positions are not used.
    poses: (P, 7) object-frame poses of the slots, world frame (xyz metres, wxyz).
    grasp: the world-frame grasp (concrete NumPy/JAX values).
    gripper: the gripper of the grasp's type.
    settings: judge settings; bin_: the bin.
    reward: the labels' reward settings: their collision tolerance and gripper collision geometry.
    scene: the heap's `HeapScene` for the collision test (built from ``models`` when None).
    grip_hulls: per object, a finer convex decomposition the gripper meets near the grasp (`GraspScene`).
  """
  grasp = jax.tree.map(np.asarray, grasp)
  poses = np.asarray(poses, np.float64)
  if settings.collision_check:
    if scene is None:
      scene = heap_scene(models, heap.object_ids, heap.mask, poses, heap.friction)
    reason = label_collision(grasp, scene, bin_, gripper, reward)
    if reason:
      return PhysicsOutcome(success=False, reason=reason, target_slot=-1, poses=poses.copy(),
                            detail={'phase': 'approach', 'sim_seconds': 0.0, 'lifted': [], 'delivered': []})
  geometry = reward.quality.geometry
  pose = np.asarray(suction_pose(grasp) if isinstance(grasp, SuctionGrasp) else parallel_jaw_pose(grasp), np.float64)
  sim = GraspScene(objects, heap, poses, pose, grasp, gripper, settings, geometry, receptacle_centre(settings), bin_,
                   reward.quality.collision_tolerance, grip_hulls)
  approach, origin = pose[:3, 0], pose[:3, 3]
  start = _start(sim, origin, approach)
  target = origin + (settings.press_depth * approach if sim.suction else 0.0)
  path = tool_path(start, target, sim.receptacle, settings.timestep, settings.path)
  d, m = sim.data, sim.model
  detail: dict[str, Any] = {}
  guarded = None  # where the guard stopped the approach
  approach_end = path.phase_end('approach')
  weld, slot, hold = -1, -1, None
  checks = {path.phase_end(PHASES[p]): p for p in (_GRIP, _LIFT, _TRANSPORT, _SHAKE) if path.has_phase(PHASES[p])}
  reason = None
  for i in range(len(path.positions)):
    phase = int(path.phase[i])
    if guarded is None and phase == _APPROACH and sim.pushback(approach) > settings.guard_force:
      # The approach stops where the tool is, backed off by ``guard_retract`` (the force sensor's reaction); the
      # rest of the path starts there.
      guarded = d.xpos[sim.hand] - settings.guard_retract * approach
      detail['guard_short'] = round(float((target - guarded) @ approach), 5)
    if guarded is None:
      d.mocap_pos[0] = path.positions[i]
    else:
      d.mocap_pos[0] = guarded if phase <= _GRIP else path.positions[i] + guarded - path.positions[approach_end]
    if not sim.suction:
      d.ctrl[:] = path.grip[i] * sim.stroke
    elif phase == _GRIP and 'sealed' not in detail:  # the cup has come to rest on the surface: seal or not
      reason, weld, slot, hold = _seal_on(sim, objects, models, heap, gripper, detail)
      if reason:
        break
    elif phase == _RELEASE and weld >= 0:  # vent the cup over the receptacle
      d.eq_active[weld], weld = 0, -1
    mujoco.mj_step(m, d)
    if settings.bin_force_limit is not None and phase <= _GRIP and sim.bin_force() > settings.bin_force_limit:
      reason = 'collision_bin'
      break
    if weld >= 0 and phase >= _LIFT:
      body = m.body(f'obj{slot}').id
      rot = d.xmat[body].reshape(3, 3)
      broke = hold.step(sim.weld_wrench(weld, slot, hold.contact_point(rot, d.xpos[body])), rot, settings.timestep)
      if broke:
        d.eq_active[weld], weld = 0, -1
        detail['limit'] = broke.split('_')[0]
        reason = 'seal_lost'
        break
    if i in checks:
      reason, slot = _check_held(sim, checks[i], slot)
      if reason:
        break
  detail['phase'] = PHASES[int(path.phase[min(i, len(path.phase) - 1)])]
  detail['sim_seconds'] = round((i + 1) * settings.timestep, 6)
  detail['lifted'] = sorted(sim.lifted())
  delivered = sim.in_receptacle()
  detail['delivered'] = sorted(delivered)
  if reason is None:
    if len(delivered) > 1:
      reason = 'multiple_objects'
    elif slot not in delivered:
      reason = 'dropped'
  return PhysicsOutcome(success=reason is None, reason=reason or 'none', target_slot=int(slot),
                        poses=sim.current_poses(), detail=detail)


def _check_held(sim: GraspScene, phase: int, slot: int) -> tuple[str | None, int]:
  """At the end of ``phase``: is the gripped object still held? (reason or None, the gripped slot)."""
  if not sim.suction and phase == _GRIP:
    gripped = sim.between_pads()
    return (None, min(gripped)) if gripped else ('no_object', -1)
  if phase == _GRIP:
    return None, slot
  held = slot in sim.lifted() and (sim.suction or slot in sim.between_pads())
  return (None, slot) if held else ('dropped', slot)


def _seal_on(sim: GraspScene, objects: Sequence[HeapObject], models: Sequence[ObjectModel], heap: HeapState,
             gripper: SuctionGripper, detail: dict[str, Any]) -> tuple[str | None, int, int, SealHold | None]:
  """The seal test at the cup's actual contact; activates the vacuum weld when it seals and sets the sealed
  bellows' stiffness and damping (`_seal_bellows`).

  Returns (failure reason or None, the weld's id or -1, the object's slot or -1, the hold or None).
  """
  reach = gripper.cone_height + gripper.contact_tolerance
  slot, distance = sim.ray_slot(reach=reach)
  if slot < 0 or not -gripper.cone_height <= distance <= gripper.contact_tolerance:
    return 'no_object', -1, slot, None
  m, d = sim.model, sim.data
  body = m.body(f'obj{slot}').id
  rot, origin = d.xmat[body].reshape(3, 3), d.xpos[body]
  mouth, frame = sim.cup_frame()
  contact = mouth + distance * frame[:, 0]  # where the cup's axis meets the surface
  local = SuctionGrasp(center=np.asarray((contact - origin) @ rot, np.float32),
                       approach=np.asarray(frame[:, 0] @ rot, np.float32))
  obj = int(heap.object_ids[slot])
  seal = jax.device_get(_seal(models[obj], local, gripper))
  detail['sealed'], detail['max_strain'] = bool(seal.sealed), float(seal.max_strain)
  if not seal.sealed:
    return 'no_seal', -1, slot, None
  eq = m.equality(f'{gb.VACUUM}_obj{slot}').id
  rel_pos = frame.T @ (origin - mouth)  # the weld's relative pose: the object's frame in the lip's frame
  lip_inverse, rel_quat = np.zeros(4), np.zeros(4)
  mujoco.mju_negQuat(lip_inverse, d.xquat[sim.lip])
  mujoco.mju_mulQuat(rel_quat, lip_inverse, d.xquat[body])
  m.eq_data[eq, 3:6], m.eq_data[eq, 6:10] = rel_pos, rel_quat
  d.eq_active[eq] = 1
  hold = seal_hold(objects[obj], np.asarray(local.center, np.float64), np.asarray(local.approach, np.float64),
                   float(heap.friction[slot]), gripper)
  _seal_bellows(sim, objects[obj], rot, origin, mouth - 0.5 * gripper.cone_height * frame[:, 0], frame)
  return None, eq, slot, hold


def _seal_bellows(sim: GraspScene, obj: HeapObject, rot: np.ndarray, origin: np.ndarray, pivot: np.ndarray,
                  frame: np.ndarray) -> None:
  """The bellows under vacuum: each hinge gets the sealed stiffness and armature, and the damping of the bellows'
  damping ratio for the held object's moment of inertia about it."""
  m, tool = sim.model, sim.settings.tool
  com = rot @ obj.center_of_mass + origin
  arm = com - pivot
  inertia = rot @ obj.inertia @ rot.T
  for name, axis in zip(gb.BELLOWS_JOINTS, (frame[:, 1], frame[:, 2])):
    joint = m.joint(name).id
    dof = m.jnt_dofadr[joint]
    about = float(axis @ inertia @ axis + obj.mass * (arm @ arm - (arm @ axis) ** 2)) + tool.sealed_armature
    m.jnt_stiffness[joint] = tool.sealed_stiffness
    m.dof_armature[dof] = tool.sealed_armature
    m.dof_damping[dof] = gb.bellows_damping(tool, about, tool.sealed_stiffness)


__all__ = ['PHYSICS_FAILURES', 'PhysicsOutcome', 'PhysicsSettings', 'execute_grasp', 'receptacle_centre']
