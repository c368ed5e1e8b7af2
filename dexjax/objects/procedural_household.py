"""Level-2 procedural families: household-like objects with complex geometry (Dex-Net 4.0 difficulty level 2).

Compound solids built with `manifold3d` booleans, in model units (largest dimension ~1; the generator
rescales to metres): mugs and cups (with a torus handle), bottles (revolved profiles), bowls (revolved
profiles hollowed by a constant wall), letter shapes (L, T, U, H, E, +), tools (hammer, spatula,
screwdriver, wrench), toys (car, figure, stacked blocks) and blister packs (a thin card with a raised
bubble and an optional hanging hole).

Household size: the largest extent lies in [0.06, 0.15] m. The parts a gripper holds are drawn in metres
(the family returns its own ``'extent'`` and divides): a bowl is >= 2.5 cm deep, a bottle's body >= 3 cm
across, a letter 2-4.5 cm thick, a tool's handle or grip 2-3.2 cm across and a wrench's bar 2.5-3.2 cm wide,
a blister's bubble 1.5-3.5 cm high, so that no object is too thin for the jaws and too narrow for the suction
cup at once.
"""

from __future__ import annotations

import manifold3d
import numpy as np

from dexjax.objects.procedural_materials import ABS
from dexjax.objects.procedural_materials import FILLED_BOTTLE
from dexjax.objects.procedural_materials import PACKAGED_GOODS
from dexjax.objects.procedural_materials import PLASTIC_TOOL
from dexjax.objects.procedural_materials import SOFTWOOD
from dexjax.objects.procedural_materials import VESSEL_PLASTIC
from dexjax.objects.procedural_shapes import ROUND_SEGMENTS
from dexjax.objects.procedural_shapes import SMALL_SEGMENTS
from dexjax.objects.procedural_shapes import CrossSection
from dexjax.objects.procedural_shapes import Manifold
from dexjax.objects.procedural_shapes import Params
from dexjax.objects.procedural_shapes import ShapeFamily
from dexjax.objects.procedural_shapes import along_y
from dexjax.objects.procedural_shapes import box
from dexjax.objects.procedural_shapes import capsule
from dexjax.objects.procedural_shapes import cylinder
from dexjax.objects.procedural_shapes import difference
from dexjax.objects.procedural_shapes import draw_extent
from dexjax.objects.procedural_shapes import ellipsoid
from dexjax.objects.procedural_shapes import extrude
from dexjax.objects.procedural_shapes import log_uniform
from dexjax.objects.procedural_shapes import polygon
from dexjax.objects.procedural_shapes import rectangle
from dexjax.objects.procedural_shapes import revolve
from dexjax.objects.procedural_shapes import rod
from dexjax.objects.procedural_shapes import rounded_box
from dexjax.objects.procedural_shapes import union

__all__ = ['LEVEL2_FAMILIES', 'mirrored_profile', 'hollowed']

_ROUND = manifold3d.JoinType.Round


def mirrored_profile(points: np.ndarray) -> CrossSection:
  """A cross-section symmetric about r = 0 from a (N, 2) half profile (r, z) running from the axis to the axis."""
  points = np.asarray(points, np.float64)
  return polygon(np.concatenate([points, points[::-1] * [-1.0, 1.0]]))


def hollowed(profile: CrossSection, wall: float, rim_height: float) -> CrossSection:
  """Hollows an open-topped (r, z) profile, symmetric about r = 0, with a constant ``wall`` thickness.

  The profile is extended upward from ``rim_height`` before it is shrunk, so the cavity opens at the top.
  """
  width = profile.bounds()[2] - profile.bounds()[0]
  top = rectangle(width, 1.0, (0.0, rim_height + 0.5 - 1e-3))
  cavity = (profile + top).offset(-wall, _ROUND, 2.0, SMALL_SEGMENTS)
  return CrossSection.batch_boolean([profile, cavity], manifold3d.OpType.Subtract)


# ----------------------------------------------------------------------------------------------------------
# Vessels: mugs, cups (a frustum hollowed by a frustum, with an optional torus handle) and bowls.


def _draw_mug(rng: np.random.Generator) -> Params:
  height = log_uniform(rng, 0.6, 1.5)
  return {'height': height, 'top_radius': 0.5 * rng.uniform(0.85, 1.2), 'wall': rng.uniform(0.05, 0.08),
          'bottom': rng.uniform(0.06, 0.12), 'has_handle': bool(rng.random() < 0.8),
          'handle_radius': rng.uniform(0.25, 0.4) * height, 'handle_thickness': rng.uniform(0.035, 0.06),
          'handle_offset': rng.uniform(0.35, 0.75), 'handle_height': rng.uniform(0.45, 0.55)}


def _build_mug(p: Params) -> Manifold:
  height, r0, r1, wall = p['height'], 0.5, p['top_radius'], p['wall']
  radius_at = lambda z: r0 + (r1 - r0) * z / height
  outer = Manifold.cylinder(height, r0, r1, ROUND_SEGMENTS)
  extra = 1.0  # The cavity continues above the rim.
  cavity = Manifold.cylinder(height - p['bottom'] + extra, radius_at(p['bottom']) - wall,
                             radius_at(height + extra) - wall, ROUND_SEGMENTS).translate((0, 0, p['bottom']))
  parts = [outer]
  z_handle = p['handle_height'] * height
  thickness = p['handle_thickness']
  ring = min(p['handle_radius'], min(z_handle, height - z_handle) - thickness - 0.02)
  if p['has_handle'] and ring > 2 * thickness + 0.04:
    torus = revolve(CrossSection.circle(thickness, SMALL_SEGMENTS).translate((ring, 0.0)), 32)
    x_handle = radius_at(z_handle) + p['handle_offset'] * ring
    parts.append(along_y(torus).translate((x_handle, 0.0, z_handle)))
  return difference(union(parts), [cavity])


# ----------------------------------------------------------------------------------------------------------
# Bottles and bowls (revolved profiles).


_MIN_BODY_DIAMETER = 0.03  # A bottle's body, metres.


def _draw_bottle(rng: np.random.Generator) -> Params:
  neck = rng.uniform(0.1, 0.22)
  p = {'body_height': log_uniform(rng, 0.9, 2.2), 'shoulder_height': rng.uniform(0.15, 0.5),
       'shoulder_power': rng.uniform(0.6, 2.0), 'neck_radius': neck, 'neck_height': rng.uniform(0.1, 0.4),
       'cap_radius': neck * rng.uniform(1.0, 1.35), 'cap_height': rng.uniform(0.08, 0.2),
       'waist': rng.uniform(0.0, 0.15)}
  height = p['body_height'] + p['shoulder_height'] + p['neck_height'] + p['cap_height']  # In body diameters.
  p['extent'] = draw_extent(rng, max(0.06, _MIN_BODY_DIAMETER * height))
  return p


def _build_bottle(p: Params) -> Manifold:
  body, neck = p['body_height'], p['neck_radius']
  z_body = np.linspace(0.04, body, 9)
  r_body = 0.5 * (1.0 - p['waist'] * np.sin(np.pi * z_body / body))
  t = np.linspace(0.0, 1.0, 9)[1:]
  z_shoulder = body + t * p['shoulder_height']
  r_shoulder = neck + (0.5 - neck) * np.cos(0.5 * np.pi * t)**p['shoulder_power']
  z_neck = body + p['shoulder_height'] + p['neck_height']
  z_top = z_neck + p['cap_height']
  half = np.concatenate([[[0.0, 0.0], [0.46, 0.0]], np.c_[r_body, z_body], np.c_[r_shoulder, z_shoulder],
                         [[neck, z_neck], [p['cap_radius'], z_neck], [p['cap_radius'], z_top], [0.0, z_top]]])
  return revolve(polygon(half))


def _draw_bowl(rng: np.random.Generator) -> Params:
  return {'depth': rng.uniform(0.2, 0.55), 'foot_radius': rng.uniform(0.12, 0.3),
          'bowl_wall': rng.uniform(0.035, 0.06), 'flare': rng.uniform(0.35, 1.0)}


def _build_bowl(p: Params) -> Manifold:
  s = np.linspace(0.0, 1.0, 12)
  half = np.c_[p['foot_radius'] + (0.5 - p['foot_radius']) * s**p['flare'], p['depth'] * s]
  profile = mirrored_profile(np.concatenate([[[0.0, 0.0]], half, [[0.0, p['depth']]]]))
  return revolve(hollowed(profile, p['bowl_wall'], p['depth']))


_MIN_BOWL_DEPTH = 0.025  # Metres: a bowl's rim stands high enough for the jaws.


def _draw_vessel(rng: np.random.Generator) -> Params:
  p = {'bowl': bool(rng.random() < 0.35), **_draw_mug(rng), **_draw_bowl(rng), 'extent': draw_extent(rng)}
  p['depth'] = max(p['depth'], _MIN_BOWL_DEPTH / p['extent'])  # The bowl's rim diameter is its extent.
  return p


def _build_vessel(p: Params) -> Manifold:
  return _build_bowl(p) if p['bowl'] else _build_mug(p)


# ----------------------------------------------------------------------------------------------------------
# Letter shapes (extruded unions of bars).

_LETTERS = ('L', 'T', 'U', 'H', 'E', '+')


def _draw_letter(rng: np.random.Generator) -> Params:
  extent, letter, height = draw_extent(rng, 0.09), _LETTERS[int(rng.integers(len(_LETTERS)))], rng.uniform(0.6, 1.2)
  unit = extent / max(1.0, height)  # Metres per model unit.
  stroke = min(rng.uniform(0.015, 0.03) / unit, 0.25 * min(1.0, height))  # Leaves room for an E's three bars.
  return {'extent': extent, 'letter': letter, 'height': height, 'stroke': stroke,
          'depth': rng.uniform(0.02, 0.045) / unit, 'rounding': rng.uniform(0.0, 0.45) * stroke}


def _letter_bars(letter: str, width: float, height: float, s: float) -> list[tuple[float, float, float, float]]:
  """Bars (x0, x1, y0, y1) of a block letter in a ``width`` x ``height`` box centred on the origin."""
  w, h = 0.5 * width, 0.5 * height
  left, right, bottom, top = (-w, -w + s, -h, h), (w - s, w, -h, h), (-w, w, -h, -h + s), (-w, w, h - s, h)
  middle_x, middle_y = (-0.5 * s, 0.5 * s, -h, h), (-w, w, -0.5 * s, 0.5 * s)
  return {'L': [left, bottom], 'T': [top, middle_x], 'U': [left, right, bottom], 'H': [left, right, middle_y],
          'E': [left, top, bottom, (-w, w - 0.2 * width, -0.5 * s, 0.5 * s)], '+': [middle_x, middle_y]}[letter]


def _build_letter(p: Params) -> Manifold:
  bars = _letter_bars(p['letter'], 1.0, p['height'], p['stroke'])
  section = CrossSection.batch_boolean(
      [rectangle(x1 - x0, y1 - y0, (0.5 * (x0 + x1), 0.5 * (y0 + y1))) for x0, x1, y0, y1 in bars],
      manifold3d.OpType.Add)
  if p['rounding'] > 1e-3:
    section = section.offset(-p['rounding'], _ROUND, 2.0, SMALL_SEGMENTS).offset(
        p['rounding'], _ROUND, 2.0, SMALL_SEGMENTS)
  return extrude(section, p['depth'])


# ----------------------------------------------------------------------------------------------------------
# Tools: a handle and a head.

_TOOLS = ('hammer', 'spatula', 'screwdriver', 'wrench')


def _draw_tool(rng: np.random.Generator) -> Params:
  extent = draw_extent(rng, 0.1)  # The tool's length.
  metres = lambda low, high: float(rng.uniform(low, high)) / extent  # A length drawn in metres, model units.
  return {'extent': extent, 'tool': _TOOLS[int(rng.integers(len(_TOOLS)))], 'head': rng.uniform(0.0, 1.0, 4),
          'round_head': bool(rng.random() < 0.4), 'handle_radius': metres(0.01, 0.014),
          'grip_radius': metres(0.011, 0.016),
          'bar_width': metres(0.025, 0.032), 'bar_thickness': metres(0.006, 0.01),
          'ring_over_width': float(rng.uniform(1.5, 2.0))}


def _build_tool(p: Params) -> Manifold:
  h, r = p['head'], p['handle_radius']
  if p['tool'] == 'hammer':
    side = 2 * r * (1.25 + 0.55 * h[:2])  # The head is thicker than the handle.
    size = np.r_[side, min(max(0.3 + 0.2 * h[2], 1.3 * side.max()), 0.7)]
    handle = rod((-0.5, 0, 0), (0.5 - 0.5 * size[0], 0, 0), r, segments=24)
    head = (cylinder(0.5 * size[0], size[2], segments=24) if p['round_head'] else box(size))
    return union([handle, head.translate((0.5 - 0.5 * size[0], 0.0, 0.0))])
  if p['tool'] == 'spatula':
    blade = np.r_[0.3 + 0.15 * h[0], 0.25 + 0.15 * h[1], 0.03 + 0.015 * h[2]]
    handle = capsule(r, 0.65, 16).rotate((0.0, 90.0, 0.0)).translate((-0.175, 0.0, 0.0))
    plate = rounded_box(blade, 0.45 * blade[2]).translate((0.1 + 0.5 * blade[0], 0.0, 0.0))
    neck = rod((0.1, 0, 0), (0.2, 0, 0), min(r, 0.45 * blade[2]), radius_end=0.45 * blade[2])
    return union([handle, neck, plate])
  if p['tool'] == 'screwdriver':
    grip_radius, grip_length = p['grip_radius'], 0.35 + 0.1 * h[1]
    shaft_radius, shaft_length = 0.022 + 0.013 * h[2], 0.4 + 0.2 * h[3]
    grip = rod((-0.5, 0, 0), (-0.5 + grip_length, 0, 0), grip_radius, segments=24)
    tip_x = -0.5 + grip_length + shaft_length
    shaft = rod((-0.5 + grip_length - 0.05, 0, 0), (tip_x, 0, 0), shaft_radius)
    tip = box((0.08, 2.4 * shaft_radius, max(0.03, shaft_radius)), (tip_x, 0.0, 0.0))
    return union([grip, shaft, tip])
  # Wrench: a flat bar with a closed hexagonal ring at one end and an open jaw at the other.
  width, thickness = p['bar_width'], p['bar_thickness']
  ring = 0.5 * width * p['ring_over_width']  # Radius of the ring ends.
  bar = rounded_box((1.0 - 2 * ring, width, thickness), 0.25 * thickness)  # A flat top >= 2 cm wide.
  ends = [cylinder(ring, thickness, segments=32).translate((x, 0.0, 0.0)) for x in (-0.5 + ring, 0.5 - ring)]
  hexagon = cylinder(0.5 * ring, 2 * thickness, segments=6).translate((-0.5 + ring, 0.0, 0.0))
  slot = box((ring * 1.5, ring * (0.8 + 0.3 * h[3]), 2 * thickness), (0.5, 0.0, 0.0))
  return difference(union([bar, *ends]), [hexagon, slot])


# ----------------------------------------------------------------------------------------------------------
# Toys: several primitives assembled.

_TOYS = ('car', 'figure', 'blocks')


def _draw_toy(rng: np.random.Generator) -> Params:
  return {'extent': draw_extent(rng, 0.08), 'toy': _TOYS[int(rng.integers(len(_TOYS)))],
          'shape': rng.uniform(0.0, 1.0, 8),
          'block_kinds': rng.integers(0, 3, 6), 'block_sizes': rng.uniform(0.15, 0.4, (6, 3)),
          'block_places': rng.uniform(-0.4, 0.4, (6, 2)), 'block_turns': rng.uniform(0.0, 90.0, 6),
          'block_count': int(rng.integers(3, 7))}


def _build_car(s: np.ndarray) -> Manifold:
  width, height = 0.4 + 0.2 * s[0], 0.18 + 0.12 * s[1]
  body = rounded_box((1.0, width, height), 0.3 * min(width, height))
  cabin_size = (0.4 + 0.2 * s[2], 0.9 * width, 0.15 + 0.1 * s[3])
  cabin = rounded_box(cabin_size, 0.25 * cabin_size[2]).translate(
      (-0.15 + 0.25 * s[4], 0.0, 0.5 * height + 0.5 * cabin_size[2] - 0.02))
  wheel_radius, wheel_width = 0.12 + 0.06 * s[5], 0.08 + 0.06 * s[6]
  wheel = along_y(cylinder(wheel_radius, wheel_width, segments=32))
  x = 0.5 - wheel_radius - 0.05 * s[7]
  y = 0.5 * width - 0.5 * wheel_width + 0.02
  wheels = [wheel.translate((sx * x, sy * y, -0.5 * height)) for sx in (-1, 1) for sy in (-1, 1)]
  return union([body, cabin, *wheels])


def _build_figure(s: np.ndarray) -> Manifold:
  torso_size = np.r_[0.3 + 0.15 * s[0], 0.18 + 0.12 * s[1], 0.35 + 0.15 * s[2]]
  torso = rounded_box(torso_size, 0.2 * torso_size[1])
  w, _, h = 0.5 * torso_size
  head_radius = 0.12 + 0.06 * s[3]
  head = Manifold.sphere(head_radius, 24).translate((0.0, 0.0, h + 0.8 * head_radius))
  leg_radius, leg_length = 0.06 + 0.03 * s[4], 0.3 + 0.15 * s[5]
  legs = [rod((x, 0, -h + 0.02), (x, 0, -h - leg_length), leg_radius) for x in (-0.5 * w, 0.5 * w)]
  arm_radius, arm_length, spread = 0.05 + 0.02 * s[6], 0.3 + 0.15 * s[7], np.radians(10 + 60 * s[0])
  arms = [rod((sx * (w - arm_radius), 0, h - 0.05),
              (sx * (w - arm_radius + arm_length * np.sin(spread)), 0, h - 0.05 - arm_length * np.cos(spread)),
              arm_radius) for sx in (-1, 1)]
  return union([torso, head, *legs, *arms])


def _build_blocks(p: Params) -> Manifold:
  s = p['shape']
  base_size = np.r_[1.0, 0.5 + 0.5 * s[0], 0.2 + 0.2 * s[1]]
  parts = [box(base_size)]
  for kind, size, place, turn in list(zip(p['block_kinds'], p['block_sizes'], p['block_places'],
                                          p['block_turns']))[:p['block_count']]:
    if kind == 0:
      part = box(size)
    elif kind == 1:
      part = cylinder(0.5 * size[0], size[2], segments=32)
    else:
      part = Manifold.sphere(0.5 * size[0], 24)
    centre = (place[0] * base_size[0], place[1] * base_size[1], 0.5 * base_size[2])
    parts.append(part.rotate((0.0, 0.0, float(turn))).translate(centre))
  return union(parts)


def _build_toy(p: Params) -> Manifold:
  if p['toy'] == 'car':
    return _build_car(p['shape'])
  if p['toy'] == 'figure':
    return _build_figure(p['shape'])
  return _build_blocks(p)


# ----------------------------------------------------------------------------------------------------------
# Blister packs: a thin card with a raised bubble.

_BUBBLES = ('dome', 'pill', 'box')


def _draw_blister(rng: np.random.Generator) -> Params:
  extent, height = draw_extent(rng, 0.08), rng.uniform(0.6, 1.1)
  unit = extent / max(1.0, height)  # Metres per model unit.
  return {'extent': extent, 'height': height, 'thickness': rng.uniform(0.03, 0.05),
          'corner': rng.uniform(0.02, 0.08), 'bubble': _BUBBLES[int(rng.integers(len(_BUBBLES)))],
          'bubble_size': rng.uniform(0.35, 0.7, 2), 'bubble_height': rng.uniform(0.015, 0.035) / unit,
          'bubble_shift': rng.uniform(-0.1, 0.1), 'has_hole': bool(rng.random() < 0.7),
          'hole_radius': rng.uniform(0.03, 0.05), 'slot_hole': bool(rng.random() < 0.5)}


def _build_blister(p: Params) -> Manifold:
  height, thickness, corner = p['height'], p['thickness'], p['corner']
  card = extrude(rectangle(1.0 - 2 * corner, height - 2 * corner).offset(corner, _ROUND, 2.0, SMALL_SEGMENTS),
                 thickness)
  hole_y, margin = 0.5 * height - 0.1, 0.06
  top_limit = hole_y - p['hole_radius'] - margin if p['has_hole'] else 0.5 * height - margin
  size_x = p['bubble_size'][0]
  size_y = min(p['bubble_size'][1] * height, top_limit - (-0.5 * height + margin))
  centre = (p['bubble_shift'], -0.5 * height + margin + 0.5 * size_y, 0.0)
  if p['bubble'] == 'dome':
    bubble = ellipsoid((0.5 * size_x, 0.5 * size_y, p['bubble_height']))
  else:
    radius = (0.45 if p['bubble'] == 'pill' else 0.15) * min(size_x, size_y, p['bubble_height'])
    bubble = rounded_box((size_x, size_y, 2 * p['bubble_height']), radius)
  bubble = bubble.trim_by_plane((0.0, 0.0, 1.0), 0.0).translate(centre)
  cutters = []
  if p['has_hole']:
    r = p['hole_radius']
    hole = (Manifold.batch_hull([cylinder(r, 1.0, segments=SMALL_SEGMENTS).translate((dx, 0.0, 0.0))
                                 for dx in (-1.5 * r, 1.5 * r)])
            if p['slot_hole'] else cylinder(r, 1.0, segments=SMALL_SEGMENTS))
    cutters.append(hole.translate((0.0, hole_y, 0.0)))
  return difference(union([card, bubble]), cutters)


LEVEL2_FAMILIES: tuple[ShapeFamily, ...] = (
    ShapeFamily('vessel', _draw_vessel, _build_vessel, VESSEL_PLASTIC),
    ShapeFamily('bottle', _draw_bottle, _build_bottle, FILLED_BOTTLE),
    ShapeFamily('letter', _draw_letter, _build_letter, ABS),
    ShapeFamily('tool', _draw_tool, _build_tool, PLASTIC_TOOL),
    ShapeFamily('toy', _draw_toy, _build_toy, SOFTWOOD),
    ShapeFamily('blister', _draw_blister, _build_blister, PACKAGED_GOODS),
)
"""Level 2 (household objects with complex geometry: vessels, bottles, letters, tools, toys, blister packs)."""
