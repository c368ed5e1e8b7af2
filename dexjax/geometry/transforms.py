"""Small SO(3)/vector helpers used by the contact models and samplers (single item; `vmap` to batch)."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

_EPS = 1e-12


def normalize(v: jax.Array, eps: float = _EPS) -> jax.Array:
  """Unit vector along ``v`` (..., 3); a zero vector stays zero."""
  n = jnp.linalg.norm(v, axis=-1, keepdims=True)
  return v / jnp.maximum(n, eps)


def tangent_basis(normal: jax.Array) -> tuple[jax.Array, jax.Array]:
  """Orthonormal tangents (t1, t2) of a unit ``normal`` (3,), with t2 = normal x t1: a deterministic frame for
  poses, cones and lip polygons.

  t1 is the projection of the frame's x axis onto the tangent plane, or of the y axis when the normal is within
  ~8 degrees of x (so t1 never comes from a short, ill-conditioned projection). This is *not* Dex-Net's
  friction-cone frame near x; the soft-finger cone uses `aligned_tangent_basis` for that.
  """
  ex = jnp.array([1.0, 0.0, 0.0], normal.dtype)
  ey = jnp.array([0.0, 1.0, 0.0], normal.dtype)
  ref = jnp.where(jnp.abs(normal[0]) < 0.99, ex, ey)
  t1 = normalize(ref - jnp.dot(ref, normal) * normal)
  t2 = jnp.cross(normal, t1)
  return t1, t2


def aligned_tangent_basis(normal: jax.Array) -> tuple[jax.Array, jax.Array]:
  """Orthonormal tangents (t1, t2 = normal x t1) of a unit ``normal`` (3,) with t1 along the projection of the
  frame's x axis onto the tangent plane, for every normal not parallel to x.

  Dex-Net's friction cone (`Contact3D.tangents(align_axes=True)`) searches 1,000 azimuths of the tangent plane
  for the one with the largest inner product with x, i.e. this projection to within 0.18 degrees; it keeps x
  however close the normal is to it. The projection x - n_x n of a unit normal is written
  (n_y^2 + n_z^2, -n_x n_y, -n_x n_z), whose length is s = sqrt(n_y^2 + n_z^2), so it stays accurate in float32
  right up to the normal being x. Only when s < 1e-6 (the normal is +-x to float32 precision, where Dex-Net's
  search returns an arbitrary SVD tangent) does t1 fall back to `tangent_basis`. Differentiable everywhere
  (the fallback branch's gradient is not NaN). t2's sign differs from Dex-Net's w = (-normal) x t1, which does
  not change a cone sampled at symmetric azimuths.
  """
  nx, ny, nz = normal[0], normal[1], normal[2]
  sq = ny * ny + nz * nz
  aligned = sq > 1e-12
  s = jnp.sqrt(jnp.where(aligned, sq, 1.0))
  projected = jnp.stack([s, -nx * ny / s, -nx * nz / s])
  fallback, _ = tangent_basis(normal)
  t1 = jnp.where(aligned, projected, fallback)
  return t1, jnp.cross(normal, t1)


def so3_exp(omega: jax.Array) -> jax.Array:
  """Rotation matrix (3, 3) of the rotation vector ``omega`` (3,), radians (Rodrigues)."""
  theta2 = jnp.dot(omega, omega)
  theta = jnp.sqrt(jnp.maximum(theta2, _EPS))
  small = theta2 < 1e-8
  a = jnp.where(small, 1.0 - theta2 / 6.0, jnp.sin(theta) / theta)
  b = jnp.where(small, 0.5 - theta2 / 24.0, (1.0 - jnp.cos(theta)) / jnp.maximum(theta2, _EPS))
  k = jnp.array([[0.0, -omega[2], omega[1]], [omega[2], 0.0, -omega[0]], [-omega[1], omega[0], 0.0]])
  return jnp.eye(3, dtype=omega.dtype) + a * k + b * (k @ k)


def sample_unit_sphere(key: jax.Array) -> jax.Array:
  """A direction (3,) uniform on the unit sphere."""
  return normalize(jax.random.normal(key, (3,)))


def sample_cone(key: jax.Array, axis: jax.Array, half_angle: float | jax.Array) -> jax.Array:
  """A direction (3,) uniform (by solid angle) on the spherical cap within ``half_angle`` rad of ``axis``.

  Exactly the distribution that rejection sampling from the uniform sphere gives, without a loop:
  cos(angle) ~ U[cos(half_angle), 1] and azimuth ~ U[0, 2 pi).
  """
  k1, k2 = jax.random.split(key)
  cos_t = jax.random.uniform(k1, (), minval=jnp.cos(half_angle), maxval=1.0)
  sin_t = jnp.sqrt(jnp.maximum(1.0 - cos_t**2, 0.0))
  phi = jax.random.uniform(k2, (), maxval=2.0 * jnp.pi)
  axis = normalize(axis)
  t1, t2 = tangent_basis(axis)
  return cos_t * axis + sin_t * (jnp.cos(phi) * t1 + jnp.sin(phi) * t2)


def perpendicular(v: jax.Array, angle: float | jax.Array = 0.0) -> jax.Array:
  """A unit vector (3,) perpendicular to unit ``v``, rotated by ``angle`` rad about ``v`` from `tangent_basis`'s t1."""
  t1, t2 = tangent_basis(v)
  return jnp.cos(angle) * t1 + jnp.sin(angle) * t2


def quat_to_matrix(q: Any, xp: Any = np) -> Any:
  """Rotation matrices (..., 3, 3) of quaternions (..., 4) in (w, x, y, z) order, normalised first.

  ``xp`` is `numpy` (default; float64, for scene building) or `jax.numpy` (jittable).
  """
  q = xp.asarray(q, np.float64) if xp is np else xp.asarray(q)
  q = q / xp.linalg.norm(q, axis=-1, keepdims=True)
  w, x, y, z = xp.moveaxis(q, -1, 0)
  return xp.stack([
      xp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
      xp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
      xp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)
