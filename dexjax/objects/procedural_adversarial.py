"""Level-3 procedural families: adversarial geometry (Dex-Net 4.0 difficulty level 3).

Shapes that are hard for both a parallel-jaw gripper and a suction cup, in model units (largest
dimension ~1; the generator rescales to metres): deep thin-walled containers, ribbed / pinned heat sinks
(deep narrow slots, thin fins and pins), gears with fine teeth, bores and lightening holes, spiky balls and
jacks (narrow spikes and rods), open wire-frame boxes, noisy blobs (a sphere displaced radially by random
waves), randomly "evolved" unions and differences of many primitives, 3D-printed-style industrial parts
(flanges with bolt holes, L-brackets with holes and a gusset) and twisted star prisms.

Household size: the largest extent lies in [0.06, 0.15] m. Where a part is what a gripper would hold, its
thickness is drawn in metres (the family returns its own ``'extent'`` and divides): containers and twisted
prisms >= 3 cm across, gears 2-3 cm thick, jack rods 0.8-1.2 cm, wire-frame bars 0.8-1.4 cm, heat-sink fins
with gaps a 1 cm finger fits in, flanges and brackets 0.6-1.5 cm thick.
"""

from __future__ import annotations

import manifold3d
import numpy as np

from dexjax.objects.procedural_materials import ALUMINIUM
from dexjax.objects.procedural_materials import GLASS
from dexjax.objects.procedural_materials import PRINTED_PLA
from dexjax.objects.procedural_shapes import ROUND_SEGMENTS
from dexjax.objects.procedural_shapes import SMALL_SEGMENTS
from dexjax.objects.procedural_shapes import CrossSection
from dexjax.objects.procedural_shapes import Manifold
from dexjax.objects.procedural_shapes import Params
from dexjax.objects.procedural_shapes import ShapeFamily
from dexjax.objects.procedural_shapes import along_x
from dexjax.objects.procedural_shapes import along_y
from dexjax.objects.procedural_shapes import box
from dexjax.objects.procedural_shapes import cylinder
from dexjax.objects.procedural_shapes import difference
from dexjax.objects.procedural_shapes import draw_extent
from dexjax.objects.procedural_shapes import ellipsoid
from dexjax.objects.procedural_shapes import extrude
from dexjax.objects.procedural_shapes import largest_piece
from dexjax.objects.procedural_shapes import log_uniform
from dexjax.objects.procedural_shapes import polygon
from dexjax.objects.procedural_shapes import rectangle
from dexjax.objects.procedural_shapes import rod
from dexjax.objects.procedural_shapes import rotation_from_uniform
from dexjax.objects.procedural_shapes import transformed
from dexjax.objects.procedural_shapes import union

__all__ = ['LEVEL3_FAMILIES']

_ADD = manifold3d.OpType.Add
_SUBTRACT = manifold3d.OpType.Subtract
_MIN_GAP = 0.03  # Narrowest slot or web left between cut features, model units.
_MIN_DIAMETER = 0.03  # Narrowest body of a container or a twisted prism, metres.
_FINGER_GAP = 0.011  # Gap between heat-sink fins or pins a 1 cm jaw finger fits in, metres.


def _ring_points(radii: np.ndarray, angles: np.ndarray) -> np.ndarray:
  """(N, 2) points at polar coordinates (radii, angles)."""
  return np.c_[radii * np.cos(angles), radii * np.sin(angles)]


# ----------------------------------------------------------------------------------------------------------
# Deep, thin-walled containers.


def _draw_deep_container(rng: np.random.Generator) -> Params:
  height = log_uniform(rng, 1.5, 3.5)
  return {'height': height, 'sides': int(rng.choice([0, 4, 5, 6, 8])), 'taper': rng.uniform(0.8, 1.15),
          'wall': rng.uniform(0.03, 0.045) * height, 'bottom': rng.uniform(0.04, 0.08) * height,
          'has_lip': bool(rng.random() < 0.5), 'extent': draw_extent(rng, max(0.06, _MIN_DIAMETER * height))}


def _build_deep_container(p: Params) -> Manifold:
  height, sides = p['height'], p['sides'] or ROUND_SEGMENTS
  r0, r1 = 0.5, 0.5 * p['taper']
  inset = p['wall'] / np.cos(np.pi / sides)  # Circumradius reduction giving the wall thickness.
  radius_at = lambda z: r0 + (r1 - r0) * z / height
  outer = Manifold.cylinder(height, r0, r1, sides)
  cavity = Manifold.cylinder(height, radius_at(p['bottom']) - inset, radius_at(height + p['bottom']) - inset,
                             sides).translate((0.0, 0.0, p['bottom']))
  parts = [outer]
  if p['has_lip']:
    parts.append(Manifold.cylinder(p['wall'], r1 + 2 * p['wall'], r1 + 2 * p['wall'], sides).translate(
        (0.0, 0.0, height - p['wall'])))
  return difference(union(parts), [cavity])


# ----------------------------------------------------------------------------------------------------------
# Heat sinks: thin fins or pins on a base plate.


def _draw_ribbed(rng: np.random.Generator) -> Params:
  extent = draw_extent(rng, 0.08)
  return {'extent': extent, 'pins': bool(rng.random() < 0.4), 'count': int(rng.integers(5, 13)),
          'grid': rng.integers(3, 7, 2), 'fin_thickness': max(0.03, rng.uniform(0.0045, 0.008) / extent),
          'pin_radius': rng.uniform(0.003, 0.005) / extent, 'gap': _FINGER_GAP / extent,
          'base': rng.uniform(0.04, 0.09), 'fin_height': rng.uniform(0.3, 0.8), 'depth': rng.uniform(0.4, 1.0)}


def _build_ribbed(p: Params) -> Manifold:
  base, fin_height, depth, gap = p['base'], p['fin_height'], p['depth'], p['gap']
  if p['pins']:
    radius = p['pin_radius']
    nx, ny = (max(1, min(int(n), int(length / (2 * radius + gap)))) for n, length in zip(p['grid'], (1.0, depth)))
    pins = [cylinder(radius, fin_height + 0.02, segments=SMALL_SEGMENTS).translate(
        (x, y, base + 0.5 * fin_height - 0.01))
            for x in (np.arange(nx) + 0.5) / nx - 0.5 for y in ((np.arange(ny) + 0.5) / ny - 0.5) * depth]
    return union([box((1.0, depth, base), (0.0, 0.0, 0.5 * base)), *pins])
  thickness = p['fin_thickness']
  count = min(p['count'], int((1.0 - thickness) / (thickness + gap)) + 1)
  xs = np.linspace(-0.5 + 0.5 * thickness, 0.5 - 0.5 * thickness, count)
  bars = [rectangle(1.0, base, (0.0, 0.5 * base))]
  bars += [rectangle(thickness, fin_height + 0.01, (x, base + 0.5 * fin_height - 0.005)) for x in xs]
  return along_y(extrude(CrossSection.batch_boolean(bars, _ADD), depth))


# ----------------------------------------------------------------------------------------------------------
# Gears: fine teeth, a bore, lightening holes and a hub.


def _draw_gear(rng: np.random.Generator) -> Params:
  extent = draw_extent(rng)  # The gear's diameter.
  return {'extent': extent, 'teeth': int(rng.integers(12, 37)), 'tooth_depth': rng.uniform(0.05, 0.1),
          'thickness': rng.uniform(0.02, 0.03) / extent, 'bore': rng.uniform(0.05, 0.12),
          'holes': int(rng.integers(3, 7)),
          'has_hub': bool(rng.random() < 0.5), 'hub_margin': rng.uniform(0.06, 0.12),
          'hub_height': rng.uniform(0.1, 0.3), 'twist': float(rng.uniform(0.0, 1.0) < 0.3) * rng.uniform(10, 30)}


def _gear_outline(teeth: int, tip: float, root: float) -> np.ndarray:
  """(4 teeth, 2) outline of a spur gear with trapezoidal teeth."""
  pitch = 2 * np.pi / teeth
  offsets = np.array([-0.3, -0.12, 0.12, 0.3]) * pitch
  angles = (np.arange(teeth)[:, None] * pitch + offsets).reshape(-1)
  return _ring_points(np.tile([root, tip, tip, root], teeth), angles)


def _build_gear(p: Params) -> Manifold:
  root, thickness = 0.5 - p['tooth_depth'], p['thickness']
  inner = p['bore'] + (p['hub_margin'] if p['has_hub'] else _MIN_GAP)
  section = polygon(_gear_outline(p['teeth'], 0.5, root))
  if p['holes'] and root - inner > 0.12:
    centre_radius = 0.5 * (root + inner)
    radius = min(0.5 * (root - inner) - _MIN_GAP, np.pi * centre_radius / p['holes'] - _MIN_GAP)
    holes = [CrossSection.circle(radius, SMALL_SEGMENTS).translate(tuple(c)) for c in _ring_points(
        np.full(p['holes'], centre_radius), 2 * np.pi * np.arange(p['holes']) / p['holes'])]
    section = CrossSection.batch_boolean([section, *holes], _SUBTRACT)
  gear = extrude(section, thickness, twist_degrees=p['twist'], divisions=4 if p['twist'] else 0)
  parts = [gear]
  if p['has_hub']:
    parts.append(cylinder(inner, p['hub_height'] + 0.01, segments=32).translate(
        (0.0, 0.0, 0.5 * thickness + 0.5 * p['hub_height'] - 0.005)))
  bore = cylinder(p['bore'], 4.0, segments=32)
  return difference(union(parts), [bore])


# ----------------------------------------------------------------------------------------------------------
# Spiky balls and jacks: narrow spikes and rods.


def _draw_spiky(rng: np.random.Generator) -> Params:
  count = int(rng.integers(6, 17))
  directions = rng.normal(size=(16, 3))
  extent = draw_extent(rng, 0.08)
  return {'extent': extent, 'jack': bool(rng.random() < 0.3), 'core': rng.uniform(0.18, 0.3, 3), 'count': count,
          'directions': directions / np.linalg.norm(directions, axis=1, keepdims=True),
          'lengths': rng.uniform(0.25, 0.45, 16), 'base_radius': rng.uniform(0.035, 0.06),
          'rod_radius': rng.uniform(0.004, 0.006) / extent}


def _build_spiky(p: Params) -> Manifold:
  if p['jack']:  # Three orthogonal rods with balls on their ends and a ball in the middle.
    r, half = p['rod_radius'], 0.5 - 2 * p['rod_radius']
    rods = [rod(-half * axis, half * axis, r) for axis in np.eye(3)]
    balls = [Manifold.sphere(2 * r, 16).translate(tuple(s * half * axis)) for axis in np.eye(3) for s in (-1, 1)]
    return union([Manifold.sphere(3 * r, 24), *rods, *balls])
  core = p['core']
  parts = [ellipsoid(core)]
  for direction, length in list(zip(p['directions'], p['lengths']))[:p['count']]:
    reach = 1.0 / np.sqrt(np.sum((direction / core)**2))  # Core surface along the direction.
    parts.append(rod(0.5 * reach * direction, (reach + length) * direction, p['base_radius'],
                     radius_end=0.012, segments=12))
  return union(parts)


# ----------------------------------------------------------------------------------------------------------
# Open wire-frame boxes.


def _draw_wire_frame(rng: np.random.Generator) -> Params:
  extent, size = draw_extent(rng, 0.08), np.r_[1.0, rng.uniform(0.5, 1.0, 2)]
  bar = min(rng.uniform(0.008, 0.014) / extent, 0.2 * size.min())  # Leaves every face open.
  return {'extent': extent, 'size': size, 'bar': bar, 'brace': bool(rng.random() < 0.5)}


def _build_wire_frame(p: Params) -> Manifold:
  (sx, sy, sz), bar = p['size'], p['bar']
  cuts = [box((sx - 2 * bar, sy - 2 * bar, 2.0)), box((sx - 2 * bar, 2.0, sz - 2 * bar)),
          box((2.0, sy - 2 * bar, sz - 2 * bar))]
  frame = difference(box(p['size']), cuts)
  if not p['brace']:
    return frame
  y = 0.5 * sy - 0.5 * bar
  brace = rod((-0.5 * sx + 0.5 * bar, y, -0.5 * sz + 0.5 * bar), (0.5 * sx - 0.5 * bar, y, 0.5 * sz - 0.5 * bar),
              0.42 * bar, segments=8)  # Inside the bars: no face coincides with theirs.
  return union([frame, brace])


# ----------------------------------------------------------------------------------------------------------
# Noisy blobs: a sphere whose log-radius is a sum of random plane waves (star-shaped, never self-intersecting).

_WAVES = 16


def _draw_noisy_blob(rng: np.random.Generator) -> Params:
  directions = rng.normal(size=(_WAVES, 3))
  directions /= np.linalg.norm(directions, axis=1, keepdims=True)
  frequencies = np.array([log_uniform(rng, 1.5, 9.0) for _ in range(_WAVES)])
  return {'wave_vectors': directions * frequencies[:, None], 'phases': rng.uniform(0, 2 * np.pi, _WAVES),
          'decay': rng.uniform(0.3, 1.2), 'amplitude': rng.uniform(0.35, 0.6),
          'semi_axes': np.r_[0.5, rng.uniform(0.3, 0.5, 2)]}


def _build_noisy_blob(p: Params) -> Manifold:
  weights = np.linalg.norm(p['wave_vectors'], axis=1)**-p['decay']
  weights *= p['amplitude'] / np.sqrt(0.5 * np.sum(weights**2))  # The log-radius has RMS ``amplitude``.

  def displace(points: np.ndarray) -> np.ndarray:
    directions = points / np.linalg.norm(points, axis=1, keepdims=True)
    radii = np.exp(np.sin(directions @ p['wave_vectors'].T + p['phases']) @ weights)  # > 0: star-shaped.
    return directions * radii[:, None] * p['semi_axes']

  return Manifold.sphere(1.0, 64).warp_batch(displace)


# ----------------------------------------------------------------------------------------------------------
# Randomly evolved unions and differences of primitives.

_STEPS = 12


def _draw_evolved(rng: np.random.Generator) -> Params:
  return {'steps': int(rng.integers(6, _STEPS + 1)), 'kinds': rng.integers(0, 4, _STEPS),
          'subtract': rng.random(_STEPS) < 0.45, 'sizes': rng.uniform(0.15, 0.55, (_STEPS, 3)),
          'cut_scale': rng.uniform(0.4, 0.9, _STEPS), 'rotations': rng.random((_STEPS, 3)),
          'anchors': rng.random(_STEPS), 'offsets': rng.uniform(-1.0, 1.0, (_STEPS, 3))}


def _evolved_primitive(kind: int, size: np.ndarray) -> Manifold:
  """A box, cylinder, sphere-like ellipsoid or hexagonal prism of (3,) ``size``, centred on the origin."""
  if kind == 0:
    return box(size)
  if kind == 1:
    return cylinder(0.5 * size[0], size[2], segments=24).scale((1.0, size[1] / size[0], 1.0))
  if kind == 2:
    return ellipsoid(0.5 * size, segments=20)
  return cylinder(0.5 * size[0], size[2], segments=6)


def _build_evolved(p: Params) -> Manifold:
  solid, placed = None, []  # placed: (centre, rotation, size) of the united primitives.
  for step in range(p['steps']):
    rotation = rotation_from_uniform(p['rotations'][step])
    subtract = bool(p['subtract'][step]) and step > 0
    size = p['sizes'][step] * (p['cut_scale'][step] if subtract else 1.0)
    centre = np.zeros(3)
    if placed:
      anchor_centre, anchor_rotation, anchor_size = placed[int(p['anchors'][step] * len(placed))]
      reach = 0.5 if subtract else 0.3  # United parts start inside the anchor; cuts bite into its surface.
      centre = anchor_centre + anchor_rotation @ (reach * p['offsets'][step] * anchor_size)
    part = transformed(_evolved_primitive(int(p['kinds'][step]), size), rotation, centre)
    if subtract:
      solid = difference(solid, [part])
    else:
      solid = part if solid is None else union([solid, part])
      placed.append((centre, rotation, size))
  return largest_piece(solid)


# ----------------------------------------------------------------------------------------------------------
# Industrial parts: flanges and brackets.


def _draw_industrial(rng: np.random.Generator) -> Params:
  extent = draw_extent(rng, 0.08)
  return {'extent': extent, 'bracket': bool(rng.random() < 0.5), 'shape': rng.uniform(0.0, 1.0, 8),
          'holes': rng.integers(1, 4, 2), 'bolts': int(rng.integers(3, 9)), 'has_gusset': bool(rng.random() < 0.6),
          'plate': rng.uniform(0.006, 0.015) / extent}


def _build_flange(p: Params) -> Manifold:
  s = p['shape']
  disc, hub, hub_height = p['plate'], 0.15 + 0.13 * s[1], 0.15 + 0.3 * s[2]
  bore = 0.05 + (hub - 0.1) * s[3]
  bolt_circle = 0.5 * (hub + 0.5)
  bolt = min(0.03 + 0.025 * s[4], 0.5 * (0.5 - hub) - _MIN_GAP, np.pi * bolt_circle / p['bolts'] - _MIN_GAP)
  body = union([cylinder(0.5, disc, segments=ROUND_SEGMENTS),
                cylinder(hub, hub_height, segments=32).translate((0.0, 0.0, 0.5 * (disc + hub_height) - 0.005))])
  centres = _ring_points(np.full(p['bolts'], bolt_circle), 2 * np.pi * np.arange(p['bolts']) / p['bolts'])
  holes = [cylinder(bolt, 4.0, segments=SMALL_SEGMENTS).translate((x, y, 0.0)) for x, y in centres]
  return difference(body, [cylinder(bore, 4.0, segments=32), *holes])


def _build_bracket(p: Params) -> Manifold:
  s = p['shape']
  thickness, rise, width = p['plate'], 0.5 + 0.5 * s[1], 0.3 + 0.3 * s[2]
  radius = min(0.035 + 0.035 * s[3], 0.3 * width)
  foot = box((1.0, width, thickness), (0.0, 0.0, 0.5 * thickness))
  upright = box((thickness, width, rise), (-0.5 + 0.5 * thickness, 0.0, 0.5 * rise))
  parts = [foot, upright]
  leg = (0.3 + 0.2 * s[4]) * min(1.0, rise) if p['has_gusset'] else 0.0
  if leg:
    corner = -0.5 + thickness - 0.01, thickness - 0.01  # Inside the bend, overlapping both plates.
    triangle = polygon(np.array([[0.0, 0.0], [leg, 0.0], [0.0, leg]]) + corner)
    parts.append(along_y(extrude(triangle, 0.04 + 0.04 * s[5])))
  hole = cylinder(radius, 3 * thickness, segments=SMALL_SEGMENTS)  # Through one plate only.
  first = thickness + leg + radius + 0.05  # Holes clear the gusset.
  foot_x = _hole_positions(-0.5 + first, 0.5 - 2 * radius, p['holes'][0], 2 * radius + _MIN_GAP)
  up_z = _hole_positions(first, rise - 2 * radius, p['holes'][1], 2 * radius + _MIN_GAP)
  holes = [hole.translate((x, 0.0, 0.5 * thickness)) for x in foot_x]
  holes += [along_x(hole).translate((-0.5 + 0.5 * thickness, 0.0, z)) for z in up_z]
  return difference(union(parts), holes)


def _hole_positions(start: float, stop: float, count: int, pitch: float) -> np.ndarray:
  """Up to ``count`` evenly spaced positions in [start, stop] at least ``pitch`` apart (none if it is empty)."""
  if stop < start:
    return np.zeros(0)
  count = min(int(count), 1 + int((stop - start) / pitch))
  return np.linspace(start, stop, count) if count > 1 else np.array([0.5 * (start + stop)])


def _build_industrial(p: Params) -> Manifold:
  return _build_bracket(p) if p['bracket'] else _build_flange(p)


# ----------------------------------------------------------------------------------------------------------
# Twisted star prisms.


def _draw_twisted(rng: np.random.Generator) -> Params:
  p = {'points': int(rng.integers(3, 9)), 'inner_ratio': rng.uniform(0.35, 0.75),
       'twist': rng.uniform(90.0, 360.0), 'height_over_diameter': log_uniform(rng, 0.8, 3.0)}
  p['extent'] = draw_extent(rng, max(0.06, _MIN_DIAMETER * max(1.0, p['height_over_diameter'])))
  return p


def _build_twisted(p: Params) -> Manifold:
  n = p['points']
  radii = np.tile([0.5, 0.5 * p['inner_ratio']], n)
  star = polygon(_ring_points(radii, np.pi * np.arange(2 * n) / n))
  divisions = int(np.ceil(p['twist'] / 10))  # At most 10 degrees of twist per layer.
  return extrude(star, p['height_over_diameter'], twist_degrees=p['twist'], divisions=divisions)


LEVEL3_FAMILIES: tuple[ShapeFamily, ...] = (
    ShapeFamily('deep_container', _draw_deep_container, _build_deep_container, GLASS),
    ShapeFamily('ribbed', _draw_ribbed, _build_ribbed, ALUMINIUM),
    ShapeFamily('gear', _draw_gear, _build_gear, PRINTED_PLA),
    ShapeFamily('spiky', _draw_spiky, _build_spiky, PRINTED_PLA),
    ShapeFamily('wire_frame', _draw_wire_frame, _build_wire_frame, PRINTED_PLA),
    ShapeFamily('noisy_blob', _draw_noisy_blob, _build_noisy_blob, PRINTED_PLA),
    ShapeFamily('evolved', _draw_evolved, _build_evolved, PRINTED_PLA),
    ShapeFamily('industrial', _draw_industrial, _build_industrial, PRINTED_PLA),
    ShapeFamily('twisted', _draw_twisted, _build_twisted, PRINTED_PLA),
)
"""Level 3 (adversarial geometry: fine detail, deep concavities, narrow parts, noisy and evolved shapes)."""
