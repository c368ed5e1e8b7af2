"""How far an object of a heap can rise straight up before it runs into another: the supervisor's lift test.

The labels' reward is quasi-static: it weighs the grasped object (and, in the supervisor's bin rewards, the load
its neighbours press it with at rest) but not what the object meets as it rises. Traced in the physics judge
(docs/benchmark.md): a 66 g bottle held by the cup rose against a neighbour lying over it, was pressed with
1-2 N (twice its weight) and tilted onto the cup's rigid body until the lip peeled; a 36 g blister pack under
two porcelain bowls, pressed with 2.4 N at rest, carried 5 N as it rose. Both are obvious from the bin's true
geometry: raise the object and see whether it enters a neighbour.

`lift_clearance` raises the object's surface samples (its model's first ``num_points`` area-uniform
``surface_points``, in the slot's pose) straight up in steps of ``step`` up to ``height`` and returns the largest
raise before a sample lies more than ``tolerance`` inside another object (signed distance grids, as the reward's
collision test). An object lying free, or beside others, clears the full height; one under a neighbour, or under
an overhang, does not. The bin is not tested: walls are vertical.

`wall_gaps` is each object's smallest distance to the bin's walls. What the straight raise misses (measured,
docs/benchmark.md): an object touching a wall held by a *tilted* cup. Of the 151 suction grasps of ten level-2
supervisor trials, the 52 on objects within 5 mm of a wall with the cup more than 0.1 rad off vertical succeeded
under the physics judge 36 times (0.69; the analytic reward passed 46), the 70 tilted ones away from the walls 63
times (0.90) and the 29 within 0.1 rad of vertical every time; 16 of the 23 suction failures were of the first
kind. Traced: the held object drags on the wall as it rises (3.6-4.8 N on a 0.14 kg blister pack) until the lip
shears. `wall_hold_risk` names those grasps (`WALL_CONTACT`, `WALL_TILT`), so the supervisor tries them after
every other passing grasp.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from dexjax.geometry.transforms import quat_to_matrix
from dexjax.quality.heap_reward import HeapScene, slot_distances, slot_model
from dexjax.sim.heap import Bin

LIFT_HEIGHT = 0.1
"""Raise tested, m: the bin's walls' height (an object that clears it is out of the heap)."""

LIFT_STEP = 0.004
"""Step of the raise, m (finer than the thinnest procedural part, 5 mm)."""

LIFT_TOLERANCE = 0.002
"""Depth a raised sample may enter another object, m: objects at rest touch, and the distance grids are exact to
about a voxel's half (1-2 mm at the benchmark's grid size); an object resting on the target is entered by a full
step (4 mm) at the first raise."""


WALL_CONTACT = 0.005
"""Distance to a wall within which an object counts as touching it, m: the 5 mm of the measurement above (the
surface samples are 256 points, a few millimetres apart on small objects)."""

WALL_TILT = 0.1
"""Cup tilt from vertical above which a grasp on an object touching a wall is a risk, rad (the measurement above:
29 of 29 succeeded below it)."""


def wall_gaps(scene: HeapScene, bin: Bin, num_points: int = 256) -> jax.Array:  # pylint: disable=redefined-builtin
  """(P,) float32 each slot's smallest horizontal distance from its surface samples (``num_points``, static) to
  the bin's inner walls, m (negative: past a wall; +inf in empty slots)."""
  half = jnp.asarray(bin.inner_size, jnp.float32) / 2

  def gap(slot):
    model = slot_model(scene, slot)
    pose = scene.poses[slot]
    points = model.surface_points[:num_points] @ quat_to_matrix(pose[3:], xp=jnp).T + pose[:3]
    return jnp.min(half - jnp.abs(points[:, :2]))

  gaps = jax.vmap(gap)(jnp.arange(scene.mask.shape[0]))
  return jnp.where(scene.mask, gaps, jnp.inf).astype(jnp.float32)


def wall_hold_risk(approach: jax.Array, gap: jax.Array, contact: float = WALL_CONTACT,
                   tilt: float = WALL_TILT) -> jax.Array:
  """() bool: a suction grasp of world approach direction ``approach`` (3,) (into the surface) on an object whose
  `wall_gaps` entry is ``gap`` (m) risks dragging on the wall: the object touches it and the cup is tilted more
  than ``tilt`` rad from vertical."""
  up = -approach[2] / jnp.maximum(jnp.linalg.norm(approach), 1e-12)
  return (gap <= contact) & (up < jnp.cos(tilt))


def lift_clearance(scene: HeapScene, slot: jax.Array, height: float = LIFT_HEIGHT, step: float = LIFT_STEP,
                   tolerance: float = LIFT_TOLERANCE, num_points: int = 256) -> jax.Array:
  """() float32 the largest straight-up raise (m, a multiple of ``step``, at most ``height``) of the object in
  ``slot`` (() int) before one of its surface samples enters another object of ``scene`` by more than
  ``tolerance`` (m); ``height`` when none does, 0 when the first step is blocked. ``height``, ``step`` and
  ``num_points`` are static. Batch over slots with `jax.vmap`."""
  model = slot_model(scene, slot)
  pose = scene.poses[slot]
  points = model.surface_points[:num_points] @ quat_to_matrix(pose[3:], xp=jnp).T + pose[:3]
  others = jnp.arange(scene.mask.shape[0]) != slot
  raises = step * jnp.arange(1, int(round(height / step)) + 1, dtype=jnp.float32)

  def deepest(dz):
    d = slot_distances(scene, points + jnp.stack([jnp.float32(0.0), jnp.float32(0.0), dz]))
    return jnp.min(jnp.where(others[:, None], d, jnp.inf))

  blocked = jax.lax.map(deepest, raises) < -tolerance
  first = jnp.argmax(blocked)
  return jnp.where(jnp.any(blocked), raises[first] - step, jnp.float32(height)).astype(jnp.float32)


def slots_clear_to_lift(scene: HeapScene, height: float = LIFT_HEIGHT, step: float = LIFT_STEP,
                        tolerance: float = LIFT_TOLERANCE) -> jax.Array:
  """(P,) bool: each slot's object rises the full ``height`` (m) without entering another (`lift_clearance`);
  False in empty slots."""
  slots = jnp.arange(scene.mask.shape[0])
  clearance = jax.vmap(lambda s: lift_clearance(scene, s, height, step, tolerance))(slots)
  return scene.mask & (clearance >= height - 0.5 * step)


__all__ = ['LIFT_HEIGHT', 'LIFT_STEP', 'LIFT_TOLERANCE', 'WALL_CONTACT', 'WALL_TILT', 'lift_clearance',
           'slots_clear_to_lift', 'wall_gaps', 'wall_hold_risk']
