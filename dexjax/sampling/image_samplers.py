"""Depth-image grasp samplers (spec sections 4.1 and 4.2), jittable with a fixed budget and a validity mask.

Depth images are (H, W) float32 metres, NaN (or <= 0) for invalid pixels; an optional (H, W) bool ``mask``
(the segmask) restricts where grasps may be sampled. Each function samples one image; `vmap` to batch.

* `sample_antipodal_image_grasps` (gqcnn's `AntipodalDepthImageGraspSampler`): Gaussian-smooth the depth,
  downsample, threshold the central-difference gradient magnitude to get edge pixels, take the 2-D edge
  normal n = normalise(d/drow, d/dcol) of the full-resolution smoothed depth (it points to increasing depth,
  i.e. out of a raised object), keep pairs that are antipodal (n_i . n_j < -cos(arctan mu)), closer than the
  jaw span in pixels and inside both friction cones (the angle between n_i and p_i - p_j below arctan mu);
  draw pairs at random, reject those whose deprojected contacts are farther apart than the jaws or whose
  centre is near the border or over an invalid depth, and draw gripper depths in [z_c + min, z_c + max].
  Invalid depths are handled by NaN-aware smoothing (`masked_blur`) instead of gqcnn's prerequisite
  inpainting: they are never contacts, and a centre window touching one is rejected.
  Shapes are static: ``num_edges`` edge pixels are drawn by Gumbel top-k over the edge mask, all their pairs
  are tested, and ``ceil(num_grasps / depth_samples)`` valid pairs are drawn by Gumbel top-k over the pair mask;
  the pair mask already holds the contact-distance and border tests, so the drawn pairs pass them (gqcnn keeps
  drawing until enough pairs pass).
* `sample_suction_image_grasps` (gqcnn's `DepthImageSuctionPointSampler`): camera-frame point cloud, normals
  = cross(d/drow, d/dcol) (towards the camera), approach = -normal, admissible pixels = valid depth and
  normal, inside the mask and away from the border, approach within ``max_approach_angle`` of the optical
  axis; ``num_grasps`` of them drawn uniformly without replacement (Gumbel top-k).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.render.camera import Camera, pixel_rays
from dexjax.sampling.image_grasps import (ImageParallelJawGrasp, ImageSuctionGrasp, angles_from_approach,
                                          camera_point)


@struct.dataclass
class AntipodalImageSampler:
  """Parameters of the antipodal depth-image sampler (Dex-Net 4.0 PJ values, spec section 4.1).

  Attributes:
    friction: friction coefficient mu of the antipodality and friction-cone tests.
    gripper_width: jaw opening, metres (the grasps' width and the largest contact distance).
    depth_grad_threshold: edge threshold on |grad depth| per downsampled pixel, metres.
    min_depth_offset, max_depth_offset: gripper depth ~ U[z_c + min, z_c + max], metres.
    boundary: reject grasp centres closer than this to the image border, pixels (crop-safe: 68 for 96 crops).
    gaussian_sigma: static, pre-smoothing standard deviation, pixels (0 disables).
    downsample: static, integer downsampling factor for edge detection (4 in Dex-Net 4.0).
    num_edges: static, size of the edge-pixel pool whose pairs are tested.
    num_grasps: static, candidate budget N.
    depth_samples: static, depths drawn per pair (3 in Dex-Net 4.0).
    depth_window: static, half-size of the window around the centre whose minimum depth is z_c, pixels.
  """

  friction: float = 1.0
  gripper_width: float = 0.05
  depth_grad_threshold: float = 0.0025
  min_depth_offset: float = 0.015
  max_depth_offset: float = 0.05
  boundary: float = 68.0
  gaussian_sigma: float = struct.field(pytree_node=False, default=1.0)
  downsample: int = struct.field(pytree_node=False, default=4)
  num_edges: int = struct.field(pytree_node=False, default=512)
  num_grasps: int = struct.field(pytree_node=False, default=100)
  depth_samples: int = struct.field(pytree_node=False, default=3)
  depth_window: int = struct.field(pytree_node=False, default=1)


@struct.dataclass
class SuctionImageSampler:
  """Parameters of the suction point sampler (Dex-Net 4.0 values, spec section 4.2).

  Attributes:
    max_approach_angle: largest angle between the approach and the optical axis, radians (30 degrees).
    boundary: reject points closer than this to the image border, pixels.
    gaussian_sigma: static, pre-smoothing of the depth before normals, pixels (0: none, as gqcnn with a mask).
    num_grasps: static, candidate budget N.
  """

  max_approach_angle: float = math.radians(30.0)
  boundary: float = 68.0
  gaussian_sigma: float = struct.field(pytree_node=False, default=0.0)
  num_grasps: int = struct.field(pytree_node=False, default=100)


def gaussian_blur(image: jax.Array, sigma: float) -> jax.Array:
  """(H, W) image smoothed by a separable Gaussian of static ``sigma`` pixels (scipy's gaussian_filter:
  truncate 4, 'reflect' borders); sigma <= 0 returns the image."""
  if sigma <= 0:
    return image
  radius = int(4.0 * sigma + 0.5)
  x = jnp.arange(-radius, radius + 1, dtype=jnp.float32)
  w = jnp.exp(-0.5 * (x / sigma) ** 2)
  w = w / jnp.sum(w)
  return _convolve_axis(_convolve_axis(image, w, 0), w, 1)


def masked_blur(depth: jax.Array, sigma: float) -> jax.Array:
  """(H, W) NaN-aware Gaussian smoothing of a depth image (metres): the normalised convolution
  blur(d * valid) / blur(valid), so invalid (NaN / <= 0) pixels neither pull their neighbours toward 0 nor
  create false depth edges; they are filled with the local average (0 when no valid pixel is within 4 sigma).
  """
  valid = _valid_depth(depth)
  filled = jnp.where(valid, depth, 0.0)
  if sigma <= 0:
    return filled
  weight = gaussian_blur(valid.astype(depth.dtype), sigma)
  return jnp.where(weight > 1e-6, gaussian_blur(filled, sigma) / jnp.maximum(weight, 1e-6), 0.0)


def _convolve_axis(image: jax.Array, weights: jax.Array, axis: int) -> jax.Array:
  radius = (weights.shape[0] - 1) // 2
  pad = [(0, 0), (0, 0)]
  pad[axis] = (radius, radius)
  padded = jnp.pad(image, pad, mode='symmetric')
  n = image.shape[axis]
  return sum(weights[k] * jax.lax.slice_in_dim(padded, k, k + n, axis=axis) for k in range(2 * radius + 1))


def _gradient(image: jax.Array) -> jax.Array:
  """(H, W, 2) (d/drow, d/dcol) by central differences (one-sided at the border, as np.gradient)."""
  return jnp.stack(jnp.gradient(image), axis=-1)


def _valid_depth(depth: jax.Array) -> jax.Array:
  return jnp.isfinite(depth) & (depth > 0)


def _gumbel_top_k(key: jax.Array, eligible: jax.Array, k: int) -> tuple[jax.Array, jax.Array]:
  """k distinct indices drawn uniformly without replacement among the True entries of flat ``eligible``.

  Returns (indices (k,) int32, ok (k,) bool); ok is False where fewer than k entries were eligible.
  """
  scores = jnp.where(eligible, jax.random.gumbel(key, eligible.shape), -jnp.inf)
  top, idx = jax.lax.top_k(scores, k)
  return idx, jnp.isfinite(top)


def _edge_mask(smoothed: jax.Array, params: AntipodalImageSampler) -> jax.Array:
  """(H/f, W/f) bool edges of the downsampled smoothed depth (0, i.e. no valid pixel near, counts as an edge)."""
  f = params.downsample
  h, w = smoothed.shape
  small = smoothed if f == 1 else jax.image.resize(smoothed, (h // f, w // f), 'linear', antialias=False)
  magnitude = jnp.linalg.norm(_gradient(small), axis=-1)
  return (magnitude > params.depth_grad_threshold) | (small == 0)


def _edge_pool(key: jax.Array, smoothed: jax.Array, mask: jax.Array,
               params: AntipodalImageSampler) -> tuple[jax.Array, jax.Array, jax.Array]:
  """``num_edges`` random edge pixels: (positions (K, 2) int32 (row, col) full resolution, unit normals (K, 2)
  (d/drow, d/dcol) of the smoothed depth, ok (K,) bool). Edges without a gradient or outside the mask are
  dropped."""
  f = params.downsample
  edges = _edge_mask(smoothed, params)
  rows, cols = jnp.meshgrid(jnp.arange(edges.shape[0]) * f, jnp.arange(edges.shape[1]) * f, indexing='ij')
  grad = _gradient(smoothed)[rows, cols]
  norm = jnp.linalg.norm(grad, axis=-1)
  eligible = edges & mask[rows, cols] & (norm > 0)
  idx, ok = _gumbel_top_k(key, eligible.reshape(-1), min(params.num_edges, eligible.size))
  pos = jnp.stack([rows.reshape(-1)[idx], cols.reshape(-1)[idx]], axis=-1)
  normals = grad.reshape(-1, 2)[idx] / jnp.maximum(norm.reshape(-1)[idx], 1e-12)[:, None]
  return pos, normals, ok


def _pair_mask(pos: jax.Array, normals: jax.Array, ok: jax.Array, span_px: jax.Array,
               friction: float | jax.Array) -> jax.Array:
  """(K, K) bool: pairs (i, j) antipodal, 0 < distance < span_px, both friction cones hold (gqcnn's tests)."""
  cos_cone = jnp.cos(jnp.arctan(friction))
  diff = (pos[:, None, :] - pos[None, :, :]).astype(jnp.float32)  # p_i - p_j
  dist = jnp.linalg.norm(diff, axis=-1)
  v = diff / jnp.maximum(dist, 1e-12)[..., None]
  ip1 = jnp.sum(normals[:, None, :] * v, axis=-1)
  ip2 = jnp.sum(normals[None, :, :] * -v, axis=-1)
  antipodal = normals @ normals.T < -cos_cone
  return (ok[:, None] & ok[None, :] & antipodal & (dist > 0) & (dist < span_px) & (ip1 > cos_cone)
          & (ip2 > cos_cone))


def _pair_feasible(pos: jax.Array, smoothed: jax.Array, camera: Camera, params: AntipodalImageSampler) -> jax.Array:
  """(K, K) bool: the per-pair tests that need no random draw, applied before pairs are drawn (gqcnn keeps
  drawing pairs until it has enough that pass): deprojected contacts at most the jaw width apart, the centre
  away from the border."""
  h, w = smoothed.shape
  points = jax.vmap(camera_point, in_axes=(None, 0, 0))(camera, pos[:, ::-1].astype(jnp.float32),
                                                       smoothed[pos[:, 0], pos[:, 1]])
  close = jnp.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1) <= params.gripper_width
  center = (pos[:, None, :] + pos[None, :, :]) // 2  # (row, col), as `_pair_grasp`
  b = params.boundary
  inside = ((center[..., 0] >= b) & (center[..., 1] >= b) & (center[..., 0] <= h - b)
            & (center[..., 1] <= w - b))
  return close & inside


def centre_window(image: jax.Array, center: jax.Array, radius: int) -> jax.Array:
  """(2r, 2r) window of ``image`` (H, W) at the integer pixel ``center`` (row, col), shifted to lie inside the
  image: the window whose smallest depth is a grasp's surface depth z_c (``radius`` static)."""
  h, w = image.shape
  start = jnp.clip(center - radius, 0, jnp.array([h - 2 * radius, w - 2 * radius]))
  return jax.lax.dynamic_slice(image, (start[0], start[1]), (2 * radius, 2 * radius))


def _pair_grasp(key: jax.Array, p1: jax.Array, p2: jax.Array, smoothed: jax.Array, valid_px: jax.Array,
                params: AntipodalImageSampler) -> tuple[ImageParallelJawGrasp, jax.Array]:
  """Grasp of one contact pair (row, col) ints and its validity: every raw depth of the centre window valid
  (z_c = their smoothed minimum). The contact-distance and border tests are the pair mask's (`_pair_feasible`)."""
  center = (p1 + p2) // 2  # (row, col)
  axis = (p2 - p1).astype(jnp.float32)
  angle = jnp.arctan2(axis[0], axis[1])
  r = params.depth_window
  z_c = jnp.min(centre_window(smoothed, center, r))
  depth_ok = jnp.all(centre_window(valid_px, center, r)) & (z_c > 0)
  depth = z_c + jax.random.uniform(key, (), minval=params.min_depth_offset, maxval=params.max_depth_offset)
  grasp = ImageParallelJawGrasp(center=center[::-1].astype(jnp.float32), angle=angle, depth=depth,
                                width=jnp.asarray(params.gripper_width, jnp.float32))
  return grasp, depth_ok & valid_px[p1[0], p1[1]] & valid_px[p2[0], p2[1]]


def sample_antipodal_image_grasps(key: jax.Array, depth: jax.Array, camera: Camera,
                                  params: AntipodalImageSampler = AntipodalImageSampler(),
                                  mask: jax.Array | None = None) -> tuple[ImageParallelJawGrasp, jax.Array]:
  """Samples ``params.num_grasps`` antipodal parallel-jaw candidates from one depth image (spec 4.1).

  Args:
    key: PRNG key.
    depth: (H, W) float32 depth, metres; NaN / <= 0 invalid.
    camera: the `Camera` (intrinsics sized H x W).
    params: `AntipodalImageSampler`.
    mask: optional (H, W) bool segmask; edge pixels must lie inside it.

  Returns:
    grasps: `ImageParallelJawGrasp` with leading axis N (centre (N, 2) pixels, width = gripper width).
    valid: (N,) bool.
  """
  k_edge, k_pair, k_depth = jax.random.split(key, 3)
  valid_px = _valid_depth(depth)
  mask = valid_px if mask is None else mask & valid_px
  smoothed = masked_blur(depth, params.gaussian_sigma)
  pos, normals, ok = _edge_pool(k_edge, smoothed, mask, params)
  min_depth = jnp.min(jnp.where(mask, depth, jnp.inf)) + params.min_depth_offset
  span_px = camera.intrinsics.fx * params.gripper_width / min_depth
  pairs = _pair_mask(pos, normals, ok, span_px, params.friction) & _pair_feasible(pos, smoothed, camera, params)
  num_pairs = -(-params.num_grasps // params.depth_samples)
  idx, pair_ok = _gumbel_top_k(k_pair, pairs.reshape(-1), min(num_pairs, pairs.size))
  rep = jnp.repeat(jnp.arange(idx.shape[0]), params.depth_samples)[:params.num_grasps]
  filled = jnp.arange(params.num_grasps) < rep.shape[0]  # False only when the pair pool is tiny
  rep = jnp.pad(rep, (0, params.num_grasps - rep.shape[0]))
  i, j = idx[rep] // pos.shape[0], idx[rep] % pos.shape[0]
  keys = jax.random.split(k_depth, params.num_grasps)
  grasps, ok_grasp = jax.vmap(_pair_grasp, in_axes=(0, 0, 0, None, None, None))(
      keys, pos[i], pos[j], smoothed, valid_px, params)
  return grasps, ok_grasp & pair_ok[rep] & filled


def surface_normals(camera: Camera, depth: jax.Array) -> jax.Array:
  """(H, W, 3) camera-frame unit normals of a depth image (metres), pointing towards the camera.

  n = normalise(cross(dP/drow, dP/dcol)) of the camera-frame point cloud P (central differences, as
  perception's normal cloud); NaN where the depth or a neighbour used by the differences is invalid.
  """
  valid = _valid_depth(depth)
  points = pixel_rays(camera.intrinsics) * jnp.where(valid, depth, jnp.nan)[..., None]
  d_row, d_col = jnp.gradient(points, axis=(0, 1))
  n = jnp.cross(d_row, d_col)
  return n / jnp.linalg.norm(n, axis=-1, keepdims=True)


def _border_mask(shape: tuple[int, int], boundary: float | jax.Array) -> jax.Array:
  """(H, W) bool: pixels at least ``boundary`` from the image border (gqcnn's comparison)."""
  h, w = shape
  rows, cols = jnp.meshgrid(jnp.arange(h), jnp.arange(w), indexing='ij')
  return (rows >= boundary) & (cols >= boundary) & (rows <= h - boundary) & (cols <= w - boundary)


def sample_suction_image_grasps(key: jax.Array, depth: jax.Array, camera: Camera,
                                params: SuctionImageSampler = SuctionImageSampler(),
                                mask: jax.Array | None = None) -> tuple[ImageSuctionGrasp, jax.Array]:
  """Samples ``params.num_grasps`` suction candidates from one depth image (spec 4.2).

  Args:
    key: PRNG key.
    depth: (H, W) float32 depth, metres; NaN / <= 0 invalid.
    camera: the `Camera` (intrinsics sized H x W).
    params: `SuctionImageSampler`.
    mask: optional (H, W) bool segmask (e.g. the object, or everything above the bin floor).

  Returns:
    grasps: `ImageSuctionGrasp` with leading axis N: centre (N, 2) pixels, depth = the pixel's depth,
      approach = -normal encoded as (angle, approach_angle).
    valid: (N,) bool, False where fewer than N pixels were admissible.
  """
  valid_px = _valid_depth(depth)
  smoothed = jnp.where(valid_px, masked_blur(depth, params.gaussian_sigma), jnp.nan)
  approach = -surface_normals(camera, smoothed)
  psi = jnp.arccos(jnp.clip(approach[..., 2], -1.0, 1.0))
  eligible = valid_px & jnp.isfinite(approach[..., 0]) & (psi <= params.max_approach_angle)
  eligible &= _border_mask(depth.shape, params.boundary)
  if mask is not None:
    eligible &= mask
  idx, ok = _gumbel_top_k(key, eligible.reshape(-1), min(params.num_grasps, eligible.size))
  w = depth.shape[1]
  angle, approach_angle = jax.vmap(angles_from_approach)(approach.reshape(-1, 3)[idx])
  grasps = ImageSuctionGrasp(center=jnp.stack([idx % w, idx // w], axis=-1).astype(jnp.float32), angle=angle,
                             depth=depth.reshape(-1)[idx], approach_angle=approach_angle)
  return grasps, ok
