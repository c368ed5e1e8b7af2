"""One heap with one tool in MuJoCo: the scene the physics judge executes a grasp in (`GraspScene`), and its
settings (`PhysicsSettings`).

The heap's model (`dexjax.sim.heap_spec`: the bin and every object as a free body of convex hulls, with the
heap's own contact settings) gets the gripper (`dexjax.bench.gripper_bodies`) at the pre-grasp pose and is stepped
with the judge's physics: 2 ms steps, implicit-fast integration, elliptic friction cones, impratio 10, 5 noslip
iterations. The queries read MuJoCo's contact and constraint arrays directly (no per-contact Python calls except
for the suction lip's few contacts).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import mujoco
import numpy as np

from dexjax.bench import gripper_bodies as gb
from dexjax.bench.tool_path import PathSettings
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp
from dexjax.quality.gripper_geometry import GripperGeometry
from dexjax.sim.bodies import HeapObject
from dexjax.sim.heap import Bin, HeapState
from dexjax.sim.scene import SettleSettings, compile_heap, heap_slots, heap_spec

_BIN_GEOMS = ('ground', 'wall0', 'wall1', 'wall2', 'wall3')
_SETTLED_GROUP, _GRIP_GROUP = 3, 4  # geom groups: the coarse hulls of objects near the grasp; their finer pieces
_RAY_GROUPS = np.array([1, 1, 1, 0, 1, 1], np.uint8)  # the cup's ray meets everything but those coarse hulls


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
    bin_force_limit: contact force of the gripper on the bin (floor or walls) during the approach and the grip
      that fails the attempt, N; None (default): the labels' collision rule alone decides bin collisions, before
      the attempt (`collision_check`), and in the simulation the bin is an obstacle like any other (a palm that
      grazes a wall's top within the rule's 1 mm tolerance, with the hand held stiffly at its target, pressed on it
      with over 50 N and failed attempts the labels accept).
    min_lift: an object counts as lifted when its centre of mass ends this much higher than it started, m.
    collision_check: before executing, test the gripper's swept solids against the simulated bodies with the
      labels' collision rule (`dexjax.bench.collision_rule`); a collision fails the attempt without simulating.
      False: the gripper pushes whatever is in its way (a stress test, not the labels' world).
    receptacle_half: half the inner side of the square receptacle beside the bin, m.
    receptacle_wall: height of the receptacle's walls, m.
    grip_radius: objects whose centre lies within this distance of the grasp (plus their own radius) meet the
      gripper through their finer grip hulls, when the judge has them, m.
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
  bin_force_limit: float | None = None
  min_lift: float = 0.1
  collision_check: bool = True
  receptacle_half: float = 0.12
  receptacle_wall: float = 0.08
  grip_radius: float = 0.1
  path: PathSettings = PathSettings()
  tool: gb.ToolSettings = gb.ToolSettings()


class GraspScene:
  """One heap with one tool in MuJoCo (a fresh model per attempt), and the queries the physics judge's verdict
  needs: contacts and their forces, what lies between the jaws, what was lifted, the vacuum weld's wrench."""

  def __init__(self, objects: Sequence[HeapObject], heap: HeapState, poses: np.ndarray, pose: np.ndarray,
               grasp: ParallelJawGrasp | SuctionGrasp, gripper, settings: PhysicsSettings,
               geometry: GripperGeometry, receptacle: np.ndarray, bin_: Bin = Bin(), clearance: float = 0.0,
               grip_hulls: Sequence[Sequence[np.ndarray]] | None = None):
    self.settings, self.suction = settings, isinstance(grasp, SuctionGrasp)
    self.contact_point, self.contact_offset = None, np.zeros(3)  # suction: the sealed contact (world, hand frame)
    # No sleeping objects here: the tool moves through mocap and weld constraints, and the judge's physics was
    # validated with every object awake (settling alone lets resting objects sleep).
    spec = heap_spec(objects, heap, SettleSettings(timestep=settings.timestep, impratio=settings.impratio,
                                                   solver_iterations=settings.solver_iterations, sleep=False,
                                                   bin=bin_))
    opt = spec.option
    opt.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    opt.noslip_iterations = settings.noslip_iterations
    self.slots = heap_slots(heap)
    friction = np.asarray(heap.friction, np.float64)
    ids = np.asarray(heap.object_ids)
    hulls = self._gripper_hulls(spec, objects, ids, poses, pose[:3, 3], friction, grip_hulls)
    if self.suction:
      gb.add_suction_cup(spec, pose, gripper, geometry, settings.tool, clearance)
      gb.add_vacuum(spec, [f'obj{s}' for s in self.slots], settings.tool)
      tool_geoms = [gb.CUP, gb.SHAFT]
    else:
      self.stroke = 0.5 * float(grasp.width) + settings.tool.close_overtravel
      gb.add_parallel_jaw(spec, pose, float(grasp.width), gripper, settings.tool, clearance)
      tool_geoms = [gb.PALM, *gb.FINGERS, *gb.FINGERTIPS]
    gb.add_gripper_pairs(spec, tool_geoms, hulls, _BIN_GEOMS,
                         (2.0 / 3.0) * float(getattr(gripper, 'finger_radius', 0.0)), settings.tool)
    self.receptacle = np.asarray(receptacle, np.float64)
    gb.add_receptacle(spec, self.receptacle, settings.receptacle_half, settings.receptacle_wall,
                      bin_.wall_thickness)
    self.model = compile_heap(spec, objects, heap)
    self.data = mujoco.MjData(self.model)
    m = self.model
    self.hand = m.body(gb.HAND).id
    self.lip = m.body(gb.LIP).id if self.suction else -1
    self.tool_geoms = np.array([m.geom(g).id for g in tool_geoms])
    # Each jaw's geoms (pad, fingertip) in FINGERS order.
    self.finger_geoms = ([[m.geom(p).id, m.geom(t).id] for p, t in zip(gb.FINGERS, gb.FINGERTIPS)]
                         if not self.suction else [])
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
    self.quat = gb.rotation_quat(pose[:3, :3])
    mujoco.mj_forward(m, self.data)
    self.start_z = {s: float(self.data.xipos[m.body(f'obj{s}').id][2]) for s in self.slots}

  def _gripper_hulls(self, spec, objects, ids, poses, centre, friction, grip_hulls) -> list[tuple[str, float]]:
    """(geom name, friction) of the object geoms the gripper collides with. With ``grip_hulls`` (per object, a
    finer convex decomposition), the objects within ``grip_radius`` of the grasp get those pieces as extra geoms
    that only the gripper touches (and the cup's ray sees): the gripper meets the mesh's cavities, while the
    objects keep colliding with each other through their own (coarser) hulls, as they settled."""
    out = []
    for s in self.slots:
      obj, mu = objects[int(ids[s])], max(float(friction[s]), mujoco.mjMINMU)
      near = (grip_hulls is not None and
              np.linalg.norm(poses[s, :3] - centre) < self.settings.grip_radius + obj.radius)
      if not near:
        out += [(f'obj{s}_hull{j}', mu) for j in range(len(obj.hulls))]
        continue
      body = spec.body(f'obj{s}')
      for j in range(len(obj.hulls)):
        spec.geom(f'obj{s}_hull{j}').group = _SETTLED_GROUP
      for j, hull in enumerate(grip_hulls[int(ids[s])]):
        name = f'obj{s}_grip{j}'
        spec.add_mesh(name=name, uservert=np.asarray(hull, np.float64).reshape(-1).tolist())
        body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=name, contype=0, conaffinity=0,
                      group=_GRIP_GROUP, rgba=[0.5, 0.8, 0.5, 0.3])
        out.append((name, mu))
    return out

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
    force = np.where(adr >= 0, d.efc_force[np.maximum(adr, 0)], 0.0) if d.nefc else np.zeros(n)
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
    """Slots touching both jaws (pad or fingertip)."""
    touching = []
    for jaw in self.finger_geoms:
      _, other, _ = self.contacts(np.array(jaw), depth=1e-4)
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

  def in_receptacle(self) -> set[int]:
    """Slots whose centre of mass lies inside the receptacle's walls, below their top."""
    m, d = self.model, self.data
    half, top = self.settings.receptacle_half, self.settings.receptacle_wall
    inside = set()
    for s in self.slots:
      c = d.xipos[m.body(f'obj{s}').id]
      if np.all(np.abs(c[:2] - self.receptacle) < half) and c[2] < top:
        inside.add(int(s))
    return inside

  def cup_frame(self) -> tuple[np.ndarray, np.ndarray]:
    """(the cup's mouth (3,), its frame (3, 3): columns approach, y, z), world frame: the lip body's."""
    return self.data.xpos[self.lip].copy(), self.data.xmat[self.lip].reshape(3, 3).copy()

  def ray_slot(self, reach: float, jitter: float = 2.5e-4) -> tuple[int, float]:
    """(slot of the object the cup's axis meets first from ``reach`` behind the mouth, its distance past the
    mouth (negative: behind it, the bellows compressed), m); (-1, inf) when it meets no object. A ray exactly
    along an edge of a hull can slip between its faces: when the axis misses, four rays ``jitter`` beside it
    decide (the nearest hit)."""
    origin, rot = self.cup_frame()
    start = origin - reach * rot[:, 0]
    for offsets in ([np.zeros(3)], [jitter * s * rot[:, k] for k in (1, 2) for s in (1.0, -1.0)]):
      hits = [self._ray(start + o, rot[:, 0]) for o in offsets]
      hits = [h for h in hits if h[0] >= 0]
      if hits:
        slot, dist = min(hits, key=lambda h: h[1])
        return slot, dist - reach
    return -1, math.inf

  def _ray(self, origin: np.ndarray, direction: np.ndarray) -> tuple[int, float]:
    """(slot, distance) of the first object a ray meets, or (-1, inf)."""
    geom = np.zeros(1, np.int32)
    dist = mujoco.mj_ray(self.model, self.data, origin, direction, _RAY_GROUPS, 1, self.hand, geom)
    if dist < 0 or geom[0] < 0 or self.geom_slot[geom[0]] < 0:
      return -1, math.inf
    return int(self.geom_slot[geom[0]]), float(dist)

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


__all__ = ['GraspScene', 'PhysicsSettings']
