"""One collision rule for both judges: the gripper's swept solids may not enter an object or the bin.

The labels' reward (seed: "the gripper geometry in the pose specified by u_t is collision-free from all objects
and obstacles") tests the gripper's collision geometry (`dexjax.quality.gripper_geometry`: fingers and palm, or
cup and shaft, swept back along the approach by the pre-grasp standoff; the finger pads and the cup's lip, which
are meant to touch, are not tested) against every object's signed distance grid and the bin, with the library's
one collision tolerance (`QualityConfig.collision_tolerance`, 1 mm): `dexjax.quality.parallel_jaw_collisions` /
`suction_collisions`. The physics judge applies that very test to the simulated bin before it executes a grasp
(`label_collision`): a grasp the labels call a collision is a collision for the judge too, decided before
anything moves, instead of a pick that pushes its neighbours aside.

What can still differ is the geometry the simulation then collides with: each object's convex collision hulls
(its convex decomposition; the mesh's own hull for a convex object) instead of the mesh the labels and the images
see. `gripper_collision` tests the same gripper samples against the hulls; `benchmarks/collision_agreement.py`
measures how often the two geometries decide differently on the grasps policies propose.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
from scipy.spatial import ConvexHull

from dexjax.geometry.transforms import quat_to_matrix
import jax

from dexjax.grasps import ParallelJawGrasp, SuctionGrasp, parallel_jaw_pose, suction_pose
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality.gripper_geometry import GripperGeometry, jaw_collision_points, suction_collision_points
from dexjax.quality.heap_reward import (HeapScene, RewardParams, bin_collision, parallel_jaw_collisions,
                                        suction_collisions)
from dexjax.sim.bodies import HeapObject
from dexjax.sim.heap import Bin


_collisions = {False: jax.jit(parallel_jaw_collisions), True: jax.jit(suction_collisions)}


def label_collision(grasp: ParallelJawGrasp | SuctionGrasp, scene: HeapScene, bin_: Bin,
                    gripper: ParallelJawGripper | SuctionGripper, params: RewardParams = RewardParams()) -> str | None:
  """The labels' collision verdict of a world-frame grasp on a heap: ``'collision_object'``, ``'collision_bin'``
  or None (`parallel_jaw_collisions` / `suction_collisions`, the reward's first check, in its order)."""
  hit_object, hit_bin = jax.device_get(_collisions[isinstance(grasp, SuctionGrasp)](grasp, scene, bin_, gripper,
                                                                                    params))
  return 'collision_object' if hit_object else ('collision_bin' if hit_bin else None)


def hull_planes(hull: np.ndarray) -> np.ndarray:
  """(F, 4) outward unit face planes (n, d) of the convex hull of vertices (V, 3): n . x + d <= 0 inside."""
  return ConvexHull(np.asarray(hull, np.float64), qhull_options='QJ').equations


@functools.lru_cache(maxsize=4096)
def _planes(obj: HeapObject) -> tuple[np.ndarray, ...]:
  return tuple(hull_planes(h) for h in obj.hulls)


def penetration(obj: HeapObject, points: np.ndarray) -> np.ndarray:
  """(K,) how deep each object-frame point (K, 3) lies inside the object's convex hulls, m (the distance to the
  nearest face of the hull it is deepest in; <= 0 outside every hull)."""
  depth = np.full(len(points), -np.inf)
  for planes in _planes(obj):
    depth = np.maximum(depth, -np.max(points @ planes[:, :3].T + planes[:, 3], axis=1))
  return depth


def collision_samples(grasp: ParallelJawGrasp | SuctionGrasp, gripper: ParallelJawGripper | SuctionGripper,
                      geometry: GripperGeometry = GripperGeometry()) -> np.ndarray:
  """(K, 3) world-frame collision samples of the gripper at a world-frame grasp: exactly the points the heap
  reward tests (`jaw_collision_points` / `suction_collision_points` at `parallel_jaw_pose` / `suction_pose`)."""
  if isinstance(grasp, SuctionGrasp):
    pose = suction_pose(grasp)
    local = suction_collision_points(geometry, gripper.cup_radius, gripper.cone_height)
  else:
    pose = parallel_jaw_pose(grasp)
    local = jaw_collision_points(gripper, geometry, grasp.width)
  pose, local = np.asarray(pose, np.float64), np.asarray(local, np.float64)
  return local @ pose[:3, :3].T + pose[:3, 3]


def gripper_collision(objects: Sequence[HeapObject], object_ids: np.ndarray, mask: np.ndarray, poses: np.ndarray,
                      points: np.ndarray, bin_: Bin = Bin(), tolerance: float = 1e-3) -> tuple[str | None, int]:
  """The reward's collision test of world-frame gripper samples against a simulated heap.

  Args:
    objects: the available objects' bodies; object_ids, mask: (P,) the heap's slots.
    poses: (P, 7) object-frame poses (xyz metres, wxyz).
    points: (K, 3) world-frame gripper samples (`collision_samples`).
    bin_: the bin; tolerance: metres a sample may lie inside an object or the bin.

  Returns:
    (``'collision_object'``, the first slot entered), (``'collision_bin'``, -1) or (None, -1), in the reward's
    order of checks (objects first).
  """
  for slot in np.flatnonzero(mask):
    rot = quat_to_matrix(np.asarray(poses[slot, 3:], np.float64), xp=np)
    local = (points - poses[slot, :3]) @ rot
    if np.any(penetration(objects[int(object_ids[slot])], local) > tolerance):
      return 'collision_object', int(slot)
  if bool(bin_collision(np.asarray(points, np.float32), bin_, tolerance)):
    return 'collision_bin', -1
  return None, -1


__all__ = ['collision_samples', 'gripper_collision', 'hull_planes', 'label_collision', 'penetration']
