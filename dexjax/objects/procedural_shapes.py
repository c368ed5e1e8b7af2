"""Building blocks of the procedural object generator: the `ShapeFamily` record, random draws and primitives.

The generator (`dexjax.objects.procedural`) draws the parameters of a *shape family* from a
`numpy.random.Generator` and then builds a `manifold3d.Manifold` from them. Families work in *model units*:
their largest dimension is about 1 and the generator rescales the result to the object's largest extent in
metres, ``params['extent']``. That extent is drawn by the generator (log-uniform in `SIZE_RANGE`) unless the
family draws it itself: a family whose parts need absolute sizes (level 1's boxes and cans, at least 3 cm
thick; level 2's tool handles and letter strokes, at least 1.5-2 cm) returns ``'extent'`` (metres) from its
``draw`` and expresses its other lengths as metres / extent. Thin features (walls, rods, fins, plates) are at
least about 3 % of the largest extent, i.e. at least 2-3 voxels of the default 100^3 signed distance grid.

This module holds the `ShapeFamily` record, the random draws and small `manifold3d` constructors used by all
levels (boxes, cylinders, ellipsoids, capsules, revolved profiles, extruded polygons, booleans). The families
are in `procedural_solids` (level 1), `procedural_household` (level 2) and `procedural_adversarial` (level 3);
their materials in `procedural_materials`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import manifold3d
import numpy as np
import trimesh

from dexjax.objects.procedural_materials import Material

Manifold = manifold3d.Manifold
CrossSection = manifold3d.CrossSection
Params = dict[str, Any]
"""Drawn parameters of one shape: floats, ints, strings and small numpy arrays (model units, degrees)."""

ROUND_SEGMENTS: int = 48
"""Segments of a full circle for cylinders, discs and revolved profiles."""

SPHERE_SEGMENTS: int = 32
"""Segments of a full circle for spheres and ellipsoids (about 512 triangles)."""

SMALL_SEGMENTS: int = 16
"""Segments of a full circle for small parts (pins, spikes, holes, rounded corners)."""

SIZE_RANGE: tuple[float, float] = (0.06, 0.15)
"""Range of the largest extent of a level-2 or level-3 object, metres (household size; drawn log-uniformly)."""


@dataclasses.dataclass(frozen=True)
class ShapeFamily:
  """One family of procedural shapes.

  Attributes:
    name: short name shown in previews and docs, e.g. ``'mug'``.
    draw: draws the family's parameters from a generator (must consume the generator deterministically); may
      return ``'extent'``, the object's largest extent in metres (see the module docstring).
    build: turns the parameters into a closed `manifold3d.Manifold` in model units (largest extent ~1).
    material: what the family's objects are made of: the density range the generator draws from.
  """
  name: str
  draw: Callable[[np.random.Generator], Params]
  build: Callable[[Params], Manifold]
  material: Material


# ----------------------------------------------------------------------------------------------------------
# Random draws.


def log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
  """Draws a float whose logarithm is uniform on [log(low), log(high)] (for aspect ratios)."""
  return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def draw_extent(rng: np.random.Generator, low: float = SIZE_RANGE[0], high: float = SIZE_RANGE[1]) -> float:
  """Draws a largest extent, metres, log-uniformly in [low, high] (within `SIZE_RANGE` by default)."""
  return log_uniform(rng, low, high)


def rotation_from_uniform(uniform: np.ndarray) -> np.ndarray:
  """The (3, 3) rotation given by (3,) numbers uniform on [0, 1) (uniformly random when they are)."""
  return trimesh.transformations.random_rotation_matrix(rand=np.asarray(uniform, np.float64))[:3, :3]


# ----------------------------------------------------------------------------------------------------------
# Primitives (model units, centred on the origin unless stated).


def box(size: Sequence[float], centre: Sequence[float] = (0.0, 0.0, 0.0)) -> Manifold:
  """An axis-aligned box of (3,) ``size`` centred at (3,) ``centre``."""
  return Manifold.cube(tuple(float(s) for s in size), center=True).translate(tuple(float(c) for c in centre))


def cylinder(radius: float, height: float, *, radius_top: float | None = None,
             segments: int = ROUND_SEGMENTS) -> Manifold:
  """A cylinder (or frustum when ``radius_top`` is given) along z, centred on the origin."""
  top = radius if radius_top is None else radius_top
  return Manifold.cylinder(float(height), float(radius), float(top), segments, center=True)


def ellipsoid(semi_axes: Sequence[float], segments: int = SPHERE_SEGMENTS) -> Manifold:
  """An axis-aligned ellipsoid with (3,) ``semi_axes``, centred on the origin."""
  return Manifold.sphere(1.0, segments).scale(tuple(float(a) for a in semi_axes))


def capsule(radius: float, length: float, segments: int = SPHERE_SEGMENTS) -> Manifold:
  """A capsule along z of overall ``length`` (>= 2 radius), centred on the origin (hull of two spheres)."""
  half = 0.5 * float(length) - float(radius)
  ball = Manifold.sphere(float(radius), segments)
  return Manifold.batch_hull([ball.translate((0.0, 0.0, -half)), ball.translate((0.0, 0.0, half))])


def rod(start: Sequence[float], end: Sequence[float], radius: float, *, radius_end: float | None = None,
        segments: int = SMALL_SEGMENTS) -> Manifold:
  """A cylinder (or cone frustum) from (3,) ``start`` to (3,) ``end``."""
  start, end = np.asarray(start, np.float64), np.asarray(end, np.float64)
  axis = end - start
  length = float(np.linalg.norm(axis))
  part = cylinder(radius, length, radius_top=radius_end, segments=segments)
  return transformed(part, rotation_to(axis), 0.5 * (start + end))


def rounded_box(size: Sequence[float], radius: float, segments: int = SMALL_SEGMENTS) -> Manifold:
  """A box of (3,) ``size`` with edges and corners rounded by ``radius`` (hull of eight spheres)."""
  half = 0.5 * np.asarray(size, np.float64) - radius
  ball = Manifold.sphere(float(radius), segments)
  corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing='ij')).reshape(3, -1).T * half
  return Manifold.batch_hull([ball.translate(tuple(c)) for c in corners])


def rotation_to(direction: Sequence[float]) -> np.ndarray:
  """The (3, 3) rotation taking +z to the unit vector along (3,) ``direction``."""
  return trimesh.geometry.align_vectors([0.0, 0.0, 1.0], np.asarray(direction, np.float64))[:3, :3]


def transformed(part: Manifold, rotation: np.ndarray, translation: Sequence[float] = (0.0, 0.0, 0.0)) -> Manifold:
  """Applies x -> rotation @ x + translation ((3, 3) and (3,)) to ``part``."""
  matrix = np.c_[np.asarray(rotation, np.float64), np.asarray(translation, np.float64)]
  return part.transform(matrix)


def along_x(part: Manifold) -> Manifold:
  """Rotates a z-axis part so that its axis is x."""
  return part.rotate((0.0, 90.0, 0.0))


def along_y(part: Manifold) -> Manifold:
  """Rotates a z-axis part so that its axis is y."""
  return part.rotate((90.0, 0.0, 0.0))


def polygon(points: np.ndarray) -> CrossSection:
  """A cross-section from one (N, 2) polygon (either orientation)."""
  points = np.asarray(points, np.float64)
  area = 0.5 * np.sum(points[:, 0] * np.roll(points[:, 1], -1) - np.roll(points[:, 0], -1) * points[:, 1])
  return CrossSection([points if area > 0 else points[::-1]])


def rectangle(width: float, height: float, centre: Sequence[float] = (0.0, 0.0)) -> CrossSection:
  """An axis-aligned ``width`` x ``height`` rectangle centred at (2,) ``centre``."""
  return CrossSection.square((float(width), float(height)), center=True).translate(tuple(float(c) for c in centre))


def extrude(section: CrossSection, height: float, *, twist_degrees: float = 0.0, divisions: int = 0) -> Manifold:
  """Extrudes a cross-section along z by ``height``, centred on z = 0."""
  solid = Manifold.extrude(section, float(height), divisions, float(twist_degrees))
  return solid.translate((0.0, 0.0, -0.5 * float(height)))


def revolve(profile: CrossSection, segments: int = ROUND_SEGMENTS) -> Manifold:
  """Revolves a profile in the (r, z) plane (only its r >= 0 part) around the z axis."""
  return Manifold.revolve(profile, segments)


def union(parts: Sequence[Manifold]) -> Manifold:
  """Boolean union of ``parts``."""
  return Manifold.batch_boolean(list(parts), manifold3d.OpType.Add)


def difference(base: Manifold, cutters: Sequence[Manifold]) -> Manifold:
  """``base`` minus the union of ``cutters``."""
  if not cutters:
    return base
  return Manifold.batch_boolean([base, *cutters], manifold3d.OpType.Subtract)


def largest_piece(solid: Manifold) -> Manifold:
  """The connected component of ``solid`` with the largest volume."""
  pieces = solid.decompose()
  if len(pieces) <= 1:
    return solid
  return max(pieces, key=lambda piece: piece.volume())
