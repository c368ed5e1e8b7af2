"""The Dex-Net 4.0 reward S(x, u) in {0, 1} of a grasp in a settled heap (seed, "Reward Distribution").

S = 1 iff, in this order of checks (the first failing one names the `RewardRecord.failure`):

1. ``collision_object`` / ``collision_bin``: no sample point of the gripper's collision geometry
   (`dexjax.quality.gripper_geometry`: fingers and palm with the sizes of the `ParallelJawGripper`, or cup and
   shaft, swept back along the approach by the standoff) lies deeper than ``quality.collision_tolerance``
   (`QualityConfig`, the one collision tolerance of the library) inside any heap object (its signed distance grid,
   queried in the object's frame) or the bin (below the floor z = 0, or inside a wall box of
   `dexjax.sim.bin_boxes`). For the jaws, each object gets the single-object quality's test (`jaw_collides`: the
   samples nearest to it are also refined between the samples), so overlaps from about the tolerance on are found
   wherever they lie. The surfaces meant to touch (finger pads, cup lip) are not sampled. This check alone is
   `parallel_jaw_collisions` / `suction_collisions` (also used by the supervisor and, on the simulated bin, by the
   benchmark's physics judge).
2. ``no_object`` / ``multiple_objects``: exactly one object is contacted. Parallel jaw: an object is contacted
   when it reaches more than ``quality.collision_tolerance`` into the closing region between the pads (the jaws would
   squeeze it). Suction: when its surface comes within ``suction_contact_distance`` of the cup's mouth disc.
   The target is the contacted object under the grasp centre (smallest signed distance at the centre for the
   jaws, smallest absolute distance for suction); ``target_slot`` is -1 when nothing is contacted.
3. ``not_robust``: the robust quality of the grasp on the target alone (`robust_parallel_jaw_quality` /
   `robust_suction_quality`, M = ``num_samples`` = 10 draws) exceeds ``threshold`` = 0.5 (strictly: "over
   50 %"). The grasp is expressed in the target's frame. What belongs to the heap state x_t is fixed: gravity
   is the world's -z in that frame (``Perturbations.gravity_axis`` = R^T (0, 0, -1), ``gravity_cone_angle``
   = 0) and the Coulomb friction is the target's own, ``HeapScene.friction`` (seed: friction is drawn once
   per object as part of the state, `dexjax.sim.HeapState.friction`). The M draws randomise what the seed
   names: the object mass (Gamma), the gripper position (2.5 mm / 0.1 mm) and the disturbance wrench eps_w. A
   scene with ``mass`` (labels version 8) draws each object's mass from the Gamma law centred on its own mass
   with the seed's relative spread instead of the seed's prior about 0.25 kg (``docs/deviations.md``).
   A scene with ``loads`` (the supervisor's privileged state, not the seed's reward) adds the target's: the
   wrench its neighbours press it with at rest (`dexjax.sim.resting_loads`), fixed in every draw.

Heap objects: `HeapScene` holds the models of the N available objects stacked along a leading axis (all
built with the same grid size, e.g. `prepare_object_set` output at one ``grid_size``; `stack_models`), and
per slot of the padded heap (P = 10) an object id, a mask, a pose and the object's Coulomb friction. Signed distances are read straight
from the stacked grid at (id, voxel) (`dexjax.geometry.select_model`), so no copy of a grid is made, neither per
slot nor for the target's robust quality. Every function takes one grasp; batch with
`jax.vmap` (over grasps, keys or heaps).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from dexjax.geometry.object_model import ObjectModel, select_model
from dexjax.geometry.sdf import sdf_value
from dexjax.geometry.transforms import quat_to_matrix
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp, parallel_jaw_pose, suction_pose
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality.grasp_quality import QualityConfig
from dexjax.quality.gripper_geometry import (jaw_clearance, jaw_closing_box, jaw_collision_points, jaw_contact_points,
                                             jaw_corner_points, jaw_solids, suction_collision_points,
                                             suction_contact_points, suction_rim_points, to_world)
from dexjax.quality.robust import (REWARD_SAMPLES, REWARD_THRESHOLD, Perturbations, parallel_jaw_perturbations,
                                   robust_parallel_jaw_quality, robust_suction_quality, suction_perturbations,
                                   with_known_friction, with_known_mass, with_object_mass)

if TYPE_CHECKING:
  from dexjax.sim.heap import Bin

#: Names of `RewardRecord.failure` codes (index = code).
REWARD_FAILURES = ('none', 'collision_object', 'collision_bin', 'no_object', 'multiple_objects', 'not_robust')
(NONE, COLLISION_OBJECT, COLLISION_BIN, NO_OBJECT, MULTIPLE_OBJECTS, NOT_ROBUST) = range(len(REWARD_FAILURES))


def decided_by_robustness(failure: Any) -> Any:
  """Same-shape bool (NumPy or JAX, as ``failure``): the reward's failure code is 'none' or 'not_robust', so the
  robust probability alone decided it (the gripper touched only its target, without a collision)."""
  return (failure == NONE) | (failure == NOT_ROBUST)

_WORLD_DOWN = (0.0, 0.0, -1.0)


@struct.dataclass
class HeapScene:
  """A settled heap as seen by the reward (P padded slots; add a leading axis and `vmap` for batches).

  Attributes:
    models: `ObjectModel` of the N available objects stacked along a leading axis (same grid size).
    object_ids: (P,) int32 index into ``models`` per slot (ignored where not ``mask``).
    mask: (P,) bool, the slot holds an object of the heap.
    poses: (P, 7) float32 object-frame poses in the world frame: position (metres), then the unit
      quaternion (w, x, y, z) rotating object coordinates into the world (`SettleResult.poses[b]`).
    friction: (P,) float32 Coulomb friction coefficient of each slot's object, part of the heap state
      (`HeapState.friction`, drawn once per object from the seed's truncated Gaussian).
    mass: None (the seed's reward: the robust quality draws the mass from its Gamma prior, mean 0.25 kg), or (P,)
      float32 each slot's object's mass, kg: the draws follow the Gamma law centred on it with the prior's relative
      spread (`dexjax.quality.with_object_mass`; labels version 8), or with ``mass_known`` are fixed at it (a
      simulated bin's true masses: the benchmark's ``known_mass`` judge).
    loads: None (the seed's reward), or (P, 6) float32 the load each slot's object carries from its neighbours
      at rest: force (N) and torque (N m, about its centre of mass), world frame (`dexjax.sim.resting_loads`);
      the target's is added to every draw's external wrench.
    mass_known: static; with ``mass``, the draws use it as it is instead of drawing around it.
  """

  models: ObjectModel
  object_ids: jax.Array
  mask: jax.Array
  poses: jax.Array
  friction: jax.Array
  mass: jax.Array | None = None
  loads: jax.Array | None = None
  mass_known: bool = struct.field(pytree_node=False, default=False)


@struct.dataclass
class RewardParams:
  """Settings of the heap reward (defaults: Dex-Net 4.0).

  Attributes:
    suction_contact_distance: the cup contacts an object whose surface is within this of the mouth disc,
      metres (2 mm).
    threshold: the grasp is robust when the probability exceeds this (strictly).
    num_samples: static Monte-Carlo draws M of the robust quality.
    quality: numerical settings of the quality tests: the wrench-resistance test of the target and the gripper
      collision tests (``quality.collision_tolerance``, 1 mm; ``quality.geometry``: sample spacing, standoff,
      suction shaft). The jaw sizes come from the `ParallelJawGripper`.
  """

  suction_contact_distance: float = 2e-3
  threshold: float = REWARD_THRESHOLD
  num_samples: int = struct.field(pytree_node=False, default=REWARD_SAMPLES)
  quality: QualityConfig = QualityConfig()


@struct.dataclass
class RewardRecord:
  """The reward of one grasp and why it is 0.

  Attributes:
    reward: () int32, 1 for a successful grasp, else 0.
    robust_probability: () float32 robust quality on the target (0 when there is no target).
    target_slot: () int32 heap slot of the grasped object, -1 when no object is contacted.
    num_contacts: () int32 number of objects the gripper contacts.
    failure: () int32 index into `REWARD_FAILURES` (0 when ``reward`` is 1).
  """

  reward: jax.Array
  robust_probability: jax.Array
  target_slot: jax.Array
  num_contacts: jax.Array
  failure: jax.Array


def stack_models(models: Sequence[ObjectModel]) -> ObjectModel:
  """Stacks object models of equal grid size into one `ObjectModel` with a leading object axis."""
  shapes = {m.sdf.shape for m in models}
  if len(shapes) != 1:
    raise ValueError(f'stack_models: expected models of one grid size, got sdf shapes {sorted(shapes)}')
  return jax.tree.map(lambda *xs: jnp.stack(xs), *models)


def scene_slot_ids(object_ids: Any, mask: Any) -> np.ndarray:
  """(P,) int64 model index of each slot of a `heap_scene`: ``object_ids`` where ``mask``, else the first
  object's (so per-slot tables, e.g. grasp sets, can be gathered the same way)."""
  ids, mask = np.asarray(object_ids), np.asarray(mask, bool)
  first = int(ids[mask][0]) if mask.any() else 0
  return np.where(mask, ids, first).astype(np.int64)


def heap_scene(models: Sequence[ObjectModel], object_ids: Any, mask: Any, poses: Any, friction: Any,
               mass: Any = None, mass_known: bool = False) -> HeapScene:
  """The `HeapScene` of one heap of P slots from the available objects' models: slot i's model is
  ``models[object_ids[i]]`` (empty slots repeat the first object's; ignored by the reward).

  Args:
    models: the N available objects' models (one grid size).
    object_ids: (P,) ints into ``models`` (anything where not ``mask``); mask: (P,) bool.
    poses: (P, 7) object-frame poses (xyz metres, wxyz); friction: (P,) Coulomb friction per slot.
    mass: None, or (P,) each slot's object's mass, kg; mass_known: draw around it (False) or use it as it is
      (see `HeapScene`).
  """
  mask = np.asarray(mask, bool)
  slot_ids = scene_slot_ids(object_ids, mask)
  return HeapScene(models=stack_models([models[int(i)] for i in slot_ids]),
                   object_ids=jnp.arange(len(slot_ids), dtype=jnp.int32), mask=jnp.asarray(mask),
                   poses=jnp.asarray(poses, jnp.float32),
                   friction=jnp.asarray(np.where(mask, np.asarray(friction), 0.0), jnp.float32),
                   mass=None if mass is None else jnp.asarray(np.where(mask, np.asarray(mass), 1.0), jnp.float32),
                   mass_known=mass_known)


def slot_distances(scene: HeapScene, points: jax.Array) -> jax.Array:
  """(P, K) signed distance (metres) of world points (K, 3) to the object in each slot; +inf in empty slots.

  Each slot is a `jax.lax.cond` on its mask: when the caller batches grasps but not the heap (``vmap`` over
  points with ``scene`` unbatched, as `dexjax.generate.label_image` does), empty slots cost nothing (heaps hold
  3-10 objects in P = 10 slots); with a batched ``scene`` the cond becomes a select and every slot is computed.
  """
  ids = jnp.clip(scene.object_ids, 0, scene.models.sdf.shape[0] - 1)

  def one(slot):
    pose = scene.poses[slot]
    rot = quat_to_matrix(pose[3:], xp=jnp)
    local = (points - pose[:3]) @ rot  # R^T (p - t), row-wise
    model = select_model(scene.models, ids[slot])
    return jax.vmap(lambda p: sdf_value(model, p))(local)

  empty = lambda slot: jnp.full(points.shape[:1], jnp.inf, points.dtype)
  body = lambda carry, slot: (carry, jax.lax.cond(scene.mask[slot], one, empty, slot))
  return jax.lax.scan(body, None, jnp.arange(scene.mask.shape[0]))[1]  # one compiled slot, not P


def bin_collision(points: jax.Array, bin_: Bin, tolerance: float) -> jax.Array:
  """() bool, a world point (K, 3) is more than ``tolerance`` below the floor z = 0 or inside a wall box."""
  from dexjax.sim.scene import bin_boxes  # pylint: disable=g-import-not-at-top (avoids a quality <-> sim cycle)
  walls = bin_boxes(bin_)[1:]
  centres = jnp.asarray(np.stack([c for c, _ in walls]), jnp.float32)
  halves = jnp.asarray(np.stack([s for _, s in walls]), jnp.float32) - tolerance
  inside = jnp.all(jnp.abs(points[:, None, :] - centres[None]) < halves[None], axis=-1)
  return jnp.any(points[:, 2] < -tolerance) | jnp.any(inside)


def boxes_overlap(centre_a: jax.Array, axes_a: jax.Array, half_a: jax.Array, centre_b: jax.Array,
                  half_b: jax.Array) -> jax.Array:
  """() bool: an oriented box (centre (3,), axes (3, 3) as columns, half sizes (3,)) overlaps an axis-aligned box
  (centre (3,), half sizes (3,)); exact (the separating axis test over the 15 axes of two boxes)."""
  eye = jnp.eye(3, dtype=axes_a.dtype)
  crosses = jnp.cross(axes_a.T[:, None, :], eye[None, :, :]).reshape(9, 3)
  candidates = jnp.concatenate([axes_a.T, eye, crosses])
  norms = jnp.linalg.norm(candidates, axis=1)
  axes = candidates / jnp.maximum(norms, 1e-9)[:, None]
  reach_a = jnp.abs(axes @ axes_a) @ half_a
  reach_b = jnp.abs(axes) @ half_b
  separated = (jnp.abs(axes @ (centre_b - centre_a)) > reach_a + reach_b) & (norms > 1e-6)
  return ~jnp.any(separated)


def _jaw_wall_collision(pose: jax.Array, gripper: ParallelJawGripper, params: RewardParams, width: jax.Array,
                        bin_: Bin) -> jax.Array:
  """() bool: a swept finger or the palm (boxes, `jaw_solids`), or the region the pads sweep as they close
  (`jaw_closing_box`: a wall between the pads is what the jaws would close on), overlaps a bin wall shrunk by the
  tolerance."""
  from dexjax.sim.scene import bin_boxes  # pylint: disable=g-import-not-at-top (avoids a quality <-> sim cycle)
  tol = params.quality.collision_tolerance
  walls = bin_boxes(bin_)[1:]
  hit = jnp.asarray(False)
  boxes = [(lo, hi) for lo, hi, _ in jaw_solids(gripper, params.quality.geometry, width)]
  for lo, hi in boxes + [jaw_closing_box(gripper, width)]:
    centre = pose[:3, :3] @ (0.5 * (lo + hi)) + pose[:3, 3]
    for wall_centre, wall_half in walls:
      hit |= boxes_overlap(centre, pose[:3, :3], 0.5 * (hi - lo), jnp.asarray(wall_centre, jnp.float32),
                           jnp.asarray(wall_half, jnp.float32) - tol)
  return hit


def _to_object_frame(pose: jax.Array, point: jax.Array, directions: jax.Array):
  """A world point (3,) and directions (k, 3) in the frame of the object at ``pose`` (7,)."""
  rot = quat_to_matrix(pose[3:], xp=jnp)
  return (point - pose[:3]) @ rot, directions @ rot, rot


def _state_perturbations(base: Perturbations, rot: jax.Array, scene: HeapScene, target: jax.Array,
                         num_samples: int) -> Perturbations:
  """``base`` with what the heap state fixes for the object in slot ``target``: gravity along the world's -z
  expressed in the object frame (object-to-world ``rot``) and the object's Coulomb friction (and its mass when
  the scene knows it: drawn around it, or fixed when ``mass_known``); the rest stays random."""
  slot = jnp.maximum(target, 0)
  down = jnp.asarray(_WORLD_DOWN, jnp.float32) @ rot
  fixed = with_known_friction(base, scene.friction[slot])
  if scene.mass is not None:
    fixed = (with_known_mass if scene.mass_known else with_object_mass)(fixed, scene.mass[slot])
  return fixed.replace(gravity_axis=down, gravity_cone_angle=0.0, num_samples=num_samples)


def _target_load(scene: HeapScene, rot: jax.Array, target: jax.Array) -> jax.Array | None:
  """(6,) the target's neighbours' load in its frame (object-to-world ``rot``), or None without scene loads."""
  if scene.loads is None:
    return None
  load = scene.loads[jnp.maximum(target, 0)]
  return jnp.concatenate([load[:3] @ rot, load[3:] @ rot])


def _select_target(contacted: jax.Array, center_distance: jax.Array) -> jax.Array:
  """() int32 slot of the contacted object with the smallest ``center_distance`` (P,); -1 if none."""
  score = jnp.where(contacted, center_distance, jnp.inf)
  return jnp.where(jnp.any(contacted), jnp.argmin(score), -1).astype(jnp.int32)


def _record(hit_object, hit_bin, contacted, target, probability, threshold) -> RewardRecord:
  """Combines the ordered checks into a `RewardRecord`."""
  count = jnp.sum(contacted).astype(jnp.int32)
  probability = jnp.where(target >= 0, probability, 0.0)
  checks = [(hit_object, COLLISION_OBJECT), (hit_bin, COLLISION_BIN), (count == 0, NO_OBJECT),
            (count > 1, MULTIPLE_OBJECTS), (probability <= threshold, NOT_ROBUST)]
  failure = jnp.int32(NONE)
  for failed, code in reversed(checks):
    failure = jnp.where(failed, code, failure)
  failure = failure.astype(jnp.int32)
  return RewardRecord(reward=(failure == NONE).astype(jnp.int32), robust_probability=probability,
                      target_slot=target, num_contacts=count, failure=failure)


def slot_model(scene: HeapScene, target: jax.Array) -> ObjectModel:
  """The `ObjectModel` of the object in slot ``target`` (() int; slot 0's when ``target`` is -1), read in place
  from the scene's stacked grids (`dexjax.geometry.select_model`)."""
  index = jnp.clip(scene.object_ids[jnp.maximum(target, 0)], 0, scene.models.sdf.shape[0] - 1)
  return select_model(scene.models, index)


def _slot_jaw_clearance(scene: HeapScene, grasp: ParallelJawGrasp, gripper: ParallelJawGripper,
                        params: RewardParams) -> jax.Array:
  """(P,) `jaw_clearance` of the open jaws of a world-frame grasp to the object in each slot (+inf in empty
  slots), in each object's frame; one compiled slot, each a `jax.lax.cond` on its mask (as `slot_distances`)."""
  ids = jnp.clip(scene.object_ids, 0, scene.models.sdf.shape[0] - 1)
  tol = params.quality.collision_tolerance

  def one(slot):
    center, dirs, _ = _to_object_frame(scene.poses[slot], grasp.center, jnp.stack([grasp.axis, grasp.approach]))
    local = grasp.replace(center=center, axis=dirs[0], approach=dirs[1])
    return jaw_clearance(select_model(scene.models, ids[slot]), local, gripper, params.quality.geometry, tol)

  empty = lambda slot: jnp.asarray(jnp.inf, jnp.float32)
  body = lambda carry, slot: (carry, jax.lax.cond(scene.mask[slot], one, empty, slot))
  return jax.lax.scan(body, None, jnp.arange(scene.mask.shape[0]))[1]


def parallel_jaw_collisions(grasp: ParallelJawGrasp, scene: HeapScene, bin_: Bin,
                            gripper: ParallelJawGripper = ParallelJawGripper(),
                            params: RewardParams = RewardParams()) -> tuple[jax.Array, jax.Array]:
  """Check 1 of the reward for one world-frame parallel-jaw grasp: (hit_object, hit_bin), () bools.

  ``hit_object``: the single-object test `dexjax.quality.gripper_geometry.jaw_collides` against each heap
  object in its own frame: a sample of the fingers and palm (`jaw_collision_points`: the sizes of ``gripper``,
  the grasp's ``width``, swept back by the standoff of ``params.quality.geometry``), or a refined point between
  the samples nearest to the object, lies more than ``params.quality.collision_tolerance`` inside it (so an
  overlap from about the tolerance on is found anywhere, not only where a sample lies; point jaws, with no
  finger volume, test the palm's samples alone). ``hit_bin``: a sample or a corner of the solids
  (`jaw_corner_points`: exact against the floor) below the floor or in a wall (`bin_collision`), or a solid
  overlapping a wall shrunk by the tolerance (`boxes_overlap`: exact, also where an edge crosses a wall's edge).
  """
  tol = params.quality.collision_tolerance
  geometry = params.quality.geometry
  pose = parallel_jaw_pose(grasp)
  body = to_world(pose, jaw_collision_points(gripper, geometry, grasp.width))
  if gripper.finger_thickness > 0:
    hit_object = jnp.any(_slot_jaw_clearance(scene, grasp, gripper, params) < -tol)
  else:
    hit_object = jnp.any(slot_distances(scene, body) < -tol)
  corners = to_world(pose, jaw_corner_points(gripper, geometry, grasp.width))
  hit_bin = bin_collision(jnp.concatenate([body, corners]), bin_, tol) | _jaw_wall_collision(pose, gripper, params,
                                                                                            grasp.width, bin_)
  return hit_object, hit_bin


def suction_collisions(grasp: SuctionGrasp, scene: HeapScene, bin_: Bin, gripper: SuctionGripper = SuctionGripper(),
                       params: RewardParams = RewardParams()) -> tuple[jax.Array, jax.Array]:
  """Check 1 of the reward for one world-frame suction grasp: (hit_object, hit_bin), () bools.

  As `parallel_jaw_collisions` for the cup (``gripper.cup_radius`` and ``cone_height``, without the lip slab)
  and the tool shaft: their samples against the objects; samples and rim points (`suction_rim_points`) against the
  bin.
  """
  tol = params.quality.collision_tolerance
  geometry = params.quality.geometry
  pose = suction_pose(grasp)
  body = to_world(pose, suction_collision_points(geometry, gripper.cup_radius, gripper.cone_height))
  rims = to_world(pose, suction_rim_points(geometry, gripper.cup_radius, gripper.cone_height))
  return jnp.any(slot_distances(scene, body) < -tol), bin_collision(jnp.concatenate([body, rims]), bin_, tol)


def parallel_jaw_heap_reward(key: jax.Array, grasp: ParallelJawGrasp, scene: HeapScene, bin_: Bin,
                             gripper: ParallelJawGripper = ParallelJawGripper(),
                             params: RewardParams = RewardParams(),
                             perturbations: Perturbations | None = None) -> RewardRecord:
  """Dex-Net 4.0 reward of one parallel-jaw grasp given in the world frame (see the module doc).

  Args:
    key: `jax.random` key of the robust-quality draws.
    grasp: the grasp, world frame, metres.
    scene: the heap's objects and poses.
    bin_: the bin's geometry (static).
    gripper: jaw parameters of the robust quality.
    params: reward settings.
    perturbations: robust-quality noise (default `parallel_jaw_perturbations`); its gravity is replaced by
      the world's and its friction by the target's ``scene.friction``.
  """
  tol = params.quality.collision_tolerance
  hit_object, hit_bin = parallel_jaw_collisions(grasp, scene, bin_, gripper, params)
  closing = to_world(parallel_jaw_pose(grasp), jaw_contact_points(gripper, params.quality.geometry, grasp.width))
  contacted = jnp.min(slot_distances(scene, closing), axis=1) < -tol
  target = _select_target(contacted, slot_distances(scene, grasp.center[None])[:, 0])
  obj_pose = scene.poses[jnp.maximum(target, 0)]
  center, dirs, rot = _to_object_frame(obj_pose, grasp.center, jnp.stack([grasp.axis, grasp.approach]))
  local = grasp.replace(center=center, axis=dirs[0], approach=dirs[1])
  base = parallel_jaw_perturbations() if perturbations is None else perturbations
  pert = _state_perturbations(base, rot, scene, target, params.num_samples)
  robust = robust_parallel_jaw_quality(key, slot_model(scene, target), local, gripper, pert, params.quality,
                                       _target_load(scene, rot, target))
  return _record(hit_object, hit_bin, contacted, target, robust.probability, params.threshold)


def suction_heap_reward(key: jax.Array, grasp: SuctionGrasp, scene: HeapScene, bin_: Bin,
                        gripper: SuctionGripper = SuctionGripper(), params: RewardParams = RewardParams(),
                        perturbations: Perturbations | None = None) -> RewardRecord:
  """Dex-Net 4.0 reward of one suction grasp given in the world frame (see the module doc).

  Args: as `parallel_jaw_heap_reward`; ``perturbations`` defaults to `suction_perturbations` (gravity replaced
  by the world's, friction by the target's).
  """
  hit_object, hit_bin = suction_collisions(grasp, scene, bin_, gripper, params)
  mouth = to_world(suction_pose(grasp), suction_contact_points(params.quality.geometry, gripper.cup_radius))
  contacted = jnp.min(slot_distances(scene, mouth), axis=1) < params.suction_contact_distance
  target = _select_target(contacted, jnp.abs(slot_distances(scene, grasp.center[None])[:, 0]))
  obj_pose = scene.poses[jnp.maximum(target, 0)]
  center, dirs, rot = _to_object_frame(obj_pose, grasp.center, grasp.approach[None])
  local = grasp.replace(center=center, approach=dirs[0])
  base = suction_perturbations() if perturbations is None else perturbations
  pert = _state_perturbations(base, rot, scene, target, params.num_samples)
  robust = robust_suction_quality(key, slot_model(scene, target), local, gripper, pert, params.quality,
                                  _target_load(scene, rot, target))
  return _record(hit_object, hit_bin, contacted, target, robust.probability, params.threshold)


def heap_grasp_reward(key: jax.Array, grasp: ParallelJawGrasp | SuctionGrasp, scene: HeapScene, bin_: Bin,
                      gripper: ParallelJawGripper | SuctionGripper | None = None,
                      params: RewardParams = RewardParams(),
                      perturbations: Perturbations | None = None) -> RewardRecord:
  """Dispatches on the grasp type to `parallel_jaw_heap_reward` or `suction_heap_reward` (gripper default:
  the Dex-Net 4.0 one of that type)."""
  if isinstance(grasp, SuctionGrasp):
    return suction_heap_reward(key, grasp, scene, bin_, gripper or SuctionGripper(), params, perturbations)
  return parallel_jaw_heap_reward(key, grasp, scene, bin_, gripper or ParallelJawGripper(), params, perturbations)
