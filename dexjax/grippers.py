"""Gripper parameters as frozen pytrees, with the Dex-Net 4.0 defaults (ABB YuMi jaws and a 20 mm suction cup).

Float fields are pytree leaves (they can be traced, batched or differentiated); integer fields that set array
shapes are static metadata, so changing them recompiles. ``validate()`` checks the fields, their limits (lengths at
most 1 m, forces at most 1e5 N, static counts at most 1024: `dexjax.config_rules`) and the rules that tie them
together (e.g. ``min_width < max_width``) eagerly, before any computing.
"""

from __future__ import annotations

import math

import jax
import numpy as np
from flax import struct

from dexjax.config_rules import (MAX_FORCE, MAX_GRIPPER_SIZE, MAX_STATIC_COUNT, check_fields, count_rule, number_or_nan,
                                 number_rule)

STANDARD_GRAVITY = 9.81  # m/s^2

#: Suction payload of the Dex-Net 4.0 cup (seed: "approximately 0.9 kg").
SUCTION_PAYLOAD_KG = 0.9

#: Safety factor of a suction gripper on its static load: at least 1.5 for smooth, dense workpieces (Schmalz's
#: sizing guide, after the German accident-prevention regulation UVV).
SUCTION_SAFETY_FACTOR = 1.5

#: The heaviest object the seed's cup is rated for: its payload over the safety factor, kg (0.6).
SUCTION_RATED_MASS_KG = SUCTION_PAYLOAD_KG / SUCTION_SAFETY_FACTOR

#: Bending stiffness of the cup's bellows, N m / rad: an estimate (no maker publishes it; docs/benchmark.md): a
#: 20 mm silicone tube of 1.5 mm wall and 1 cm length bends at E I / L ~ 0.7 N m/rad (E ~ 1.5 MPa), a convoluted
#: bellows one to two orders softer; a finger tilts one by 30 degrees with about 1 N at 2 cm. The labels' tipping
#: test (`SuctionGripper.bellows_stiffness`) and the physics judge's bellows (`dexjax.bench.gripper_bodies`) share it.
BELLOWS_STIFFNESS = 0.05

#: The bellows' bending range, rad (about 30 degrees: the "angle compensation" bellows cups are sold for; an
#: estimate). The labels' tipping test (`SuctionGripper.bellows_max_angle`) and the physics judge's bellows share it.
BELLOWS_MAX_ANGLE = 0.5


@struct.dataclass
class ParallelJawGripper:
  """A parallel-jaw gripper whose fingers close along a line of action (Dex-Net's point-finger sweep).

  Attributes:
    max_width: opening of the jaws, metres (YuMi: 0.05).
    min_width: closest the jaws can get, metres.
    force_limit: largest grip force per finger, newtons (YuMi: 20).
    finger_radius: radius of the soft fingertip's contact patch, metres; sets the torsional friction of the
      soft-finger model, gamma = (2/3) * mu * finger_radius (uniform pressure on a disc).
    num_cone_edges: static, edges of the linearised friction cone per contact (Dex-Net: 8).
    num_line_samples: static, samples along each jaw's line of action before root refinement.
    finger_thickness: static, finger size along the jaw axis, outward from the pad, metres (1 cm). 0 means point
      jaws (Dex-Net's model): the single-object quality and the 3-D sampler then run no volume test.
    finger_width: static, finger (pad) size across the jaw axis and the approach, metres (2 cm).
    finger_length: static, finger size along the approach, metres (6 cm).
    tip_depth: static, how far the fingertips reach beyond the grasp centre along the approach, metres (1 cm).
    palm_depth: static, palm size along the approach, behind the fingers, metres (2 cm).
    palm_width: static, palm size along the jaw axis, metres (7 cm: the 5 cm opening plus two fingers).
    palm_height: static, palm size across the jaw axis and the approach, metres (2 cm).

  The finger and palm sizes are the collision solids of `dexjax.quality.gripper_geometry` (fingers and palm
  swept back along the approach by the standoff), used alike by the heap reward, the single-object quality
  (``jaw_collision``) and the antipodal sampler. Defaults: estimates for the YuMi with its silicone
  fingertips (the seed's CAD model is not public; docs/deviations.md items 27 and 38). They are static because
  they set sample counts: changing them recompiles.
  """

  max_width: float = 0.05
  min_width: float = 0.0
  force_limit: float = 20.0
  finger_radius: float = 0.005
  num_cone_edges: int = struct.field(pytree_node=False, default=8)
  num_line_samples: int = struct.field(pytree_node=False, default=64)
  finger_thickness: float = struct.field(pytree_node=False, default=0.01)
  finger_width: float = struct.field(pytree_node=False, default=0.02)
  finger_length: float = struct.field(pytree_node=False, default=0.06)
  tip_depth: float = struct.field(pytree_node=False, default=0.01)
  palm_depth: float = struct.field(pytree_node=False, default=0.02)
  palm_width: float = struct.field(pytree_node=False, default=0.07)
  palm_height: float = struct.field(pytree_node=False, default=0.02)

  def validate(self, source: str = 'ParallelJawGripper', section: str = '') -> ParallelJawGripper:
    """Returns ``self`` if the fields are consistent; raises `dexjax.config.ConfigError` (a ValueError) naming
    ``source``, the field and the expected value otherwise. Traced or batched fields are not checked (call it
    eagerly, on one gripper)."""
    if _not_concrete(self):
      return self
    thickness, length = number_or_nan(self.finger_thickness), number_or_nan(self.finger_length)
    needed = number_or_nan(self.max_width) + 2.0 * thickness

    def size(field: str, unit: str = 'metres', low_open: bool = True):  # a length of at most MAX_GRIPPER_SIZE
      return number_rule(field, getattr(self, field), 0, MAX_GRIPPER_SIZE, unit, low_open=low_open)

    return check_fields([
        size('max_width'),
        ('min_width', 0 <= number_or_nan(self.min_width) < number_or_nan(self.max_width),
         f'a number in [0, max_width = {self.max_width}) (metres)'),
        number_rule('force_limit', self.force_limit, 0, MAX_FORCE, 'newtons', low_open=True),
        size('finger_radius', low_open=False),
        count_rule('num_cone_edges', self.num_cone_edges, 3, MAX_STATIC_COUNT),
        count_rule('num_line_samples', self.num_line_samples, 2, MAX_STATIC_COUNT),
        size('finger_thickness', 'metres; 0 = point jaws', low_open=False),
        size('finger_width'),
        size('finger_length'),
        ('tip_depth', 0 <= number_or_nan(self.tip_depth) <= length,
         f'a number in [0, finger_length = {self.finger_length}] (metres; the pads must reach the grasp centre)'),
        size('palm_depth'),
        ('palm_width', needed - 1e-9 <= number_or_nan(self.palm_width) <= 3 * MAX_GRIPPER_SIZE,
         f'a number in [max_width + 2 finger_thickness = {needed:.6g}, {3 * MAX_GRIPPER_SIZE:g}] (metres; the palm '
         'carries both fingers at the widest opening)'),
        size('palm_height'),
    ], self, source=source, section=section)


@struct.dataclass
class SuctionGripper:
  """A compliant single-bellows vacuum cup (Dex-Net 3.0 spring model and suction-ring contact).

  Attributes:
    cup_radius: radius of the cup lip, metres (Dex-Net 4.0: 20 mm diameter -> 0.01).
    cone_height: height of the undeformed spring cone from lip to apex, metres (not reported by Dex-Net;
      we use the cup radius, a 45 degree cone).
    vacuum_force: pull of the vacuum on the object, newtons. Default: the seed's payload, 0.9 kg x g.
    elastic_limit: kappa, the largest amplitude of the first harmonic of the lip pressure, newtons per
      radian; the cup resists torques about its tangent axes up to pi * r * kappa / sqrt(2). Default
      V / (2 pi): the largest amplitude that keeps the lip pressure of the vacuum non-negative.
    max_strain: largest relative length change of any spring for a seal (Dex-Net 3.0: 10 %).
    bellows_stiffness: k, the bellows' bending stiffness, N m / rad (`BELLOWS_STIFFNESS`, an estimate). A held
      object bends the bellows about their pivot (half the cone height behind the lip) until the spring balances
      its weight's torque; it tips over when that takes more than the bellows' range (`suction_quality`'s
      ``tips``, `dexjax.quality.grasp_quality.bellows_margin`; e.g. a bowl held from inside).
    bellows_max_angle: a, the bellows' bending range, rad (`BELLOWS_MAX_ANGLE`, an estimate).
    contact_tolerance: the approach ray through the grasp centre must first hit the object within this
      distance of the centre (along the approach), metres; otherwise the approach is blocked or misses.
    num_ring_vertices: static, vertices of the perimeter polygon (Dex-Net 3.0: 8).
    num_edge_subsamples: static, extra points projected along each perimeter edge to measure its
      arclength on the surface.
    num_ray_steps: static, sphere-tracing steps per lip projection ray (twice as many for the approach ray,
      which starts outside the object's grid).
  """

  cup_radius: float = 0.01
  cone_height: float = 0.01
  vacuum_force: float = SUCTION_PAYLOAD_KG * STANDARD_GRAVITY
  elastic_limit: float = SUCTION_PAYLOAD_KG * STANDARD_GRAVITY / (2.0 * math.pi)
  max_strain: float = 0.1
  bellows_stiffness: float = BELLOWS_STIFFNESS
  bellows_max_angle: float = BELLOWS_MAX_ANGLE
  contact_tolerance: float = 0.005
  num_ring_vertices: int = struct.field(pytree_node=False, default=8)
  num_edge_subsamples: int = struct.field(pytree_node=False, default=2)
  num_ray_steps: int = struct.field(pytree_node=False, default=12)

  def validate(self, source: str = 'SuctionGripper', section: str = '') -> SuctionGripper:
    """Returns ``self`` if the fields are consistent; raises `dexjax.config.ConfigError` (a ValueError) naming
    ``source``, the field and the expected value otherwise (traced or batched fields: not checked)."""
    if _not_concrete(self):
      return self
    return check_fields([
        number_rule('cup_radius', self.cup_radius, 0, MAX_GRIPPER_SIZE, 'metres', low_open=True),
        number_rule('cone_height', self.cone_height, 0, MAX_GRIPPER_SIZE, 'metres', low_open=True),
        number_rule('vacuum_force', self.vacuum_force, 0, MAX_FORCE, 'newtons', low_open=True),
        number_rule('elastic_limit', self.elastic_limit, 0, MAX_FORCE, 'newtons per radian'),
        ('max_strain', 0 < number_or_nan(self.max_strain) < 1, 'a fraction in (0, 1)'),
        number_rule('bellows_stiffness', self.bellows_stiffness, 0, MAX_FORCE, 'N m per radian'),
        number_rule('bellows_max_angle', self.bellows_max_angle, 0, math.pi / 2, 'radians', low_open=True),
        number_rule('contact_tolerance', self.contact_tolerance, 0, MAX_GRIPPER_SIZE, 'metres', low_open=True),
        count_rule('num_ring_vertices', self.num_ring_vertices, 3, MAX_STATIC_COUNT),
        count_rule('num_edge_subsamples', self.num_edge_subsamples, 0, MAX_STATIC_COUNT),
        count_rule('num_ray_steps', self.num_ray_steps, 1, MAX_STATIC_COUNT),
    ], self, source=source, section=section)


Gripper = ParallelJawGripper | SuctionGripper


def _not_concrete(params) -> bool:
  """True if a field is a JAX tracer (inside jit / vmap) or a batch of values: validation is then skipped."""
  return any(isinstance(x, jax.core.Tracer) or np.ndim(x) > 0 for x in jax.tree.leaves(params))
