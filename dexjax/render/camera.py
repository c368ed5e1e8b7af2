"""Pinhole depth cameras: intrinsics and pose as pytrees, projection and deprojection (single item; `vmap`).

Conventions (OpenCV's, as in Dex-Net's perception package):

* camera frame: x right, y down, z forward (along the optical axis); depth is the z coordinate of a point in
  the camera frame, metres (not the distance along the ray);
* pixel (u, v) = (column, row); the centre of pixel (i, j) (row i, column j) is at u = j, v = i, so
  u = fx x / z + cx and v = fy y / z + cy;
* `Camera.rotation` and `Camera.position` give the camera frame in the world frame: a point p_c in the camera
  frame is ``rotation @ p_c + position`` in the world frame.
"""

from __future__ import annotations

import numbers
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.geometry.transforms import normalize

#: Largest image width and height dexjax renders and accepts from a camera, intrinsics or config file, pixels:
#: room for a 4K sensor (3840 x 2160), within the offscreen framebuffer every GL backend provides (larger ones
#: fail inside MuJoCo: "Offscreen framebuffer is not complete") and the memory of one image per ray-casting call.
MAX_IMAGE_SIDE = 4096

#: Largest focal length fx, fy of an intrinsics file, pixels: a field of view of 0.23 degrees across 4096 pixels
#: (a 1000 mm lens on 1 um pixels); larger values are a unit mistake and overflow float32 beyond 3.4e38.
MAX_FOCAL_LENGTH = 1e6


def check_image_side(name: str, field: str, value: Any) -> int:
  """``value`` as an int; raises ValueError naming ``name`` (a file, or the checked class) and ``field`` unless it
  is an integer (not a bool or a float) in [1, `MAX_IMAGE_SIDE`] pixels."""
  if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not 0 < value <= MAX_IMAGE_SIDE:
    raise ValueError(f'{name}: {field}: expected a positive integer of at most {MAX_IMAGE_SIDE} (pixels; the '
                     f'largest image side dexjax renders), got {value!r}')
  return int(value)


@struct.dataclass
class Intrinsics:
  """Pinhole intrinsics without distortion.

  Attributes:
    fx, fy: focal lengths, pixels.
    cx, cy: principal point, pixels (pixel centres at integer coordinates).
    width, height: static image size, pixels.
  """

  fx: jax.Array | float
  fy: jax.Array | float
  cx: jax.Array | float
  cy: jax.Array | float
  width: int = struct.field(pytree_node=False, default=500)
  height: int = struct.field(pytree_node=False, default=500)

  @property
  def matrix(self) -> jax.Array:
    """(3, 3) float32 camera matrix K."""
    return jnp.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], jnp.float32)


@struct.dataclass
class Camera:
  """A posed pinhole camera.

  Attributes:
    intrinsics: the `Intrinsics`.
    rotation: (3, 3) float32 world-from-camera rotation; its columns are the camera's x (right), y (down) and
      z (optical axis) in world coordinates.
    position: (3,) float32 camera centre in the world frame, metres.
  """

  intrinsics: Intrinsics
  rotation: jax.Array
  position: jax.Array


def look_at(eye: jax.Array, target: jax.Array, up: jax.Array | None = None) -> jax.Array:
  """(3, 3) world-from-camera rotation of a camera at ``eye`` (3,) looking at ``target`` (3,).

  The optical axis (z) points from ``eye`` to ``target``; the image's "up" (-y) is the projection of ``up``
  (default world +z) onto the image plane; when the axis is parallel to ``up``, world +y is used instead
  (world +x if the axis is also close to y).
  """
  z = normalize(target - eye)
  if up is None:  # not a default argument: building an array at import would compile a program
    up = jnp.array([0.0, 0.0, 1.0], z.dtype)
  fallback = jnp.where(jnp.abs(z[1]) < 0.9, jnp.array([0.0, 1.0, 0.0], z.dtype),
                       jnp.array([1.0, 0.0, 0.0], z.dtype))
  up = jnp.where(jnp.abs(jnp.dot(normalize(up), z)) > 1.0 - 1e-6, fallback, up)
  x = normalize(jnp.cross(z, up))  # right = forward x up, for y down
  y = jnp.cross(z, x)
  return jnp.stack([x, y, z], axis=1)


def world_to_camera(camera: Camera, points: jax.Array) -> jax.Array:
  """Points (..., 3) from the world frame to the camera frame, metres."""
  return (points - camera.position) @ camera.rotation


def camera_to_world(camera: Camera, points: jax.Array) -> jax.Array:
  """Points (..., 3) from the camera frame to the world frame, metres."""
  return points @ camera.rotation.T + camera.position


def project(camera: Camera, points: jax.Array) -> tuple[jax.Array, jax.Array]:
  """Projects world points (..., 3) to pixels.

  Returns:
    (pixels (..., 2) float32 (u, v), depth (...,) float32 metres): points at or behind the camera (depth <= 0)
    get NaN pixels.
  """
  p = world_to_camera(camera, points)
  k = camera.intrinsics
  z = p[..., 2]
  safe = jnp.where(z > 0, z, 1.0)
  uv = jnp.stack([k.fx * p[..., 0] / safe + k.cx, k.fy * p[..., 1] / safe + k.cy], axis=-1)
  return jnp.where((z > 0)[..., None], uv, jnp.nan), z


def pixel_rays(intrinsics: Intrinsics) -> jax.Array:
  """(H, W, 3) float32 camera-frame rays through every pixel centre, scaled to unit depth (z = 1)."""
  v, u = jnp.meshgrid(jnp.arange(intrinsics.height, dtype=jnp.float32),
                      jnp.arange(intrinsics.width, dtype=jnp.float32), indexing='ij')
  return jnp.stack([(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy,
                    jnp.ones_like(u)], axis=-1)


def deproject(camera: Camera, depth: jax.Array) -> jax.Array:
  """Deprojects a depth image (H, W) float32 metres into world points (H, W, 3).

  Invalid pixels (depth NaN, infinite or <= 0) give NaN points; filter with ``jnp.isfinite(points[..., 0])``.
  """
  valid = jnp.isfinite(depth) & (depth > 0)
  p = pixel_rays(camera.intrinsics) * jnp.where(valid, depth, 0.0)[..., None]
  return jnp.where(valid[..., None], camera_to_world(camera, p), jnp.nan)
