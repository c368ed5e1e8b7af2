"""Observation pre-processing for real depth images: inpainting, segmentation and the checks a user needs.

Real sensors leave holes (0 / NaN) and users pass images in the wrong units or size (spec section 1.5 and
section 6 items 3-4). `prepare_observation` turns a depth image (metres) and a camera into an `Observation`:

* holes are recorded and filled by `inpaint_depth`, a jittable multigrid membrane fill of the inverse depth
  (disparity, 1 / z: a plane in space is linear in pixels in 1 / z, not in z, so any plane is reproduced,
  whatever the camera's tilt). Valid disparities are averaged down a 2 x 2 pyramid (push); from the coarsest
  level up, each level starts from the bilinear upsampling of the one below (pull) and is relaxed by red-black
  Gauss-Seidel sweeps of u = w d + (1 - w) mean(4 neighbours), w being the valid fraction of the cell and d its
  valid mean. At full resolution w is 1 on valid pixels (kept bit for bit) and 0 in holes, so holes converge
  to the solution of Laplace's equation with the valid pixels as boundary values: smooth, within the range of
  the valid depths, holes of any size filled; the coarse levels make large holes converge in a fixed number of
  sweeps (static shapes). gqcnn calls OpenCV's inpainting at half resolution instead; we have no OpenCV. Holes
  touching the image border are extended flat (zero normal gradient), not extrapolated;
* the mask (where grasps may be centred) is the user's segmask, else what is nearer than a background (empty
  bin) depth image by more than ``threshold`` (`background_mask`), else what lies more than ``threshold``
  above the dominant plane (`plane_mask`: RANSAC on the camera-frame point cloud, fixed seed, then a total
  least-squares refit on the inliers; fitted in the camera frame, so it works for tilted cameras without a
  pose); it is ANDed with the valid pixels, so no grasp is centred on a hole.

Files are read by `dexjax.policy.depth_io` (`load_depth`, `load_segmask`), which also checks units.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage

from dexjax.policy.depth_io import check_depth_image
from dexjax.policy.observation import Observation
from dexjax.render.camera import Camera, Intrinsics

SEGMENTATIONS = ('auto', 'plane', 'background', 'none')
_COARSEST = 8  # the pyramid's coarsest level has at most this many pixels along its longer side
_COARSE_SWEEPS = 128  # relaxation sweeps at the coarsest level (cheap: at most 8 x 8 pixels)


def _valid(depth: jax.Array) -> jax.Array:
  """(H, W) bool, finite depths > 0."""
  return jnp.isfinite(depth) & (depth > 0)


def _num_levels(height: int, width: int) -> int:
  """Number of 2 x 2 downsamplings until the longer side is at most `_COARSEST` pixels."""
  return max(0, math.ceil(math.log2(max(height, width) / _COARSEST)))


def _downsample(values: jax.Array, weights: jax.Array) -> tuple[jax.Array, jax.Array]:
  """(values, weights) (H, W) -> 2 x 2 cell means (H/2, W/2): the weighted mean value (0 where no weight) and
  the mean weight (the valid fraction of the cell)."""
  h, w = values.shape
  cells = lambda x: x.reshape(h // 2, 2, w // 2, 2).sum(axis=(1, 3))
  total = cells(weights)
  mean = cells(values * weights) / jnp.where(total > 0, total, 1.0)
  return jnp.where(total > 0, mean, 0.0), total / 4.0


def _upsample_axis(x: jax.Array, axis: int) -> jax.Array:
  """Doubles ``axis`` by bilinear interpolation between cell centres (linear extrapolation at the ends, so a
  linear ramp is reproduced exactly)."""
  n = x.shape[axis]
  end = lambda i: jax.lax.slice_in_dim(x, i, i + 1, axis=axis)
  first, last = (end(0), end(n - 1)) if n == 1 else (2.0 * end(0) - end(1), 2.0 * end(n - 1) - end(n - 2))
  padded = jnp.concatenate([first, x, last], axis=axis)
  before = jax.lax.slice_in_dim(padded, 0, n, axis=axis)
  after = jax.lax.slice_in_dim(padded, 2, n + 2, axis=axis)
  pairs = jnp.stack([0.75 * x + 0.25 * before, 0.75 * x + 0.25 * after], axis=axis + 1)
  return pairs.reshape(x.shape[:axis] + (2 * n,) + x.shape[axis + 1:])


def _neighbour_mean(u: jax.Array) -> jax.Array:
  """(H, W) mean of the 4 neighbours, replicating the border (zero normal gradient)."""
  p = jnp.pad(u, 1, mode='edge')
  return 0.25 * (p[:-2, 1:-1] + p[2:, 1:-1] + p[1:-1, :-2] + p[1:-1, 2:])


def _relax(u: jax.Array, values: jax.Array, weights: jax.Array, sweeps: int) -> jax.Array:
  """``sweeps`` red-black Gauss-Seidel sweeps of u = w d + (1 - w) mean(neighbours), all (H, W)."""
  row, col = (jax.lax.broadcasted_iota(jnp.int32, u.shape, axis) for axis in (0, 1))
  red = (row + col) % 2 == 0
  data, free = weights * values, 1.0 - weights

  def sweep(_, u):
    u = jnp.where(red, data + free * _neighbour_mean(u), u)
    return jnp.where(red, u, data + free * _neighbour_mean(u))

  return jax.lax.fori_loop(0, sweeps, sweep, u)


@functools.partial(jax.jit, static_argnames='sweeps')
def inpaint_depth(depth: jax.Array, sweeps: int = 32) -> jax.Array:
  """Fills the invalid pixels (NaN, inf, <= 0) of a depth image from the valid ones; jitted (``sweeps`` static;
  compiling takes seconds per image size on a CPU, running ~40 ms for 640 x 480).

  Valid pixels are returned unchanged (bit for bit); holes get a smooth membrane (harmonic) interpolation of
  the surrounding inverse depths, which reproduces a plane seen by any camera (to ~0.1 mm over a 40 x 40 hole
  with the default sweeps) and stays within the range of the valid depths (see the module docstring).

  Args:
    depth: (H, W) float depth image, metres.
    sweeps: static, relaxation sweeps per pyramid level (more: closer to the exact membrane).
  Returns:
    (H, W) float32 metres, finite everywhere, or NaN everywhere if no pixel is valid (the caller's error).
  """
  depth = jnp.asarray(depth, jnp.float32)
  h, w = depth.shape
  levels = _num_levels(h, w)
  size = 2 ** levels
  pad = ((0, -(-h // size) * size - h), (0, -(-w // size) * size - w))
  valid = _valid(depth)
  disparity = jnp.where(valid, 1.0 / jnp.where(valid, depth, 1.0), 0.0)
  pyramid = [(jnp.pad(disparity, pad), jnp.pad(valid.astype(jnp.float32), pad))]
  for _ in range(levels):
    pyramid.append(_downsample(*pyramid[-1]))
  values, weights = pyramid[-1]
  total = jnp.sum(weights)
  mean = jnp.where(total > 0, jnp.sum(values * weights) / jnp.where(total > 0, total, 1.0), jnp.nan)
  low, high = jnp.min(jnp.where(valid, disparity, jnp.inf)), jnp.max(disparity)  # the range of valid disparities
  u = _relax(jnp.where(weights > 0, values, mean), values, weights, _COARSE_SWEEPS)
  for values, weights in reversed(pyramid[:-1]):
    coarse = jnp.clip(_upsample_axis(_upsample_axis(u, 0), 1), low, high)  # no overshoot at extrapolated ends
    u = _relax(weights * values + (1.0 - weights) * coarse, values, weights, sweeps)
  return jnp.where(valid, depth, 1.0 / u[:h, :w])


def background_mask(depth: jax.Array, background: jax.Array, threshold: float = 0.005) -> jax.Array:
  """(H, W) bool: pixels nearer to the camera than the ``background`` (empty bin) image by more than
  ``threshold`` metres; pixels invalid (NaN, inf, <= 0) in either image are False. Jittable.

  Args:
    depth, background: (H, W) depth images of the same camera, metres.
    threshold: metres.
  """
  depth, background = jnp.asarray(depth, jnp.float32), jnp.asarray(background, jnp.float32)
  if depth.shape != background.shape:
    raise ValueError(f'background: the background depth image is {background.shape[0]}x{background.shape[1]} '
                     f'(H x W) but the depth image is {depth.shape[0]}x{depth.shape[1]}; expected the same camera')
  return _valid(depth) & _valid(background) & (background - depth > threshold)


def _camera_points(depth: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
  """(H, W, 3) float64 camera-frame points of a depth image (metres); invalid pixels give NaN."""
  k = [float(np.asarray(getattr(intrinsics, f))) for f in ('fx', 'fy', 'cx', 'cy')]
  v, u = np.mgrid[0:depth.shape[0], 0:depth.shape[1]].astype(np.float64)
  z = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float64)
  return np.stack([(u - k[2]) / k[0] * z, (v - k[3]) / k[1] * z, z], axis=-1)


def _refit(points: np.ndarray) -> tuple[np.ndarray, float]:
  """Total least-squares plane (unit normal (3,), offset) of points (N, 3): n . p + offset = 0."""
  centre = points.mean(axis=0)
  centred = points - centre
  normal = np.linalg.eigh(centred.T @ centred)[1][:, 0]  # the direction of least scatter
  return normal, -float(normal @ centre)


def fit_plane(points: np.ndarray, threshold: float = 0.005, iterations: int = 256, sample: int = 4096,
              seed: int = 0) -> tuple[np.ndarray, float, float]:
  """Dominant plane of a point cloud: RANSAC (``iterations`` random triples, inliers within ``threshold``
  among ``sample`` random points, fixed ``seed``), then two total least-squares refits on all inliers.

  Args:
    points: (N, 3) finite camera-frame points, metres (N >= 3).
  Returns:
    (unit normal (3,), offset metres, inlier fraction): n . p + offset is the signed distance to the plane,
    positive on the camera's side (the camera centre, the origin, has distance offset > 0).
  """
  rng = np.random.default_rng(seed)
  subset = points[rng.choice(len(points), min(sample, len(points)), replace=False)]
  triples = subset[rng.integers(0, len(subset), (iterations, 3))]
  normals = np.cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])
  length = np.linalg.norm(normals, axis=-1, keepdims=True)
  normals = normals / np.where(length > 1e-12, length, 1.0)
  offsets = -np.sum(normals * triples[:, 0], axis=-1)
  scores = np.sum(np.abs(subset @ normals.T + offsets) < threshold, axis=0) * (length[:, 0] > 1e-12)
  normal, offset = normals[np.argmax(scores)], offsets[np.argmax(scores)]
  for _ in range(2):
    inliers = points[np.abs(points @ normal + offset) < threshold]
    if len(inliers) >= 3:
      normal, offset = _refit(inliers)
  sign = 1.0 if offset >= 0 else -1.0
  fraction = float(np.mean(np.abs(points @ normal + offset) < threshold))
  return sign * normal, sign * offset, fraction


def _plane_mask(depth: np.ndarray, intrinsics: Intrinsics, threshold: float,
                **fit: Any) -> tuple[np.ndarray, dict[str, Any]]:
  """`plane_mask` and the plane: {'normal': [3 floats], 'offset': metres, 'inlier_fraction': float}."""
  points = _camera_points(np.asarray(depth), intrinsics)
  valid = np.isfinite(points[..., 2])
  if valid.sum() < 3:
    raise ValueError(f'depth: {valid.sum()} valid pixels; fitting the floor plane needs at least 3')
  normal, offset, fraction = fit_plane(points[valid], threshold, **fit)
  height = np.where(valid, np.nan_to_num(points) @ normal + offset, 0.0)
  above, containers = _drop_containers(valid & (height > threshold), valid & (np.abs(height) <= threshold))
  plane = {'normal': (normal + 0.0).tolist(), 'offset': offset, 'inlier_fraction': fraction,  # + 0.0: no -0.0
           'containers_removed': containers}
  return above, plane


def _surrounded(component: np.ndarray) -> np.ndarray:
  """(H, W) bool: pixels with a pixel of ``component`` to their left, right, top or bottom in >= 3 of the 4."""
  hits = [np.maximum.accumulate(component, axis=axis) for axis in (0, 1)]
  hits += [np.flip(np.maximum.accumulate(np.flip(component, axis), axis=axis), axis) for axis in (0, 1)]
  return np.sum(hits, axis=0) >= 3


def _drop_containers(above: np.ndarray, floor: np.ndarray, min_size: float = 0.01) -> tuple[np.ndarray, int]:
  """``above`` without its "containers" (bin walls): connected components (of at least ``min_size`` of the
  image) whose outline, holes filled, encloses more ``floor`` pixels than their own size (a rim around a
  floor; an object shows no floor inside, a tape roll less than its own area). A pixel is enclosed when the
  component lies in at least three of the four image directions from it (`_surrounded`), so a rim that the image
  border cuts on one side still encloses its floor. Returns (mask, count)."""
  labels, count = ndimage.label(above)
  if count == 0 or not floor.any():
    return above, 0
  sizes = np.bincount(labels.ravel(), minlength=count + 1)
  removed = 0
  for label in np.flatnonzero(sizes >= min_size * above.size):
    if label == 0:
      continue
    component = labels == label
    if np.count_nonzero(_surrounded(component) & floor) > sizes[label]:
      above = above & ~component
      removed += 1
  return above, removed


def plane_mask(depth: np.ndarray, camera_or_intrinsics: Camera | Intrinsics, threshold: float = 0.005,
               **fit: Any) -> np.ndarray:
  """(H, W) bool: pixels more than ``threshold`` metres above the dominant plane (bin floor or table), on the
  camera's side. Invalid pixels are False. NumPy (it runs once per image).

  The plane is fitted in the camera frame, so a tilted camera needs no pose: the height is measured along the
  plane's normal, whatever the view direction. The dominant plane is the one with the most valid pixels: if an
  object's top face covers more of the image than the visible floor, that face is taken. Bin walls rise above the
  floor too: a component of the mask whose outline encloses a floor larger than itself (a container's rim) is dropped, so
  the mask keeps the objects inside a bin; an object leaning on the wall is dropped with it (pass a segmask or an
  empty-bin image, ``background``, to keep it).

  Args:
    depth: (H, W) depth image, metres (holes allowed).
    camera_or_intrinsics: a `Camera` or its `Intrinsics` (sized H x W).
    threshold: metres, also the RANSAC inlier distance.
    **fit: ``iterations``, ``sample``, ``seed`` of `fit_plane`.
  Raises:
    ValueError: fewer than 3 valid pixels.
  """
  intrinsics = getattr(camera_or_intrinsics, 'intrinsics', camera_or_intrinsics)
  return _plane_mask(depth, intrinsics, threshold, **fit)[0]


def _check_shape(name: str, shape: tuple[int, ...], expected: tuple[int, int], fix: str) -> None:
  """ValueError naming ``name`` and both (H, W) shapes (pixels) unless ``shape == expected``."""
  if tuple(shape) != tuple(expected):
    raise ValueError(f'{name}: the image is {"x".join(map(str, shape))} (H x W) but {fix}')


def _check_inputs(depth: np.ndarray, intrinsics: Intrinsics, mask: np.ndarray | None,
                  background: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
  """(depth (H, W) float32 metres, mask (H, W) bool or None, background (H, W) float32 or None), checked."""
  h, w = intrinsics.height, intrinsics.width
  depth = check_depth_image(depth, 'depth')
  _check_shape('depth', depth.shape, (h, w), f'the intrinsics are for {h}x{w} (height x width); resize the image '
               f'to {h}x{w} or rescale the intrinsics (fx, cx by the width ratio, fy, cy by the height ratio) and '
               f'set width={depth.shape[1]}, height={depth.shape[0]}')
  if background is not None:
    background = check_depth_image(background, 'background')
    _check_shape('background', background.shape, (h, w), f'the depth image is {h}x{w}; expected an empty-bin '
                 'image from the same camera')
  if mask is not None:
    mask = np.asarray(mask)
    mask = np.any(mask != 0, axis=-1) if mask.ndim == 3 else mask != 0  # (H, W, 1) or a colour mask
    _check_shape('mask', mask.shape, (h, w), f'the depth image is {h}x{w}; expected a pixel-aligned segmask')
  return depth, mask, background


def _segment(depth: np.ndarray, camera: Camera, mask: np.ndarray | None, background: np.ndarray | None,
             segment: str, threshold: float) -> tuple[np.ndarray, dict[str, Any]]:
  """(mask (H, W) bool before the valid-pixel AND, info) by the rules of `prepare_observation`."""
  if segment not in SEGMENTATIONS:
    raise ValueError(f'segment: expected one of {", ".join(SEGMENTATIONS)}, got {segment!r}')
  if mask is not None:
    return mask, {'segmentation': 'segmask'}
  if segment == 'none':
    return np.ones(depth.shape, bool), {'segmentation': 'none'}
  if segment == 'background' and background is None:
    raise ValueError("segment: 'background' needs a background depth image (an empty-bin image, --background)")
  if background is not None and segment in ('auto', 'background'):
    return np.asarray(background_mask(depth, background, threshold)), {'segmentation': 'background'}
  segmask, plane = _plane_mask(depth, camera.intrinsics, threshold)
  return segmask, {'segmentation': 'plane', 'plane': plane}


_NO_OBJECT = {
    'segmask': 'the segmask covers no valid depth pixel; check that it is aligned with the depth image',
    'none': 'the depth image has no valid pixel',
    'background': 'nothing is nearer than the background image by more than {t:g} m; check that the background '
                  'is an empty-bin image from the same camera, or lower the threshold',
    'plane': 'nothing rises more than {t:g} m above the dominant plane; check the depth units (metres) and the '
             'scene, lower the threshold, or pass a segmask',
}


def prepare_observation(depth: np.ndarray, camera: Camera | Intrinsics, mask: np.ndarray | None = None, *,
                        background: np.ndarray | None = None, segment: str = 'auto', threshold: float = 0.005,
                        boundary: int = 0) -> tuple[Observation, dict[str, Any]]:
  """An `Observation` of a real depth image: holes inpainted, mask = segmentation AND valid pixels.

  Args:
    depth: (H, W) or (H, W, 1) depth image, metres; 0 / NaN / inf / negative pixels are holes.
    camera: a `Camera`, or `Intrinsics` (the observation's camera then has the identity pose: world = camera
      frame); sized H x W.
    mask: (H, W) or (H, W, 1) user segmask (non-zero = object); if given it wins over ``segment``.
    background: (H, W) or (H, W, 1) empty-bin depth image of the same camera, metres.
    segment: without a mask: 'auto' (background subtraction if ``background`` is given, else the plane fit),
      'plane', 'background' or 'none' (every valid pixel).
    threshold: metres above the plane / nearer than the background that count as object.
    boundary: pixels; ``info['interior_mask_pixels']`` counts the mask pixels at least this far from the image
      border (a policy whose crops need a margin can warn early; nothing is refused here).
  Returns:
    (observation, info): info has 'segmentation' ('segmask', 'background', 'plane' or 'none'),
    'invalid_pixels', 'invalid_fraction', 'mask_pixels', 'interior_mask_pixels' and, for the plane,
    'plane' (see `plane_mask`).
  Raises:
    ValueError: depth not (H, W) / (H, W, 1) or not sized as the intrinsics (both named, with the fix), no
      valid pixel, implausible units, mask or background of another size, or no object pixel left.
  """
  intrinsics = getattr(camera, 'intrinsics', camera)
  depth, mask, background = _check_inputs(depth, intrinsics, mask, background)
  if not isinstance(camera, Camera):
    camera = Camera(intrinsics=intrinsics, rotation=jnp.eye(3, dtype=jnp.float32), position=jnp.zeros(3))
  valid = np.isfinite(depth) & (depth > 0)
  segmask, info = _segment(depth, camera, mask, background, segment, threshold)
  segmask = segmask & valid
  if not segmask.any():
    raise ValueError(f'no object pixels: {_NO_OBJECT[info["segmentation"]].format(t=threshold)}')
  b = max(int(boundary), 0)
  interior = segmask[b:depth.shape[0] - b, b:depth.shape[1] - b]
  info.update(invalid_pixels=int((~valid).sum()), invalid_fraction=float((~valid).mean()),
              mask_pixels=int(segmask.sum()), interior_mask_pixels=int(interior.sum()))
  return Observation(depth=inpaint_depth(depth), mask=jnp.asarray(segmask), camera=camera), info


__all__ = ['SEGMENTATIONS', 'background_mask', 'fit_plane', 'inpaint_depth', 'plane_mask', 'prepare_observation']
