"""Image-space grasps (gqcnn's `Grasp2D` / `SuctionPoint2D`, spec section 1.1) and their 3-D world grasps.

Conventions: pixel centres (u, v) = (column, row) as `dexjax.render.camera`; camera frame x right, y down,
z forward; depths are camera-frame z, metres. Every function works on one grasp; `vmap` to batch.

* parallel jaw: the jaw axis is (cos angle, sin angle) in (x right, y down) image coordinates, i.e. the 3-D
  camera-frame axis (cos angle, sin angle, 0); the approach is the optical axis (camera +z).
* suction: the camera-frame approach a (unit, into the surface) is encoded by psi = ``approach_angle`` =
  arccos(a_z) and ``angle`` = the signed angle of r = a x z_hat = (a_y, -a_x) from the image x axis, so
  a = (-sin(angle) sin(psi), cos(angle) sin(psi), cos(psi)); angle = 0 when a is parallel to z.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.grasps import ParallelJawGrasp, SuctionGrasp
from dexjax.render.camera import Camera

_EPS = 1e-9


@struct.dataclass
class ImageParallelJawGrasp:
  """A parallel-jaw grasp in a depth image.

  Attributes:
    center: (2,) float32 grasp centre pixel (u, v) = (column, row).
    angle: () in-plane jaw-axis angle from the image x axis (x right, y down), radians.
    depth: () camera-frame z of the grasp centre (gripper depth), metres.
    width: () jaw opening, metres.
  """

  center: jax.Array
  angle: jax.Array
  depth: jax.Array
  width: jax.Array


@struct.dataclass
class ImageSuctionGrasp:
  """A suction grasp in a depth image.

  Attributes:
    center: (2,) float32 target pixel (u, v) = (column, row).
    angle: () in-plane angle of r = a x z_hat = (a_y, -a_x) from the image x axis, radians (the crop angle).
    depth: () camera-frame z of the target point, metres.
    approach_angle: () angle psi between the approach axis and the optical axis, radians, in [0, pi).
  """

  center: jax.Array
  angle: jax.Array
  depth: jax.Array
  approach_angle: jax.Array


def approach_from_angles(angle: jax.Array, approach_angle: jax.Array) -> jax.Array:
  """(3,) camera-frame unit suction approach from the in-image ``angle`` and the ``approach_angle`` (rad)."""
  s = jnp.sin(approach_angle)
  return jnp.stack([-jnp.sin(angle) * s, jnp.cos(angle) * s, jnp.cos(approach_angle)])


def angles_from_approach(approach: jax.Array) -> tuple[jax.Array, jax.Array]:
  """(angle, approach_angle) radians of a camera-frame unit approach (3,) (spec section 1.1).

  angle = atan2(r_y, r_x) with r = (a_y, -a_x), 0 when a is (anti)parallel to the optical axis;
  approach_angle = arccos(a_z).
  """
  rx, ry = approach[1], -approach[0]
  aligned = rx * rx + ry * ry < _EPS * _EPS
  angle = jnp.where(aligned, 0.0, jnp.arctan2(ry, jnp.where(aligned, 1.0, rx)))
  return angle, jnp.arccos(jnp.clip(approach[2], -1.0, 1.0))


def camera_point(camera: Camera, center: jax.Array, depth: jax.Array) -> jax.Array:
  """(3,) camera-frame point at pixel ``center`` (2,) (u, v) and camera-frame z ``depth`` metres."""
  k = camera.intrinsics
  return jnp.stack([(center[0] - k.cx) / k.fx * depth, (center[1] - k.cy) / k.fy * depth, depth])


def parallel_jaw_grasp_3d(camera: Camera, grasp: ImageParallelJawGrasp) -> ParallelJawGrasp:
  """World-frame `ParallelJawGrasp` of an image grasp seen by ``camera``.

  centre = deprojected centre pixel at the grasp depth; axis = camera-frame (cos angle, sin angle, 0);
  approach = the optical axis (camera +z); width unchanged. Directions are rotated into the world frame.
  """
  rot = camera.rotation
  center = rot @ camera_point(camera, grasp.center, grasp.depth) + camera.position
  axis = rot @ jnp.stack([jnp.cos(grasp.angle), jnp.sin(grasp.angle), jnp.zeros_like(grasp.angle)])
  return ParallelJawGrasp(center=center, axis=axis, approach=rot[:, 2], width=jnp.asarray(grasp.width))


def suction_grasp_3d(camera: Camera, grasp: ImageSuctionGrasp) -> SuctionGrasp:
  """World-frame `SuctionGrasp`: centre = deprojected pixel at the depth, approach from the two angles."""
  rot = camera.rotation
  center = rot @ camera_point(camera, grasp.center, grasp.depth) + camera.position
  return SuctionGrasp(center=center, approach=rot @ approach_from_angles(grasp.angle, grasp.approach_angle))
