"""Random depth-camera poses and intrinsics above the bin, as in Dex-Net 4.0 (single camera; `vmap` over keys).

Seed text: "The camera pose is sampled uniformly from a set of spherical coordinates: r in [0.7 m, 0.9 m],
theta in [250, 290] degrees, phi in [0, 10] degrees. The center of the sphere is selected randomly from the
planar base of the bin ... Images are rendered at half resolution with dimensions 500x500."

Our reading (see docs/cameras.md):

* phi is the polar angle of the camera measured from world +z (phi = 0: straight overhead) and theta is the
  azimuth about world +z measured from world +x towards +y, so the camera centre is
  ``center + r (sin phi cos theta, sin phi sin theta, cos phi)`` and is always above the floor;
* the sphere centre is uniform on the bin floor (z = 0) in a 10 cm x 10 cm square about the origin and the
  camera looks at it;
* r, theta, phi, the centre, f, cx and cy are independent and uniform in their ranges (uniform in the
  coordinates, not in area on the sphere);
* the image roll follows the azimuth: image "up" is world +z projected onto the image plane, i.e. the
  horizontal direction from the camera towards the centre; with theta = 270 degrees, image right is world +x
  and image up is world +y, and theta in [250, 290] rolls the image by at most +-20 degrees;
* the images are 500 x 500 pixels as rendered (the seed's "half resolution" refers to the sensor's native
  resolution); the principal point range [257.5, 262.5] px is ~8-13 px off the geometric centre 249.5 of a
  500-pixel image, as a real sensor's is.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.render.camera import Camera, Intrinsics, check_image_side, look_at

# (field name, unit, lower bound kind) of every sampled range, in sampling order.
_RANGES = (
    ('radius', 'metres', 'positive'),
    ('theta_deg', 'degrees', 'any'),
    ('phi_deg', 'degrees', 'polar'),
    ('center_x', 'metres', 'any'),
    ('center_y', 'metres', 'any'),
    ('focal', 'pixels', 'positive'),
    ('cx', 'pixels', 'any'),
    ('cy', 'pixels', 'any'),
)


@struct.dataclass
class CameraDistribution:
  """Uniform ranges of the camera's spherical pose and intrinsics; defaults are the Dex-Net 4.0 seed values.

  Each range is a (low, high) pair; each quantity is drawn uniformly and independently in it.

  Attributes:
    radius: distance from the sphere centre to the camera, metres (seed: [0.7, 0.9]).
    theta_deg: azimuth about world +z from world +x towards +y, degrees (seed: [250, 290]).
    phi_deg: polar angle from world +z, degrees; 0 is straight overhead; must stay in [0, 90)
      (seed: [0, 10]).
    center_x, center_y: sphere centre on the bin floor (z = 0), metres (seed: +-5 cm each).
    focal: focal length fx = fy, pixels (seed: [550, 600]).
    cx, cy: principal point, pixels, drawn independently (seed: [257.5, 262.5] each).
    width, height: static image size, pixels (seed: 500 x 500).
  """

  radius: tuple[float, float] = (0.7, 0.9)
  theta_deg: tuple[float, float] = (250.0, 290.0)
  phi_deg: tuple[float, float] = (0.0, 10.0)
  center_x: tuple[float, float] = (-0.05, 0.05)
  center_y: tuple[float, float] = (-0.05, 0.05)
  focal: tuple[float, float] = (550.0, 600.0)
  cx: tuple[float, float] = (257.5, 262.5)
  cy: tuple[float, float] = (257.5, 262.5)
  width: int = struct.field(pytree_node=False, default=500)
  height: int = struct.field(pytree_node=False, default=500)

  def validate(self) -> CameraDistribution:
    """Checks every field and returns ``self``; raises ValueError naming the field and the expected value.

    Traced (abstract) ranges cannot be checked and are skipped, so call this eagerly, outside `jit`.
    """
    for name, unit, kind in _RANGES:
      _check_range(name, getattr(self, name), unit, kind)
    for name in ('width', 'height'):
      check_image_side('CameraDistribution', name, getattr(self, name))
    return self


def _check_range(name: str, value, unit: str, kind: str) -> None:
  """Raises ValueError unless ``value`` is a finite (low, high) pair with low <= high and ``kind``'s bound."""
  expected = {
      'any': 'finite (low, high) with low <= high',
      'positive': 'finite (low, high) with 0 < low <= high',
      'polar': 'finite (low, high) with 0 <= low <= high < 90',
  }[kind]
  message = f'CameraDistribution: {name}: expected {expected} ({unit}), got {value!r}'
  try:
    pair = tuple(value)
  except TypeError:
    raise ValueError(message) from None
  if len(pair) != 2:
    raise ValueError(message)
  if any(isinstance(v, jax.core.Tracer) for v in pair):
    return
  try:
    low, high = (float(v) for v in pair)
  except (TypeError, ValueError):
    raise ValueError(message) from None
  ok = math.isfinite(low) and math.isfinite(high) and low <= high
  if kind == 'positive':
    ok = ok and low > 0
  elif kind == 'polar':
    ok = ok and low >= 0 and high < 90
  if not ok:
    raise ValueError(message)


def camera_from_spherical(center: jax.Array, r: jax.Array | float, theta: jax.Array | float,
                          phi: jax.Array | float, intrinsics: Intrinsics) -> Camera:
  """The camera at spherical coordinates (r, theta, phi) about ``center``, looking at ``center``.

  Args:
    center: (3,) sphere centre in the world frame, metres (on the bin floor for Dex-Net, z = 0).
    r: distance from ``center`` to the camera, metres (> 0).
    theta: azimuth about world +z from world +x towards +y, radians.
    phi: polar angle from world +z, radians, in [0, pi/2) for a camera above ``center``.
    intrinsics: the camera's `Intrinsics`.

  Returns:
    A `Camera` at ``center + r (sin phi cos theta, sin phi sin theta, cos phi)`` whose optical axis passes
    through ``center``. Image "up" is world +z projected onto the image plane, which is the horizontal
    direction (-cos theta, -sin theta, 0) projected; passing that direction to `look_at` keeps the roll
    continuous at phi = 0 (straight overhead) instead of switching to `look_at`'s fallback.
  """
  center = jnp.asarray(center, jnp.float32)
  r, theta, phi = (jnp.asarray(x, jnp.float32) for x in (r, theta, phi))
  offset = jnp.stack([jnp.sin(phi) * jnp.cos(theta), jnp.sin(phi) * jnp.sin(theta), jnp.cos(phi)])
  position = center + r * offset
  up = jnp.stack([-jnp.cos(theta), -jnp.sin(theta), jnp.zeros_like(theta)])
  return Camera(intrinsics=intrinsics, rotation=look_at(position, center, up), position=position)


def spherical_from_camera(camera: Camera, floor_height: float | jax.Array = 0.0
                          ) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
  """The spherical pose of a camera about where its optical axis meets the floor: `camera_from_spherical`'s
  inverse, for any posed camera (a sampled one, or the user's own, to compare with a `CameraDistribution`).

  Args:
    camera: one `Camera` (world-from-camera rotation; its third column is the optical axis).
    floor_height: world z of the floor plane the axis is intersected with, metres (the bin floor: 0).

  Returns:
    (center (3,) the axis's floor point, metres; r () the distance from it to the camera, metres; theta () the
    camera's azimuth about world +z from +x towards +y, radians in [0, 2 pi); phi () its polar angle from world
    +z, radians: the camera's tilt from straight down). All NaN when the axis does not point down to the floor
    (or the camera is below it).
  """
  position = jnp.asarray(camera.position, jnp.float32)
  axis = jnp.asarray(camera.rotation, jnp.float32)[:, 2]
  height = position[2] - floor_height
  valid = (axis[2] < 0.0) & (height > 0.0)
  r = jnp.where(valid, height / jnp.where(valid, -axis[2], 1.0), jnp.nan)
  center = position + r * axis
  offset = position - center
  theta = jnp.mod(jnp.arctan2(offset[1], offset[0]), 2.0 * jnp.pi)
  phi = jnp.arccos(jnp.clip(-axis[2], -1.0, 1.0))
  nan = jnp.float32(jnp.nan)
  return center, r, jnp.where(valid, theta, nan), jnp.where(valid, phi, nan)


def _sample_pose_and_intrinsics(key: jax.Array, dist: CameraDistribution) -> tuple[jax.Array, ...]:
  """Draws (center (3,) m, r m, theta rad, phi rad, f px, cx px, cy px), each uniform in its range."""
  low = jnp.array([getattr(dist, name)[0] for name, _, _ in _RANGES], jnp.float32)
  high = jnp.array([getattr(dist, name)[1] for name, _, _ in _RANGES], jnp.float32)
  r, theta, phi, x, y, f, cx, cy = low + (high - low) * jax.random.uniform(key, (len(_RANGES),))
  center = jnp.stack([x, y, jnp.zeros_like(x)])
  return center, r, jnp.deg2rad(theta), jnp.deg2rad(phi), f, cx, cy


def sample_camera(key: jax.Array, dist: CameraDistribution = CameraDistribution()) -> Camera:
  """One random camera from ``dist`` (validated when its ranges are concrete).

  Batch with ``jax.vmap(sample_camera, in_axes=(0, None))(keys, dist)``.

  Args:
    key: a PRNG key.
    dist: the `CameraDistribution` (default: Dex-Net 4.0's).

  Returns:
    A `Camera` with float32 scalar intrinsics (fx = fy), (3, 3) rotation and (3,) position in metres,
    looking at a random point of the bin floor.
  """
  dist.validate()
  center, r, theta, phi, f, cx, cy = _sample_pose_and_intrinsics(key, dist)
  intrinsics = Intrinsics(fx=f, fy=f, cx=cx, cy=cy, width=dist.width, height=dist.height)
  return camera_from_spherical(center, r, theta, phi, intrinsics)
