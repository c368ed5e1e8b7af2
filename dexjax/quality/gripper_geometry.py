"""Collision geometry of the grippers as static sets of sample points in the gripper frame (metres).

The gripper frame is the one of `dexjax.grasps.parallel_jaw_pose` / `suction_pose`: origin at the grasp
centre, x = approach (pointing from the gripper toward the object), y = jaw axis, z = x cross y. Points lie at
the cell centres of a regular partition of each solid (cell edge <= ``GripperGeometry.spacing``), so the solid's
faces themselves (in particular the finger pads and the cup lip, which are meant to touch the object) are not
sampled; any penetration deeper than half a cell diagonal (~4.3 mm at the default 5 mm spacing) reaches a
sample point. Sample counts are static (from static fields of the gripper and of `GripperGeometry`); only the
grasp width and the cup's radius and height scale the points at run time, so the sets `jit` and `vmap` without
recompiling.

Parallel jaw (ABB YuMi-like; the opening comes from the grasp, every size from the static fields of
`dexjax.grippers.ParallelJawGripper`, the one source of the jaw solids for the heap reward, the single-object
quality and the 3-D sampler):

* two fingers, each ``finger_thickness`` (along y, outward from its pad at y = +-width/2) by
  ``finger_width`` (along z) by ``finger_length`` (along x, ending ``tip_depth`` beyond the grasp centre);
  a ``finger_thickness`` of 0 means point jaws (Dex-Net's model): the fingers have no samples;
* the palm behind the fingers: ``palm_depth`` (x) by ``palm_width`` (y, centred) by ``palm_height`` (z);
* the approach path: every solid swept back along -x by ``standoff`` (the gripper moves in from a pre-grasp
  pose ``standoff`` behind the grasp; the sweep of a box along its own x edges is a longer box);
* the closing region (contact test, not collision): the space between the pads, y in [-width/2, width/2],
  over the fingers' x and z extents, which the pads sweep when the jaws close (`jaw_closing_box`: no bin wall
  may lie in it, or the jaws close on the wall).

`jaw_collides` is the single-object test of these solids against one `ObjectModel` (used by
`dexjax.quality.parallel_jaw_quality` and `dexjax.sampling.sample_antipodal_grasps`): the same cell-centre
samples, each followed by one refinement step toward the object (see there), which finds walls thinner than
the sample spacing.

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

from dexjax.config_rules import MAX_GRIPPER_SIZE, ConfigError, check_fields, count_rule, number_rule
from dexjax.geometry.object_model import ObjectModel
from dexjax.geometry.sdf import sdf_gradient, sdf_value
from dexjax.geometry.transforms import normalize
from dexjax.grasps import ParallelJawGrasp, parallel_jaw_pose
from dexjax.grippers import ParallelJawGripper

__all__ = [
    'GripperGeometry', 'MAX_COLLISION_SAMPLES', 'MAX_DISC_RINGS', 'REFINE_DEPTHS', 'REFINED_SAMPLES',
    'NEAREST_SAMPLES', 'check_collision_samples', 'jaw_closing_box', 'jaw_solids', 'jaw_collision_points',
    'jaw_clearance', 'jaw_collision_samples', 'jaw_contact_points', 'jaw_corner_points', 'nearest_jaw_samples',
    'jaw_collides', 'suction_collision_points', 'suction_contact_points', 'suction_rim_points', 'to_world',
]

#: Depths below the nearest surface, as multiples of the collision tolerance, to which `jaw_collides` moves
#: its nearest samples (one gradient step each): a wall thicker than about 2.5 tolerances is found wherever it
#: cuts a solid, even between the samples.
REFINE_DEPTHS = (1.25, 1.5, 2.0)

#: Samples per `jaw_collides` test that get the refinement step: those with the smallest signed distance.
REFINED_SAMPLES = 8

#: Samples that the robust quality tests at every Monte-Carlo draw's pose: the 64 of the K (1,136 by default)
#: nearest to the object at the nominal pose (`nearest_jaw_samples`, one pass over all K per grasp). Per draw
#: they agree with testing all K on 99.93-100 % of draws and keep the robust quality within ~2x of the
#: point-jaw cost (docs/deviations.md, item 38).
NEAREST_SAMPLES = 64


@struct.dataclass
class GripperGeometry:
  """How the gripper solids are sampled for collision and contact tests (all static, metres).

  The parallel-jaw sizes (fingers, palm) are fields of `dexjax.grippers.ParallelJawGripper`; the cup's radius
  and height are fields of `dexjax.grippers.SuctionGripper`.

  Attributes:
    shaft_radius: radius of the suction tool shaft (0.75 cm, a 1.5 cm shaft).
    shaft_length: length of the suction tool shaft behind the cup (10 cm).
    lip_allowance: untested slab behind the cup lip, where the compliant lip may touch the surface (3 mm).
    standoff: distance of the pre-grasp pose behind the grasp along the approach (5 cm): the solids are swept
      back by this much, so a collision on the approach path counts.
    max_opening: largest jaw opening the closing region is sampled for (5 cm, YuMi).
    nominal_cup_height: cup height used only to choose the static number of samples along the cup (1 cm).
    spacing: largest edge of a sampling cell (5 mm).
    disc_rings: rings of samples across the cup's radius (the shaft gets one ring per ``spacing``).
  """

  shaft_radius: float = struct.field(pytree_node=False, default=0.0075)
  shaft_length: float = struct.field(pytree_node=False, default=0.1)
  lip_allowance: float = struct.field(pytree_node=False, default=0.003)
  standoff: float = struct.field(pytree_node=False, default=0.05)
  max_opening: float = struct.field(pytree_node=False, default=0.05)
  nominal_cup_height: float = struct.field(pytree_node=False, default=0.01)
  spacing: float = struct.field(pytree_node=False, default=0.005)
  disc_rings: int = struct.field(pytree_node=False, default=3)

  def validate(self, source: str = 'GripperGeometry', section: str = '') -> GripperGeometry:
    """Returns ``self`` if the fields are consistent; raises `dexjax.config.ConfigError` (a ValueError) naming
    ``source``, the field and the expected value otherwise."""

    def size(field: str, low_open: bool = False):  # a length of at most MAX_GRIPPER_SIZE
      return number_rule(field, getattr(self, field), 0, MAX_GRIPPER_SIZE, 'metres', low_open=low_open)

    return check_fields([
        size('shaft_radius'), size('shaft_length'), size('lip_allowance'), size('standoff'),
        size('max_opening', low_open=True), size('nominal_cup_height', low_open=True),
        number_rule('spacing', self.spacing, 5e-4, MAX_GRIPPER_SIZE, 'metres; finer cells make millions of samples'),
        count_rule('disc_rings', self.disc_rings, 1, MAX_DISC_RINGS, 'rings of 6 k samples each'),
    ], self, source=source, section=section)


MAX_DISC_RINGS = 64
"""Largest `GripperGeometry.disc_rings` (64 rings: 12,481 samples per disc)."""

MAX_COLLISION_SAMPLES = 2_000_000
"""Largest number of collision samples of one gripper's solids (`check_collision_samples`): the default gripper
takes 1,136 (jaws) and 824 (suction) at the default 5 mm spacing, 1.14 M and 0.15 M at the finest, 0.5 mm."""


def _jaw_counts(gripper: ParallelJawGripper, geometry: GripperGeometry) -> list[tuple[int, int, int]]:
  """Static cell counts of each `jaw_solids` solid: both fingers (none for point jaws), then the palm."""
  g, s = gripper, geometry
  finger = (_count(g.finger_length + s.standoff, s.spacing), _count(g.finger_thickness, s.spacing),
            _count(g.finger_width, s.spacing))
  palm = (_count(g.palm_depth + s.standoff, s.spacing), _count(g.palm_width, s.spacing),
          _count(g.palm_height, s.spacing))
  return ([finger, finger] if g.finger_thickness > 0 else []) + [palm]


def _suction_count(geometry: GripperGeometry) -> int:
  """Static number of `suction_collision_points`: the swept cup and the tool shaft."""
  g = geometry
  cup_x = _count(g.nominal_cup_height + g.standoff - g.lip_allowance, g.spacing)
  shaft_rings = _count(g.shaft_radius, g.spacing)
  return cup_x * _disc_size(g.disc_rings) + _count(g.shaft_length, g.spacing) * _disc_size(shaft_rings)


def _disc_size(rings: int) -> int:
  """Number of `_unit_disc` points: the centre plus 6 k points on ring k."""
  return 1 + 3 * rings * (rings + 1)


def check_collision_samples(gripper: ParallelJawGripper, geometry: GripperGeometry, source: str = 'GripperGeometry',
                            section: str = 'quality.geometry') -> None:
  """Raises `ConfigError` naming ``source``, the spacing field and the sample count when the parallel-jaw solids
  (`jaw_collision_points`) or the suction solids (`suction_collision_points`) would take more than
  `MAX_COLLISION_SAMPLES` samples: every grasp tests all of them, so a large gripper at a fine spacing (both
  within their own limits) would exhaust the memory."""
  jaws = sum(math.prod(c) for c in _jaw_counts(gripper, geometry))
  for what, count in (('the parallel-jaw fingers and palm', jaws), ('the suction cup and shaft',
                                                                     _suction_count(geometry))):
    if count > MAX_COLLISION_SAMPLES:
      raise ConfigError(source, f'{section}.spacing', f'{what} would take {count:,} collision samples at a spacing of '
                        f'{geometry.spacing:g} m; expected at most {MAX_COLLISION_SAMPLES:,} (MAX_COLLISION_SAMPLES: '
                        'a coarser spacing or a smaller gripper)')


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


def jaw_solids(gripper: ParallelJawGripper, geometry: GripperGeometry,
               width: jax.Array) -> list[tuple[jax.Array, jax.Array, tuple[int, int, int]]]:
  """The parallel-jaw solids as gripper-frame boxes, swept back by the standoff: [(lo (3,), hi (3,), static
  cell counts)] for the +y finger, the -y finger (both left out when ``finger_thickness`` is 0) and the palm;
  the pads are at y = +-width/2 (width in metres)."""
  g, s = gripper, geometry
  x_lo, x_hi = g.tip_depth - g.finger_length - s.standoff, g.tip_depth
  half = 0.5 * jnp.asarray(width, jnp.float32)
  solids = []
  *fingers, palm_counts = _jaw_counts(g, s)
  if fingers:
    counts = fingers[0]
    for sign in (1.0, -1.0):
      y_lo = sign * half + min(sign, 0.0) * g.finger_thickness
      y_hi = sign * half + max(sign, 0.0) * g.finger_thickness
      solids.append((jnp.stack([jnp.float32(x_lo), y_lo, jnp.float32(-0.5 * g.finger_width)]),
                     jnp.stack([jnp.float32(x_hi), y_hi, jnp.float32(0.5 * g.finger_width)]), counts))
  palm_hi = g.tip_depth - g.finger_length
  palm_lo = palm_hi - g.palm_depth - s.standoff
  solids.append((jnp.asarray([palm_lo, -0.5 * g.palm_width, -0.5 * g.palm_height], jnp.float32),
                 jnp.asarray([palm_hi, 0.5 * g.palm_width, 0.5 * g.palm_height], jnp.float32),
                 palm_counts))
  return solids


def jaw_closing_box(gripper: ParallelJawGripper, width: jax.Array) -> tuple[jax.Array, jax.Array]:
  """(lo (3,), hi (3,)) float32 gripper-frame box the pads sweep as the jaws close from ``width`` (metres): x over
  the fingers' length (not swept back: the jaws close at the grasp), y between the pads, z across the pads."""
  g = gripper
  half = 0.5 * jnp.asarray(width, jnp.float32)
  return (jnp.stack([jnp.float32(g.tip_depth - g.finger_length), -half, jnp.float32(-0.5 * g.finger_width)]),
          jnp.stack([jnp.float32(g.tip_depth), half, jnp.float32(0.5 * g.finger_width)]))


def jaw_collision_samples(gripper: ParallelJawGripper, geometry: GripperGeometry,
                          width: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
  """(points (K, 3), lo (K, 3), hi (K, 3)): the `jaw_collision_points` and the box of the solid each belongs
  to (gripper frame, metres); K is static."""
  points, lows, highs = [], [], []
  for lo, hi, counts in jaw_solids(gripper, geometry, width):
    pts = _box(lo, hi, counts)
    points.append(pts)
    lows.append(jnp.broadcast_to(lo, pts.shape))
    highs.append(jnp.broadcast_to(hi, pts.shape))
  return jnp.concatenate(points), jnp.concatenate(lows), jnp.concatenate(highs)


def jaw_collision_points(gripper: ParallelJawGripper, geometry: GripperGeometry, width: jax.Array) -> jax.Array:
  """(K, 3) gripper-frame samples of both fingers (pads at y = +-width/2, width in metres) and the palm,
  swept back by the standoff; K is static. The heap reward tests exactly these points."""
  return jaw_collision_samples(gripper, geometry, width)[0]


def jaw_contact_points(gripper: ParallelJawGripper, geometry: GripperGeometry, width: jax.Array) -> jax.Array:
  """(C, 3) gripper-frame samples of the closing region between the pads (width in metres); C is static."""
  g, s = gripper, geometry
  half = 0.5 * width
  lo = jnp.stack([jnp.float32(g.tip_depth - g.finger_length), -half, jnp.float32(-0.5 * g.finger_width)])
  hi = jnp.stack([jnp.float32(g.tip_depth), half, jnp.float32(0.5 * g.finger_width)])
  counts = (_count(g.finger_length, s.spacing), _count(s.max_opening, s.spacing), _count(g.finger_width, s.spacing))
  return _box(lo, hi, counts)


def _jaw_frame(grasp: ParallelJawGrasp) -> tuple[jax.Array, jax.Array]:
  """(rotation (3, 3), origin (3,)) of `parallel_jaw_pose`: object point = rotation @ gripper point + origin."""
  pose = parallel_jaw_pose(grasp)
  return pose[:3, :3], pose[:3, 3]


def nearest_jaw_samples(model: ObjectModel, grasp: ParallelJawGrasp, gripper: ParallelJawGripper,
                        geometry: GripperGeometry, count: int) -> jax.Array:
  """(min(count, K),) int32 indices of the `jaw_collision_samples` with the smallest signed distance to
  ``model`` at the pose of ``grasp`` (object frame): the samples a small change of the pose can bring into the
  object first. ``count`` is static."""
  rot, origin = _jaw_frame(grasp)
  points = jaw_collision_points(gripper, geometry, grasp.width)
  d = jax.vmap(lambda p: sdf_value(model, rot @ p + origin))(points)
  return jax.lax.top_k(-d, min(count, points.shape[0]))[1]


def jaw_clearance(model: ObjectModel, grasp: ParallelJawGrasp, gripper: ParallelJawGripper,
                  geometry: GripperGeometry, tolerance: float | jax.Array,
                  samples: jax.Array | None = None) -> jax.Array:
  """() smallest signed distance to ``model`` of the open parallel-jaw gripper's tested points, metres
  (negative: the deepest point inside the object; +inf for point jaws). `jaw_collides` is ``clearance <
  -tolerance``; differentiable in the grasp pose (the tested points move with it).

  Tested points, at `dexjax.grasps.parallel_jaw_pose`: the `jaw_collision_points` (the heap reward's; all K,
  or the static subset of indices ``samples``, e.g. `nearest_jaw_samples` of a nearby pose), and for the
  ``REFINED_SAMPLES`` of them with the smallest signed distance d, ``len(REFINE_DEPTHS)`` refined points
  p - (d + delta) n each, with n the unit gradient at p (gripper frame) and delta = ``REFINE_DEPTHS`` x
  ``tolerance``: a step to the depth delta below the surface nearest to p, clipped to the box of p's solid,
  so that every tested point stays inside the gripper. A wall of thickness w cutting a solid has points deeper
  than the tolerance only if w > 2 x tolerance; the refined points find walls from about 2.5 tolerances on
  wherever they lie between the samples, which a plain sample grid would need a spacing below w - 2 x tolerance
  for (measured in docs/deviations.md, item 38).
  """
  if gripper.finger_thickness <= 0:
    return jnp.asarray(jnp.inf, jnp.float32)
  rot, origin = _jaw_frame(grasp)
  points, lows, highs = jaw_collision_samples(gripper, geometry, grasp.width)
  if samples is not None:
    points, lows, highs = points[samples], lows[samples], highs[samples]
  to_object = lambda p: rot @ p + origin
  d = jax.vmap(lambda p: sdf_value(model, to_object(p)))(points)
  _, nearest = jax.lax.top_k(-d, min(REFINED_SAMPLES, points.shape[0]))
  depths = jnp.asarray(REFINE_DEPTHS, jnp.float32) * tolerance

  def refined(p, d_p, lo, hi):
    n = rot.T @ normalize(sdf_gradient(model, to_object(p)))
    q = jnp.clip(p[None, :] - (d_p + depths)[:, None] * n[None, :], lo, hi)
    return jnp.min(jax.vmap(lambda y: sdf_value(model, to_object(y)))(q), initial=jnp.inf)

  deep = jax.vmap(refined)(points[nearest], d[nearest], lows[nearest], highs[nearest])
  return jnp.minimum(jnp.min(d), jnp.min(deep))


def jaw_collides(model: ObjectModel, grasp: ParallelJawGrasp, gripper: ParallelJawGripper,
                 geometry: GripperGeometry, tolerance: float | jax.Array,
                 samples: jax.Array | None = None) -> jax.Array:
  """() bool: the open parallel-jaw gripper of ``grasp`` (object frame) overlaps ``model`` by more than
  ``tolerance`` metres somewhere in its fingers or palm, at the grasp pose or on its approach path: its
  `jaw_clearance` (same arguments; the tested points are described there) is below ``-tolerance``. With
  ``gripper.finger_thickness == 0`` (point jaws) nothing is tested and the result is False (static)."""
  if gripper.finger_thickness <= 0:
    return jnp.asarray(False)
  return jaw_clearance(model, grasp, gripper, geometry, tolerance, samples) < -tolerance


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


def jaw_corner_points(gripper: ParallelJawGripper, geometry: GripperGeometry, width: jax.Array) -> jax.Array:
  """(8 S, 3) gripper-frame corners of the swept fingers and palm (`jaw_solids`, S solids): a solid's extreme
  point toward any plane, so a test of the corners against the bin's floor is exact."""
  signs = jnp.asarray(np.array(np.meshgrid([0.0, 1.0], [0.0, 1.0], [0.0, 1.0], indexing='ij')).reshape(3, -1).T,
                      jnp.float32)
  return jnp.concatenate([lo + signs * (hi - lo) for lo, hi, _ in jaw_solids(gripper, geometry, width)])


def suction_rim_points(geometry: GripperGeometry, cup_radius: jax.Array, cup_height: jax.Array,
                       count: int = 16) -> jax.Array:
  """(4 count, 3) gripper-frame points on the rims of the swept cup (its front face ``lip_allowance`` behind the
  lip, its back face) and of the shaft's ends: a disc's extreme point toward a plane lies on its rim, so with
  ``count`` points the floor test is within r (1 - cos(pi / count)) of exact."""
  g = geometry
  angles = 2.0 * jnp.pi * jnp.arange(count) / count
  circle = jnp.stack([jnp.cos(angles), jnp.sin(angles)], axis=1)
  rim = lambda x, radius: jnp.concatenate([jnp.full((count, 1), x, jnp.float32), radius * circle], axis=1)
  return jnp.concatenate([rim(-g.lip_allowance, cup_radius), rim(-(cup_height + g.standoff), cup_radius),
                          rim(-cup_height, g.shaft_radius), rim(-(cup_height + g.shaft_length), g.shaft_radius)])


def suction_contact_points(geometry: GripperGeometry, cup_radius: jax.Array) -> jax.Array:
  """(C, 3) gripper-frame samples of the cup's mouth disc (radius in metres) in the lip plane x = 0."""
  disc = jnp.asarray(_unit_disc(geometry.disc_rings)) * cup_radius
  return jnp.concatenate([jnp.zeros((disc.shape[0], 1), disc.dtype), disc], axis=1)


def to_world(pose: jax.Array, points: jax.Array) -> jax.Array:
  """(K, 3) points of the gripper frame mapped by the (4, 4) gripper ``pose`` into its parent frame."""
  return points @ pose[:3, :3].T + pose[:3, 3]
