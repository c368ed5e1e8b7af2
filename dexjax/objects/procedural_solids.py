"""Level-1 procedural families: household boxes and cylinders (Dex-Net 4.0 difficulty level 1).

The seed's level 1 holds "prismatic and circular solids" that every policy picks more than 80 % of the time,
the parallel-jaw-only ones included. These families draw household-sized solids with *absolute* dimensions:
each ``draw`` picks the object's largest extent in `LEVEL1_EXTENT_RANGE` (0.06-0.14 m, log-uniform) and its
other dimensions in metres, at least `LEVEL1_MIN_THICKNESS` (0.03 m, 1.5 x the seed's 20 mm suction cup; round
solids at least `LEVEL1_MIN_ROUND_DIAMETER`, 0.04 m, across, so the cup seals on their curved side), and
returns them as ``'extent'`` plus model-unit parameters (lengths / extent, so the built shape's largest
bounding-box side is 1). With probability `LEVEL1_JAW_FRACTION` (0.8) an object's width, the dimension across
it as it lies, is at most `LEVEL1_JAW_WIDTH` (0.045 m: the seed's 5 cm jaw opening less 5 mm), so that the jaws
as well as the cup can pick it (a bar, a tall can); the others may be as wide as they are long (a flat box, a
tuna can: the cup's). Balls are at least 6 cm across, wider than the jaws open. Every shape is convex:

* ``box``: a box (packaged goods: cracker, sugar, gelatin boxes);
* ``cylinder``: a cylinder, tall (soup, coffee cans, jars) or squat (a tuna can);
* ``rounded_box``: a box with rounded edges (soap bars, erasers, sponges), every face's flat at least
  `LEVEL1_MIN_FACE` (0.03 m, 1.5 x the cup) across;
* ``prism``: an irregular convex quadrilateral or hexagonal prism (toy blocks), every face at least
  `LEVEL1_MIN_FACE` wide (a lying odd prism shows the cup a ridge);
* ``frustum``: a truncated cone, the top 0.5-0.85 of the base across and at least 4 cm (tubs, cups, cone toys);
* ``ball``: a sphere or an ellipsoid with axis ratios >= 0.75 (sports and toy balls).

Each family's `Material` (density range and source) is in `procedural_materials`.
"""

from __future__ import annotations

import numpy as np

from dexjax.objects.procedural_materials import BALLS
from dexjax.objects.procedural_materials import BLOCKS
from dexjax.objects.procedural_materials import BOXED_GOODS
from dexjax.objects.procedural_materials import CANNED_GOODS
from dexjax.objects.procedural_materials import HOUSEHOLD_SOLIDS
from dexjax.objects.procedural_shapes import Manifold
from dexjax.objects.procedural_shapes import Params
from dexjax.objects.procedural_shapes import ShapeFamily
from dexjax.objects.procedural_shapes import box
from dexjax.objects.procedural_shapes import cylinder
from dexjax.objects.procedural_shapes import ellipsoid
from dexjax.objects.procedural_shapes import extrude
from dexjax.objects.procedural_shapes import log_uniform
from dexjax.objects.procedural_shapes import polygon
from dexjax.objects.procedural_shapes import rounded_box

__all__ = ['LEVEL1_EXTENT_RANGE', 'LEVEL1_MIN_THICKNESS', 'LEVEL1_MIN_ROUND_DIAMETER', 'LEVEL1_MIN_FACE', 'LEVEL1_JAW_WIDTH',
           'LEVEL1_JAW_FRACTION', 'LEVEL1_FAMILIES', 'prism_outline']

LEVEL1_EXTENT_RANGE: tuple[float, float] = (0.06, 0.14)
"""Range of a level-1 object's largest extent, metres (drawn log-uniformly)."""

LEVEL1_MIN_THICKNESS: float = 0.03
"""Smallest extent of a level-1 object, metres: 1.5 x the seed's 20 mm suction cup, above the jaws' 2 cm reach."""

LEVEL1_MIN_ROUND_DIAMETER: float = 0.04
"""Smallest diameter of a level-1 cylinder or frustum (both its ends), metres. The seed's 20 mm cup does not seal
on the side of a thinner one lying down: on Dex-Net 3.0's seal model (`dexjax.contacts.suction_seal`, 10 % strain)
the cup vertical on the top line of a lying cylinder strains 0.104 at 3 cm across, 0.070 at 4 cm and 0.054 at
5 cm (measured 2026-12-06); a cup-only policy could never pick a thinner can lying down."""

LEVEL1_MIN_FACE: float = 0.03
"""Narrowest flat face of a level-1 box, rounded box or prism, metres: 1.5 x the seed's 20 mm cup, as
`LEVEL1_MIN_THICKNESS`, so a cup aimed from a noisy image a few millimetres off a face's centre still has the whole
lip on the flat. On Dex-Net 3.0's seal model (10 % strain) the cup vertical on a 3 cm rounded box, 2 mm off the
face's centre, strains 0.01 with a 2.2 cm flat, 0.08 with 1.4 cm and 0.19 with 0.3 cm (radius 13.5 mm; measured
2026-12-06). With 2 cm (objects version 5) the suction heuristic failed to seal 17 times on level-1 faces 2-3 cm
wide of `procedural:L1/0:25@77` in five trials (docs/benchmark.md; objects version 6, 2026-12-07)."""

LEVEL1_JAW_WIDTH: float = 0.045
"""Widest dimension across a jaw-friendly level-1 object, metres (the seed's 5 cm jaw opening less 5 mm)."""

LEVEL1_JAW_FRACTION: float = 0.8
"""Share of the level-1 boxes, cylinders, prisms and frusta drawn jaw-friendly (width <= `LEVEL1_JAW_WIDTH`)."""

_MIN_BALL_RATIO = 0.75  # Smallest / largest semi-axis of a ball.
_SPHERE_FRACTION = 0.2  # Share of exact spheres among the balls.


def _largest(rng: np.random.Generator) -> float:
  """A level-1 largest extent, metres."""
  return log_uniform(rng, *LEVEL1_EXTENT_RANGE)


def _side(rng: np.random.Generator, largest: float, smallest: float = LEVEL1_MIN_THICKNESS) -> float:
  """A dimension uniform in [smallest, largest], metres."""
  return float(rng.uniform(smallest, largest))


def _extent_and_width(rng: np.random.Generator,
                      smallest: float = LEVEL1_MIN_THICKNESS) -> tuple[float, float, bool]:
  """(largest extent, width, jaw-friendly), metres: the width (the second-largest dimension, >= ``smallest``) is
  at most `LEVEL1_JAW_WIDTH` with probability `LEVEL1_JAW_FRACTION`, else uniform up to the extent."""
  extent, jaws = _largest(rng), bool(rng.random() < LEVEL1_JAW_FRACTION)
  return extent, _side(rng, LEVEL1_JAW_WIDTH if jaws else extent, smallest), jaws


def _draw_box(rng: np.random.Generator) -> Params:
  extent, width, _ = _extent_and_width(rng)
  sides = np.r_[extent, width, _side(rng, width)][rng.permutation(3)]  # Lying on its largest face: width across.
  return {'extent': extent, 'size': sides / extent}


def _build_box(p: Params) -> Manifold:
  return box(p['size'])


def _draw_rounded_box(rng: np.random.Generator) -> Params:
  params = _draw_box(rng)
  # Every face keeps a flat of at least LEVEL1_MIN_FACE: the radius is at most half the shortest side's excess.
  thinnest = float(params['size'].min()) * params['extent']
  params['radius'] = float(rng.uniform(0.2, 1.0) * 0.5 * (thinnest - LEVEL1_MIN_FACE)) / params['extent']
  return params


def _build_rounded_box(p: Params) -> Manifold:
  return rounded_box(p['size'], p['radius'])


def _round_solid(rng: np.random.Generator) -> Params:
  """Extent, diameter and height (model units) of a round solid: tall (height = extent; always when
  jaw-friendly, so the diameter is the width) or squat (diameter = extent, e.g. a tuna can)."""
  extent, width, jaws = _extent_and_width(rng, LEVEL1_MIN_ROUND_DIAMETER)
  tall = jaws or bool(rng.random() < 0.5)
  return {'extent': extent, 'diameter': width / extent if tall else 1.0, 'height': 1.0 if tall else width / extent}


def _draw_cylinder(rng: np.random.Generator) -> Params:
  return _round_solid(rng)


def _build_cylinder(p: Params) -> Manifold:
  return cylinder(0.5 * p['diameter'], p['height'])


def _draw_frustum(rng: np.random.Generator) -> Params:
  # The top 0.5-0.85 of the base, and at least LEVEL1_MIN_ROUND_DIAMETER across, so that the cup seals all along a
  # lying frustum's side as on a cylinder's (a base of 4-4.7 cm then tapers less than 0.85: a tub, nearly a can).
  params, ratio = _round_solid(rng), float(rng.uniform(0.5, 0.85))
  base = params['diameter'] * params['extent']
  return {**params, 'top_over_bottom': max(ratio, LEVEL1_MIN_ROUND_DIAMETER / base)}


def _build_frustum(p: Params) -> Manifold:
  return cylinder(0.5 * p['diameter'], p['height'], radius_top=0.5 * p['diameter'] * p['top_over_bottom'])


def prism_outline(sides: int, irregularity: np.ndarray) -> np.ndarray:
  """(sides, 2) vertices of an irregular convex polygon whose bounding box's larger side is 1.

  The vertices sit half a pitch off the x axis (a quadrilateral is a jittered square with its sides along the
  axes, not a diamond), so its bounding box is as narrow as its faces allow: with 3 cm faces a diamond's box is
  4.2 cm or more, wider than a jaw-friendly object may be.

  Args:
    sides: number of vertices, >= 3.
    irregularity: (>= sides,) angular jitter of each vertex on its circle, in pitches (|jitter| < 0.5 keeps
      the order and convexity).
  """
  angles = 2 * np.pi * (np.arange(sides) + 0.5 + np.asarray(irregularity)[:sides]) / sides
  points = np.c_[np.cos(angles), np.sin(angles)]
  low, high = points.min(axis=0), points.max(axis=0)
  return (points - 0.5 * (low + high)) / float(np.max(high - low))


def _min_width(points: np.ndarray) -> float:
  """Thinnest width of the convex polygon with (N, 2) vertices ``points`` in order (the smallest extent across
  any edge's normal: where a convex polygon's minimum width lies)."""
  edges = np.roll(points, -1, axis=0) - points
  normals = np.c_[edges[:, 1], -edges[:, 0]] / np.linalg.norm(edges, axis=1, keepdims=True)
  return float(np.min(np.ptp(points @ normals.T, axis=0)))


def _min_edge(points: np.ndarray) -> float:
  """Shortest edge of the polygon with (N, 2) vertices ``points`` in order."""
  return float(np.min(np.linalg.norm(np.roll(points, -1, axis=0) - points, axis=1)))


def _draw_prism(rng: np.random.Generator) -> Params:
  # Four or six sides, every face at least LEVEL1_MIN_FACE wide: lying on a face, an even prism shows the camera
  # the opposite face, an odd one a ridge (a lying pentagon strains the cup 0.18 at its top, a heptagon 0.13; the
  # limit is 0.10), and a face narrower than the cup breaks its seal (a hexagon 3.8 cm across its corners, faces
  # 1.9 cm: 0.20 at 2 mm off the face's centre). A triangle offers the jaws two faces 60 degrees apart (Omega
  # found 13 jaw grasps of 400 and the supervisor none in the bin, in any of 5 trials). Hexagons (faces ~0.5 x
  # the polygon's larger side) are wider than the jaws open, so a jaw-friendly prism has four sides.
  extent, width, jaws = _extent_and_width(rng)
  sides, irregularity = (4 if jaws or rng.random() < 0.5 else 6), rng.uniform(-0.15, 0.15, 8)
  outline = prism_outline(sides, irregularity)
  # The polygon's larger side must give it the minimum thickness across and its faces the minimum face width.
  narrowest = max(LEVEL1_MIN_THICKNESS / _min_width(outline), LEVEL1_MIN_FACE / _min_edge(outline))
  if jaws:  # A tall prism whose polygon fits the jaws: ``width`` rescaled from [0.03, 0.045] to [narrowest, 0.045].
    share = (width - LEVEL1_MIN_THICKNESS) / (LEVEL1_JAW_WIDTH - LEVEL1_MIN_THICKNESS)
    width, height = min(narrowest + share * max(0.0, LEVEL1_JAW_WIDTH - narrowest), extent), extent
  elif rng.random() < 0.5:  # The polygon spans the extent; the height is the other dimension.
    width, height = max(extent, narrowest), width
  else:  # A tall prism with a wide polygon.
    width, height = _side(rng, extent, min(extent, narrowest)), extent
  return {'extent': extent, 'sides': sides, 'irregularity': irregularity, 'width': width / extent,
          'height': height / extent}


def _build_prism(p: Params) -> Manifold:
  return extrude(polygon(p['width'] * prism_outline(p['sides'], p['irregularity'])), p['height'])


def _draw_ball(rng: np.random.Generator) -> Params:
  extent = _largest(rng)
  axes = np.r_[0.5, 0.5 * rng.uniform(_MIN_BALL_RATIO, 1.0, 2)]
  if rng.random() < _SPHERE_FRACTION:
    axes[:] = 0.5
  return {'extent': extent, 'semi_axes': axes[rng.permutation(3)]}


def _build_ball(p: Params) -> Manifold:
  return ellipsoid(p['semi_axes'])


LEVEL1_FAMILIES: tuple[ShapeFamily, ...] = (
    ShapeFamily('box', _draw_box, _build_box, BOXED_GOODS),
    ShapeFamily('cylinder', _draw_cylinder, _build_cylinder, CANNED_GOODS),
    ShapeFamily('rounded_box', _draw_rounded_box, _build_rounded_box, HOUSEHOLD_SOLIDS),
    ShapeFamily('prism', _draw_prism, _build_prism, BLOCKS),
    ShapeFamily('frustum', _draw_frustum, _build_frustum, HOUSEHOLD_SOLIDS),
    ShapeFamily('ball', _draw_ball, _build_ball, BALLS),
)
"""Level 1 (household boxes and cylinders), all convex, at least `LEVEL1_MIN_THICKNESS` thick."""
