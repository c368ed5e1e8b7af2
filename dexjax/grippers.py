"""Gripper parameters as frozen pytrees, with the Dex-Net 4.0 defaults (ABB YuMi jaws and a 20 mm suction cup).

Float fields are pytree leaves (they can be traced, batched or differentiated); integer fields that set array
shapes are static metadata, so changing them recompiles.
"""

from __future__ import annotations

import math

from flax import struct

STANDARD_GRAVITY = 9.81  # m/s^2

#: Suction payload of the Dex-Net 4.0 cup (seed: "approximately 0.9 kg").
SUCTION_PAYLOAD_KG = 0.9


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
  """

  max_width: float = 0.05
  min_width: float = 0.0
  force_limit: float = 20.0
  finger_radius: float = 0.005
  num_cone_edges: int = struct.field(pytree_node=False, default=8)
  num_line_samples: int = struct.field(pytree_node=False, default=64)


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
  contact_tolerance: float = 0.005
  num_ring_vertices: int = struct.field(pytree_node=False, default=8)
  num_edge_subsamples: int = struct.field(pytree_node=False, default=2)
  num_ray_steps: int = struct.field(pytree_node=False, default=12)


Gripper = ParallelJawGripper | SuctionGripper
