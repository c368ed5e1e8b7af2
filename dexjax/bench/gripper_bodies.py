"""The grippers as MuJoCo bodies, added to a heap's `MjSpec` for the physics judge.

Both tools are a free body ``hand`` welded to a mocap body ``tool_target`` (the robot's commanded pose: the weld
is a stiff spring, so a hand pushed against the bin or the heap gives a little instead of exerting unbounded
force) and cancelled by gravity compensation. Their geometry is the collision solids of the analytic reward
(`dexjax.quality.gripper_geometry`), in the grasp frame (x = approach, origin at the grasp centre or the cup's
mouth):

* **parallel jaw**: the palm and two finger pads (`ParallelJawGripper` sizes), each pad on a slide joint along
  the jaw axis, driven by a position servo whose force is clipped to the gripper's ``force_limit``; the jaws start
  open at the grasp's width and a command of 1 drives them ``close_overtravel`` past the centre, so a pad that
  meets an object presses with exactly the force limit (both are opened at once to release it: see
  `dexjax.bench.tool_path`);
* **suction**: the rigid cup body (a cylinder of the cup's radius) behind the compliant bellows (``cone_height``,
  no collision solid: the seal model is the lip's physics) and the tool shaft behind it, on the hand; the
  bellows is a body ``lip`` at the cup's mouth hinged to the hand about the two axes across the cup, at half the
  bellows' height behind the mouth, with the bellows' bending stiffness and damping and its angle range
  (`ToolSettings`; once a seal forms the judge sets the hinges to ``sealed_stiffness`` and damps them for the held
  object). The seal and the vacuum hold are the judge's (`dexjax.bench.execution`): one weld
  ``vacuum_<body>`` between the lip and each object, inactive until a seal forms on that object, so every load
  on the held object reaches the hand through the compliant bellows.

Gripper geoms never collide through MuJoCo's dynamic pairs (contype 2, conaffinity 0); every contact they can make
is an explicit pair with each object hull, the floor and the walls, so a finger-object contact has the object's
Coulomb friction and the soft-finger torsional friction of the analytic model, (2/3) mu r_f (condim 4), whatever the
heap's own contact settings.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import mujoco
import numpy as np

from dexjax.grippers import BELLOWS_MAX_ANGLE, BELLOWS_STIFFNESS, ParallelJawGripper, SuctionGripper
from dexjax.quality.gripper_geometry import GripperGeometry

HAND, TARGET, VACUUM = 'hand', 'tool_target', 'vacuum'
FINGERS = ('finger_pos', 'finger_neg')
"""Names of the jaw pads' bodies (and geoms): the pad on the +y (jaw axis) side and on the -y side."""
FINGERTIPS = ('fingertip_pos', 'fingertip_neg')
"""Names of the soft fingertips on the pads (spheres of the gripper's ``finger_radius`` on the closing line)."""
PALM, CUP, SHAFT, LIP = 'palm', 'cup', 'shaft', 'lip'
BELLOWS_JOINTS = ('bellows_y', 'bellows_z')
"""The lip's hinges: about the grasp frame's y and z axes (across the cup)."""
RECEPTACLE = 'receptacle'
_GRIPPER_GROUP = 2  # contype of gripper geoms; conaffinity 0: no dynamic contacts at all
_Z_TO_X = [np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0]  # rotates a cylinder's z axis onto x


@dataclasses.dataclass(frozen=True)
class ToolSettings:
  """Physical constants of the simulated tools (SI units).

  Attributes:
    hand_mass: mass of the hand body, kg (its weight is compensated).
    finger_mass: mass of each jaw pad, kg.
    finger_gain: stiffness of the jaw position servos, N/m (clipped to the gripper's force limit).
    finger_damping: damping of the jaw slide joints, N s/m.
    close_overtravel: the closed command drives each pad this far past the grasp centre, m (>= force limit /
      gain, so a blocked pad presses with the full force limit).
    weld_timeconst: time constant of the hand-to-target weld (MuJoCo ``solref[0]``), s.
    vacuum_timeconst: time constant of the vacuum weld of the lip to the held object, s (two physics steps, MuJoCo's
      stiffest stable setting: the lip sticks to the surface; the compliance is the bellows').
    contact_timeconst: time constant of gripper contacts, s.
    bin_friction: friction of gripper-bin contacts.
    cup_body_length: length of the rigid cup body behind the compliant bellows, m.
    bellows_stiffness: bending stiffness of the open bellows (before a seal), N m / rad (an estimate, no maker
      publishes it; see docs/benchmark.md: a 20 mm silicone tube of 1.5 mm wall and 1 cm length bends at
      E I / L ~ 0.7 N m/rad with E ~ 1.5 MPa, a convoluted bellows is one to two orders of magnitude softer; a
      finger tilts one by 30 degrees with about 1 N at 2 cm).
    sealed_stiffness: bending stiffness of the sealed bellows, N m / rad; default the open bellows' (an estimate:
      under vacuum a bellows cup contracts onto its folds, and stacked folds could bend up to the solid tube's
      ~0.7 N m/rad; with 0.7 the supervisor's level-1 reliability fell from 0.90 to 0.82, neighbours' pushes in
      the lift reaching the seal, and no maker publishes the figure: docs/benchmark.md). Both defaults are
      `dexjax.grippers.BELLOWS_STIFFNESS`, the stiffness of the labels' tipping test
      (`dexjax.grippers.SuctionGripper.bellows_stiffness`), so labels and judge tip the same objects.
    sealed_armature: rotor inertia added to the bellows' hinges once sealed, kg m² (numerical: MuJoCo integrates
      joint stiffness explicitly, and a stiff sealed hinge of a 20 g lip on a soft vacuum weld would ring at
      omega dt ~ 1 at 2 ms steps; 5e-5 keeps omega dt ~ 0.2 up to 0.7 N m/rad, a few percent of a held object's
      inertia about the hinge).
    bellows_damping_ratio: damping ratio of the bellows' bending with the held object (an estimate: silicone
      rubber's loss factor of about 0.1-0.2 alone gives 0.05-0.1; the air the bellows pumps adds to it).
    bellows_max_angle: the bellows' bending range, rad (`dexjax.grippers.BELLOWS_MAX_ANGLE`, shared with the
      labels' tipping test: about 30 degrees, the "angle compensation" bellows cups are sold for; an estimate).
    fingertip_protrusion: how far the soft fingertip stands out of the pad's face, m (the seed's "custom silicone
      fingertips"; the analytic model closes soft point contacts along one line, not flat pads: a rigid 2 x 6 cm
      pad meets a tapered face at its edge and squeezes the object out where the point contacts hold it; an
      estimate).
    lip_mass: mass of the lip body (cup, bellows and fitting), kg (weight compensated; an estimate: a 20 mm bellows
      cup weighs a few grams, its fitting more; lighter lips make the bellows' hinges numerically unstable at 2 ms).
  """

  hand_mass: float = 0.3
  finger_mass: float = 0.02
  finger_gain: float = 2000.0
  finger_damping: float = 20.0
  close_overtravel: float = 0.03
  weld_timeconst: float = 0.01
  vacuum_timeconst: float = 0.004
  contact_timeconst: float = 0.005
  bin_friction: float = 0.5
  cup_body_length: float = 0.02
  bellows_stiffness: float = BELLOWS_STIFFNESS
  sealed_stiffness: float = BELLOWS_STIFFNESS
  sealed_armature: float = 5e-5
  bellows_damping_ratio: float = 0.3
  bellows_max_angle: float = BELLOWS_MAX_ANGLE
  lip_mass: float = 0.02
  fingertip_protrusion: float = 0.003


def _box(body, name: str, centre: Sequence[float], half: Sequence[float], mass: float) -> None:
  body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_BOX, pos=list(centre), size=list(half), mass=mass,
                contype=_GRIPPER_GROUP, conaffinity=0, rgba=[0.3, 0.3, 0.35, 1.0])


def rotation_quat(matrix: np.ndarray) -> np.ndarray:
  """(4,) float64 unit quaternion (w, x, y, z) of a (3, 3) rotation matrix (MuJoCo's convention)."""
  quat = np.zeros(4)
  mujoco.mju_mat2Quat(quat, np.ascontiguousarray(matrix, np.float64).reshape(-1))
  return quat


def _hand(spec: mujoco.MjSpec, pose: np.ndarray, tool: ToolSettings):
  """The mocap target and the free hand welded to it, both at ``pose`` (4, 4)."""
  quat = rotation_quat(pose[:3, :3])
  world = spec.worldbody
  world.add_body(name=TARGET, mocap=True, pos=pose[:3, 3].tolist(), quat=quat.tolist())
  hand = world.add_body(name=HAND, pos=pose[:3, 3].tolist(), quat=quat.tolist(), gravcomp=1.0)
  hand.add_freejoint()
  weld = spec.add_equality(type=mujoco.mjtEq.mjEQ_WELD, name1=TARGET, name2=HAND, objtype=mujoco.mjtObj.mjOBJ_BODY)
  weld.data = [0.0] * 10 + [1.0, 0.0]  # anchor 0, relative pose from the initial configuration, torquescale 1
  weld.solref = [tool.weld_timeconst, 1.0]
  return hand


def add_parallel_jaw(spec: mujoco.MjSpec, pose: np.ndarray, width: float, gripper: ParallelJawGripper,
                     tool: ToolSettings = ToolSettings(), clearance: float = 0.0) -> None:
  """Adds the parallel-jaw hand at grasp-frame ``pose`` (4, 4; x approach, y jaw axis) with jaws open at
  ``width`` (m) and one position actuator per pad (command: closing stroke in metres, 0 = open).

  ``clearance`` (m, the labels' collision tolerance) shrinks every face of the solids that is not meant to touch
  (all but the pads' inner faces) by that much: the labels let a solid overlap an object or the bin by up to the
  tolerance, and so does the simulation.
  """
  hand = _hand(spec, pose, tool)
  c = float(clearance)
  length, thick, across = gripper.finger_length, max(gripper.finger_thickness, 1e-3 + c), gripper.finger_width
  x_pad = gripper.tip_depth - 0.5 * length
  x_palm = gripper.tip_depth - length - 0.5 * gripper.palm_depth
  _box(hand, PALM, [x_palm, 0.0, 0.0], [0.5 * gripper.palm_depth - c, 0.5 * gripper.palm_width - c,
                                         0.5 * gripper.palm_height - c], tool.hand_mass)
  stroke = 0.5 * width + tool.close_overtravel
  for name, side in zip(FINGERS, (1.0, -1.0)):
    pad = hand.add_body(name=name, pos=[x_pad, side * (0.5 * width + 0.5 * thick), 0.0], gravcomp=1.0)
    pad.add_joint(name=name, type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0.0, -side, 0.0], range=[-0.001, stroke],
                  damping=tool.finger_damping)
    # The inner (pad) face stays where the grasp puts it; the tip, the outer face and the sides give way by c.
    _box(pad, name, [-0.5 * c, -side * 0.5 * c, 0.0], [0.5 * (length - c), 0.5 * (thick - c), 0.5 * across - c],
         tool.finger_mass)
    # The soft fingertip on the closing line (the grasp centre's depth), standing out of the pad by
    # ``fingertip_protrusion``: the analytic model's soft point contact of radius finger_radius.
    radius = max(float(gripper.finger_radius), 1e-3)
    pad.add_geom(name=FINGERTIPS[FINGERS.index(name)], type=mujoco.mjtGeom.mjGEOM_SPHERE,
                 pos=[-x_pad, -side * (0.5 * thick - radius + tool.fingertip_protrusion), 0.0], size=[radius, 0, 0],
                 mass=1e-3, contype=_GRIPPER_GROUP, conaffinity=0, rgba=[0.9, 0.4, 0.2, 1.0])
    spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT,
                      gaintype=mujoco.mjtGain.mjGAIN_FIXED, gainprm=[tool.finger_gain] + [0.0] * 9,
                      biastype=mujoco.mjtBias.mjBIAS_AFFINE, biasprm=[0.0, -tool.finger_gain, 0.0] + [0.0] * 7,
                      ctrlrange=[0.0, stroke], ctrllimited=1,
                      forcerange=[-float(gripper.force_limit), float(gripper.force_limit)], forcelimited=1)


def add_suction_cup(spec: mujoco.MjSpec, pose: np.ndarray, gripper: SuctionGripper,
                    geometry: GripperGeometry = GripperGeometry(), tool: ToolSettings = ToolSettings(),
                    clearance: float = 0.0) -> None:
  """Adds the suction tool at grasp-frame ``pose`` (4, 4; x approach, origin at the cup's mouth): the hand with
  the rigid cup body and shaft, and the bellows' ``lip`` body at the mouth; see `add_vacuum` for its hold.
  ``clearance``: as `add_parallel_jaw` (the cup body's and the shaft's radii and front faces)."""
  hand = _hand(spec, pose, tool)
  h, r, c = gripper.cone_height, gripper.cup_radius, float(clearance)
  # The front ``cone_height`` of the cup is the compliant bellows: no collision solid (the seal model decides what
  # it does); the rigid cup body behind it and the shaft collide.
  hand.add_geom(name=CUP, type=mujoco.mjtGeom.mjGEOM_CYLINDER, pos=[-h - 0.5 * (tool.cup_body_length + c), 0.0, 0.0],
                quat=_Z_TO_X, size=[r - c, 0.5 * (tool.cup_body_length - c), 0.0], mass=0.5 * tool.hand_mass,
                contype=_GRIPPER_GROUP, conaffinity=0)
  hand.add_geom(name=SHAFT, type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                pos=[-h - tool.cup_body_length - 0.5 * geometry.shaft_length, 0.0, 0.0], quat=_Z_TO_X,
                size=[geometry.shaft_radius - c, 0.5 * geometry.shaft_length, 0.0], mass=0.5 * tool.hand_mass,
                contype=_GRIPPER_GROUP, conaffinity=0)
  # The lip body has no geom (a ray from the cup must only meet objects); its inertia is a thin ring's.
  ring = tool.lip_mass * r * r
  lip = hand.add_body(name=LIP, pos=[0.0, 0.0, 0.0], gravcomp=1.0, mass=tool.lip_mass, ipos=[0.0, 0.0, 0.0],
                      inertia=[ring, 0.5 * ring, 0.5 * ring], explicitinertial=True)
  limit = np.degrees(tool.bellows_max_angle) if spec.compiler.degree else tool.bellows_max_angle
  for name, axis in zip(BELLOWS_JOINTS, ([0.0, 1.0, 0.0], [0.0, 0.0, 1.0])):
    lip.add_joint(name=name, type=mujoco.mjtJoint.mjJNT_HINGE, axis=axis, pos=[-0.5 * h, 0.0, 0.0],
                  stiffness=tool.bellows_stiffness, range=[-limit, limit],
                  limited=mujoco.mjtLimited.mjLIMITED_TRUE,
                  damping=bellows_damping(tool, 0.5 * ring + tool.lip_mass * 0.25 * h * h))


def bellows_damping(tool: ToolSettings, inertia: float, stiffness: float | None = None) -> float:
  """Damping (N m s / rad) of the bellows' hinges at ``tool.bellows_damping_ratio`` for a held ``inertia`` (kg m²,
  about the hinge) and a hinge ``stiffness`` (N m / rad; default the open bellows'); the judge re-tunes the hinges
  to the sealed bellows and the object the cup holds."""
  stiffness = tool.bellows_stiffness if stiffness is None else stiffness
  return 2.0 * tool.bellows_damping_ratio * float(np.sqrt(stiffness * inertia))


def add_gripper_pairs(spec: mujoco.MjSpec, gripper_geoms: Sequence[str], object_geoms: Sequence[tuple[str, float]],
                      bin_geoms: Sequence[str], finger_torsion: float, tool: ToolSettings = ToolSettings()) -> None:
  """Explicit contact pairs of every gripper geom with every object hull (name, Coulomb friction) and bin geom.

  ``finger_torsion`` (m per unit friction) gives jaw pads the soft-finger torsional friction ``finger_torsion *
  mu`` (condim 4); the palm, cup and shaft get sliding friction only (condim 3).
  """
  solref = [tool.contact_timeconst, 1.0]
  for g in gripper_geoms:
    pad = g in FINGERS or g in FINGERTIPS
    for name, mu in object_geoms:
      spec.add_pair(geomname1=g, geomname2=name, condim=4 if pad else 3, solref=solref,
                    friction=[mu, mu, finger_torsion * mu if pad else 0.0, 0.0, 0.0])
    for name in bin_geoms:
      spec.add_pair(geomname1=g, geomname2=name, condim=3, solref=solref,
                    friction=[tool.bin_friction, tool.bin_friction, 0.0, 0.0, 0.0])


def add_vacuum(spec: mujoco.MjSpec, object_bodies: Sequence[str], tool: ToolSettings = ToolSettings()) -> None:
  """One inactive weld ``vacuum_<body>`` between the lip and each of ``object_bodies``: the vacuum hold, activated
  (with the relative pose of the moment) for the object a seal forms on."""
  for body in object_bodies:
    weld = spec.add_equality(type=mujoco.mjtEq.mjEQ_WELD, name=f'{VACUUM}_{body}', name1=LIP, name2=body,
                             objtype=mujoco.mjtObj.mjOBJ_BODY, active=False)
    weld.data = [0.0] * 10 + [1.0, 0.0]
    weld.solref = [tool.vacuum_timeconst, 1.0]


def add_receptacle(spec: mujoco.MjSpec, centre: Sequence[float], inner_half: float, wall_height: float,
                   wall_thickness: float) -> list[str]:
  """Adds the receptacle beside the bin: four walls of a square box on the ground around (x, y) ``centre`` (its
  floor is the ground plane); returns the walls' geom names."""
  names = []
  x, y = float(centre[0]), float(centre[1])
  out = inner_half + 0.5 * wall_thickness
  for k, (dx, dy, hx, hy) in enumerate(((out, 0.0, 0.5 * wall_thickness, inner_half + wall_thickness),
                                        (-out, 0.0, 0.5 * wall_thickness, inner_half + wall_thickness),
                                        (0.0, out, inner_half, 0.5 * wall_thickness),
                                        (0.0, -out, inner_half, 0.5 * wall_thickness))):
    names.append(f'{RECEPTACLE}{k}')
    spec.worldbody.add_geom(name=names[-1], type=mujoco.mjtGeom.mjGEOM_BOX, pos=[x + dx, y + dy, 0.5 * wall_height],
                            size=[hx, hy, 0.5 * wall_height], rgba=[0.6, 0.5, 0.3, 1.0])
  return names


__all__ = ['BELLOWS_JOINTS', 'CUP', 'FINGERS', 'FINGERTIPS', 'HAND', 'LIP', 'PALM', 'RECEPTACLE', 'SHAFT', 'TARGET',
           'ToolSettings', 'VACUUM', 'add_gripper_pairs', 'add_parallel_jaw', 'add_receptacle', 'add_suction_cup',
           'add_vacuum', 'bellows_damping', 'rotation_quat']
