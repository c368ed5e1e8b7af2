"""Grasp-centred, grasp-aligned depth crops: the GQ-CNN input image ("tf image", spec section 1.2).

For crop pixel (row, col) with offsets (x, y) = (col - c_out / 2, row - c_out / 2) / scale, the source is sampled
at ``center + x (cos a, sin a) + y (-sin a, cos a)`` in (u, v) pixels, so the grasp pixel lands at crop index
(c_out // 2, c_out // 2) (below-right of the geometric centre for even sizes, as gqcnn) and the image direction
(cos a, sin a) - the parallel-jaw axis - becomes the crop's +column axis (for suction, the in-plane approach
component becomes the crop's vertical axis). Pixels outside the image read 0 (OpenCV's constant border).
Values are the raw depths, metres: no per-crop re-centring (the FC-GQ-CNN's depth subtraction is part of its
network input normalisation, spec section 1.3).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def crop_coordinates(center: jax.Array, angle: jax.Array, crop_size: int = 96,
                     scale: float = 1.0) -> jax.Array:
  """(c_out, c_out, 2) float32 source (u, v) pixel of every crop pixel, c_out = round(crop_size * scale).

  Args:
    center: (2,) grasp centre (u, v) pixels.
    angle: () in-plane grasp angle, radians.
    crop_size: static crop side in source pixels (96 for Dex-Net 4.0).
    scale: static output pixels per source pixel (1 for Dex-Net 4.0; 1/3 for Dex-Net 2.x's 96 -> 32).
  """
  out = int(round(crop_size * scale))
  offsets = (jnp.arange(out, dtype=jnp.float32) - out // 2) / scale
  y, x = jnp.meshgrid(offsets, offsets, indexing='ij')
  c, s = jnp.cos(angle), jnp.sin(angle)
  return jnp.stack([center[0] + x * c - y * s, center[1] + x * s + y * c], axis=-1)


def grasp_crop(depth: jax.Array, center: jax.Array, angle: jax.Array, crop_size: int = 96,
               scale: float = 1.0, interpolation: str = 'nearest') -> jax.Array:
  """Crop (c_out, c_out) float32 of a depth image (H, W) metres, centred on the grasp and rotated by ``angle``.

  ``interpolation`` (static) is 'nearest' (gqcnn's warp, the default) or 'bilinear'; samples outside the image
  are 0. ``crop_size`` and ``scale`` are static (see `crop_coordinates`). Jit with static_argnames
  ('crop_size', 'scale', 'interpolation'); `vmap` over grasps.
  """
  uv = crop_coordinates(center, angle, crop_size, scale)
  if interpolation == 'nearest':
    return _sample_nearest(depth, uv)
  if interpolation == 'bilinear':
    return sample_bilinear(depth, uv)
  raise ValueError(f"interpolation must be 'nearest' or 'bilinear', got {interpolation!r}")


def model_crop(depth: jax.Array, center: jax.Array, angle: jax.Array, window: int, size: int) -> jax.Array:
  """(size, size) GQ-CNN input crop of a ``window``-pixel grasp window of ``depth`` (H, W) metres, NaN read as 0:
  nearest pixels when ``window == size`` (gqcnn's warp), bilinear resampling otherwise (e.g. Dex-Net 2.0's
  96 -> 32). ``window`` and ``size`` are static. The one crop rule of training and of the policies."""
  scale, interpolation = (1.0, 'nearest') if window == size else (size / window, 'bilinear')
  return grasp_crop(jnp.nan_to_num(depth, nan=0.0), center, angle, window, scale, interpolation)


def _read(image: jax.Array, col: jax.Array, row: jax.Array) -> jax.Array:
  """Pixels at integer (col, row) arrays, 0 outside the image."""
  h, w = image.shape
  inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
  return jnp.where(inside, image[jnp.clip(row, 0, h - 1), jnp.clip(col, 0, w - 1)], 0.0)


def _sample_nearest(image: jax.Array, uv: jax.Array) -> jax.Array:
  col = jnp.floor(uv[..., 0] + 0.5).astype(jnp.int32)
  row = jnp.floor(uv[..., 1] + 0.5).astype(jnp.int32)
  return _read(image, col, row)


def sample_bilinear(image: jax.Array, uv: jax.Array) -> jax.Array:
  """``image`` (H, W) read at continuous (u, v) pixels ``uv`` (..., 2) by bilinear interpolation (pixel centres
  at integer coordinates, 0 outside the image): differentiable in ``uv`` (piecewise linear) and in the image."""
  u0, v0 = jnp.floor(uv[..., 0]), jnp.floor(uv[..., 1])
  fu, fv = uv[..., 0] - u0, uv[..., 1] - v0
  c0, r0 = u0.astype(jnp.int32), v0.astype(jnp.int32)
  top = (1 - fu) * _read(image, c0, r0) + fu * _read(image, c0 + 1, r0)
  bottom = (1 - fu) * _read(image, c0, r0 + 1) + fu * _read(image, c0 + 1, r0 + 1)
  return (1 - fv) * top + fv * bottom
