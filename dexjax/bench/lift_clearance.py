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
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from dexjax.geometry.transforms import quat_to_matrix
from dexjax.quality.heap_reward import HeapScene, slot_distances, slot_model

LIFT_HEIGHT = 0.1
"""Raise tested, m: the bin's walls' height (an object that clears it is out of the heap)."""

LIFT_STEP = 0.004
"""Step of the raise, m (finer than the thinnest procedural part, 5 mm)."""

LIFT_TOLERANCE = 0.002
"""Depth a raised sample may enter another object, m: objects at rest touch, and the distance grids are exact to
about a voxel's half (1-2 mm at the benchmark's grid size); an object resting on the target is entered by a full
step (4 mm) at the first raise."""


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


__all__ = ['LIFT_HEIGHT', 'LIFT_STEP', 'LIFT_TOLERANCE', 'lift_clearance', 'slots_clear_to_lift']
