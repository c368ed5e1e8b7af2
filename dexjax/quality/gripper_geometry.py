"""Collision geometry of the grippers as static sets of sample points in the gripper frame (metres).

The gripper frame is the one of `dexjax.grasps.parallel_jaw_pose` / `suction_pose`: origin at the grasp
centre, x = approach (pointing from the gripper toward the object), y = jaw axis, z = x cross y. Points lie at
the cell centres of a regular partition of each solid (cell edge <= ``GripperGeometry.spacing``), so the solid's
faces themselves (in particular the finger pads and the cup lip, which are meant to touch the object) are not
sampled; any penetration deeper than half a cell diagonal (~4.3 mm at the default 5 mm spacing) reaches a
sample point. Sample counts are static (from the static fields below); only the grasp width and the cup's
radius and height scale the points at run time, so the sets `jit` and `vmap` without recompiling.

Parallel jaw (ABB YuMi-like; the opening comes from the grasp, the other sizes from `GripperGeometry`):

* two fingers, each ``finger_thickness`` (along y, outward from its pad at y = +-width/2) by
  ``finger_width`` (along z) by ``finger_length`` (along x, ending ``tip_depth`` beyond the grasp centre);
* the palm behind the fingers: ``palm_depth`` (x) by ``palm_width`` (y, centred) by ``palm_height`` (z);
* the approach path: every solid swept back along -x by ``standoff`` (the gripper moves in from a pre-grasp
  pose ``standoff`` behind the grasp; the sweep of a box along its own x edges is a longer box);
* the closing region (contact test, not collision): the space between the pads, y in [-width/2, width/2],
  over the fingers' x and z extents, which the pads sweep when the jaws close.

Suction (the cup's radius r and cone height h come from `dexjax.grippers.SuctionGripper`):

* the cup, a cylinder of radius r from x = -h to the lip at x = 0, swept back by ``standoff``; the slab
  x in [-lip_allowance, 0] next to the lip is not tested (the compliant lip touches and conforms to the
  surface);
* the tool shaft, a cylinder of radius ``shaft_radius`` from x = -h back to x = -h - ``shaft_length``;
* the contact region: the cup's mouth disc of radius r in the plane x = 0.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct


@struct.dataclass
class GripperGeometry:
  """Sizes of the gripper solids used for collision and contact tests (all static, metres).

  Attributes:
    finger_thickness: finger size along the jaw axis, outward from the pad (YuMi-like 1 cm).
    finger_width: finger size along z, across the jaw axis and the approach (2 cm).
    finger_length: finger size along the approach (6 cm: the deepest image-sampler grasp, 5 cm below the
      surface, keeps the palm out of the object; see docs/deviations.md).
    tip_depth: how far the fingertips reach beyond the grasp centre along the approach (1 cm).
    palm_depth: palm size along the approach, behind the fingers (2 cm).
    palm_width: palm size along the jaw axis (7 cm: the 5 cm opening plus two fingers).
    palm_height: palm size along z (2 cm).
    shaft_radius: radius of the suction tool shaft (0.75 cm, a 1.5 cm shaft).
    shaft_length: length of the suction tool shaft behind the cup (10 cm).
    lip_allowance: untested slab behind the cup lip, where the compliant lip may touch the surface (3 mm).
    standoff: distance of the pre-grasp pose behind the grasp along the approach (5 cm).
    max_opening: largest jaw opening the closing region is sampled for (5 cm, YuMi).
    nominal_cup_height: cup height used only to choose the static number of samples along the cup (1 cm).
    spacing: largest edge of a sampling cell (5 mm).
    disc_rings: rings of samples across the cup's radius (the shaft gets one ring per ``spacing``).
  """

  finger_thickness: float = struct.field(pytree_node=False, default=0.01)
  finger_width: float = struct.field(pytree_node=False, default=0.02)
  finger_length: float = struct.field(pytree_node=False, default=0.06)
  tip_depth: float = struct.field(pytree_node=False, default=0.01)
  palm_depth: float = struct.field(pytree_node=False, default=0.02)
  palm_width: float = struct.field(pytree_node=False, default=0.07)
  palm_height: float = struct.field(pytree_node=False, default=0.02)
  shaft_radius: float = struct.field(pytree_node=False, default=0.0075)
  shaft_length: float = struct.field(pytree_node=False, default=0.1)
  lip_allowance: float = struct.field(pytree_node=False, default=0.003)
  standoff: float = struct.field(pytree_node=False, default=0.05)
  max_opening: float = struct.field(pytree_node=False, default=0.05)
  nominal_cup_height: float = struct.field(pytree_node=False, default=0.01)
  spacing: float = struct.field(pytree_node=False, default=0.005)
  disc_rings: int = struct.field(pytree_node=False, default=3)


def _count(length: float, spacing: float) -> int:
  """Static number of cells of edge <= ``spacing`` partitioning ``length``."""
  return max(1, math.ceil(length / spacing - 1e-9))


def _unit_grid(counts: tuple[int, int, int]) -> np.ndarray:
  """(n, 3) cell centres of a regular ``counts`` partition of the unit cube [0, 1]^3."""
  axes = [(np.arange(c) + 0.5) / c for c in counts]
  return np.stack(np.meshgrid(*axes, indexing='ij'), axis=-1).reshape(-1, 3).astype(np.float32)


def _unit_disc(rings: int) -> np.ndarray:
  """(n, 2) points covering the unit disc: the centre plus ``rings`` rings of 6 k points at radius k / rings."""
  pts = [np.zeros((1, 2))]
  for k in range(1, rings + 1):
    a = 2.0 * np.pi * (np.arange(6 * k) + 0.5 * (k % 2)) / (6 * k)
    pts.append((k / rings) * np.stack([np.cos(a), np.sin(a)], axis=-1))
  return np.concatenate(pts).astype(np.float32)


def _box(lo, hi, counts) -> jax.Array:
  """(n, 3) cell centres of the box [lo, hi] (arrays or floats, (3,)) partitioned into ``counts`` cells."""
  lo, hi = jnp.asarray(lo, jnp.float32), jnp.asarray(hi, jnp.float32)
  return lo + _unit_grid(counts) * (hi - lo)


def _cylinder(radius, x_lo, x_hi, num_x: int, rings: int) -> jax.Array:
  """(n, 3) samples of the cylinder of ``radius`` about the x axis between ``x_lo`` and ``x_hi``."""
  disc = jnp.asarray(_unit_disc(rings)) * radius
  xs = x_lo + (jnp.arange(num_x) + 0.5) / num_x * (x_hi - x_lo)
  x = jnp.repeat(xs, disc.shape[0])
  yz = jnp.tile(disc, (num_x, 1))
  return jnp.concatenate([x[:, None], yz], axis=1)


def jaw_collision_points(geometry: GripperGeometry, width: jax.Array) -> jax.Array:
  """(K, 3) gripper-frame samples of both fingers (pads at y = +-width/2, width in metres) and the palm,
  swept back by the standoff; K is static."""
  g = geometry
  x_lo, x_hi = g.tip_depth - g.finger_length - g.standoff, g.tip_depth
  counts = (_count(x_hi - x_lo, g.spacing), _count(g.finger_thickness, g.spacing),
            _count(g.finger_width, g.spacing))
  half = 0.5 * width
  fingers = [_box(jnp.stack([x_lo, s * half + min(s, 0) * g.finger_thickness, -0.5 * g.finger_width]),
                  jnp.stack([x_hi, s * half + max(s, 0) * g.finger_thickness, 0.5 * g.finger_width]), counts)
             for s in (1.0, -1.0)]
  palm_hi = g.tip_depth - g.finger_length
  palm_lo = palm_hi - g.palm_depth - g.standoff
  palm = _box([palm_lo, -0.5 * g.palm_width, -0.5 * g.palm_height], [palm_hi, 0.5 * g.palm_width, 0.5 * g.palm_height],
              (_count(palm_hi - palm_lo, g.spacing), _count(g.palm_width, g.spacing),
               _count(g.palm_height, g.spacing)))
  return jnp.concatenate(fingers + [palm])


def jaw_contact_points(geometry: GripperGeometry, width: jax.Array) -> jax.Array:
  """(C, 3) gripper-frame samples of the closing region between the pads (width in metres); C is static."""
  g = geometry
  half = 0.5 * width
  lo = jnp.stack([g.tip_depth - g.finger_length, -half, -0.5 * g.finger_width])
  hi = jnp.stack([jnp.float32(g.tip_depth), half, 0.5 * g.finger_width])
  counts = (_count(g.finger_length, g.spacing), _count(g.max_opening, g.spacing), _count(g.finger_width, g.spacing))
  return _box(lo, hi, counts)


def suction_collision_points(geometry: GripperGeometry, cup_radius: jax.Array, cup_height: jax.Array) -> jax.Array:
  """(K, 3) gripper-frame samples of the cup (radius and height in metres, swept back by the standoff,
  without the lip slab) and the tool shaft; K is static."""
  g = geometry
  cup_x = _count(g.nominal_cup_height + g.standoff - g.lip_allowance, g.spacing)
  cup = _cylinder(cup_radius, -(cup_height + g.standoff), -g.lip_allowance, cup_x, g.disc_rings)
  shaft_rings = _count(g.shaft_radius, g.spacing)
  shaft = _cylinder(g.shaft_radius, -(cup_height + g.shaft_length), -cup_height, _count(g.shaft_length, g.spacing),
                    shaft_rings)
  return jnp.concatenate([cup, shaft])


def suction_contact_points(geometry: GripperGeometry, cup_radius: jax.Array) -> jax.Array:
  """(C, 3) gripper-frame samples of the cup's mouth disc (radius in metres) in the lip plane x = 0."""
  disc = jnp.asarray(_unit_disc(geometry.disc_rings)) * cup_radius
  return jnp.concatenate([jnp.zeros((disc.shape[0], 1), disc.dtype), disc], axis=1)


def to_world(pose: jax.Array, points: jax.Array) -> jax.Array:
  """(K, 3) points of the gripper frame mapped by the (4, 4) gripper ``pose`` into its parent frame."""
  return points @ pose[:3, :3].T + pose[:3, 3]
