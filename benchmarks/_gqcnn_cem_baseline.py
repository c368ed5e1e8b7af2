"""The original's way, for the plan-latency benchmark: gqcnn's ambidextrous Cross-Entropy Method in NumPy, SciPy and
scikit-learn, one grasp, one object, one step at a time, scoring with the same Flax GQ-CNN as dexjax.

Follows gqcnn's classes (spec sections 4.1-4.3, 4.5) with dexjax's parameter values (the same sampler objects):

* `antipodal_grasps` (``AntipodalDepthImageGraspSampler._sample_antipodal_grasps``): Gaussian smoothing (sigma 1),
  bilinear downsampling x1/4 (pixel centres, no anti-aliasing, as ``DepthImage.resize``), ``threshold_gradients``
  (np.gradient magnitude > 0.0025 m), the zero pixels scaled back x4 as edges, kept inside the segmask (a
  full-resolution retry below 25 edges), normals (d/drow, d/dcol) of the smoothed full-resolution depth,
  ``pdist`` distances and the antipodality, span and friction-cone tests on all pairs, up to 4,000 random
  pairs tried one at a time in Python (3-D contact distance, border, then 3 depths on the 2 x 2 window minimum).
* `suction_points` (``DepthImageSuctionPointSampler``): the depth masked by the segmask (gqcnn's quirk: no
  smoothing with a segmask), point cloud, normal cloud, up to 10,000 mask pixels tried one at a time in Python
  (border, depth jitter of std sigma^2, approach within 30 degrees).
* `cem` (``CrossEntropyRobustGraspingPolicy._action``): per iteration the set is scored, sorted, the elite
  (ceil(gamma |G|)) z-scored (std 0 -> 1e-6) and fitted by ``sklearn.mixture.GaussianMixture(k, full
  covariance, uniform weights_init, reg_covar)`` (scikit-learn's other defaults: k-means init, tol 1e-3,
  100 EM iterations), then batches of c draws are decoded (``Grasp2D.from_feature_vec``; suction re-reads
  depth and the normal cloud at the truncated pixel) and kept if on the segmask (and, as dexjax, away from the
  border and within the approach cone) for at most 100 batches. The set is cut to c grasps (gqcnn keeps whole
  batches, up to 2c - 1) so that both implementations score the same number of grasps. The last set's argmax
  is the gripper's plan; `plan` takes the grasp of highest probability over both grippers
  (``GreedyCompositeGraspingPolicy``, as intended).
* Scoring (``GQCnnQualityFunction``): one crop per grasp (gqcnn: an OpenCV ``warpAffine`` of the whole image
  per grasp; here a NumPy gather of the crop's pixels only, nearest or, for 96 -> 32 windows, bilinear, which
  is dexjax's crop rule and cheaper than gqcnn's), then the network once per set: the same Flax model jitted
  once per padded batch size (n or c), as a TF session runs its fixed-size graph.

Deliberately generous to the baseline: per-pixel Python loops of gqcnn (edge filtering, edge normals, decoding
of mixture draws) are vectorised; only the per-candidate and per-grasp loops are kept. `plan` runs with the
BLAS and OpenMP pools limited to one thread (threadpoolctl; the network runs in XLA's own pool, unaffected):
every matrix here is tiny, and on this shared 2-core machine OpenBLAS's two-thread pool made each small
solve take milliseconds (a scikit-learn fit of 13-63 rows took 140-460 ms instead of 3-10 ms).
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings

import jax.numpy as jnp
import numpy as np
import scipy.ndimage as snd
import scipy.spatial.distance as ssd
from sklearn.exceptions import ConvergenceWarning
from sklearn.mixture import GaussianMixture
from threadpoolctl import threadpool_limits

from dexjax.models.saved import predict

MAX_PAIRS = 4000           # gqcnn's max_rejection_samples
MIN_EDGE_PIXELS = 25       # gqcnn's min_num_edge_pixels
MAX_SUCTION_TRIES = 10000  # gqcnn's max_num_samples
MAX_RESAMPLES = 100        # gqcnn's max_resamples_per_iteration
DEPTH_JITTER = 0.0025 ** 2  # gqcnn passes sigma^2 as the normal's scale
STAGES = ('sampling', 'crops', 'network', 'gmm')


@dataclasses.dataclass
class Scene:
  """depth (H, W) float32 metres (valid everywhere), segmask (H, W) bool, intrinsics (fx, fy, cx, cy)."""
  depth: np.ndarray
  segmask: np.ndarray
  fx: float
  fy: float
  cx: float
  cy: float

  def deproject(self, depth: np.ndarray) -> np.ndarray:
    """(H, W, 3) camera-frame point cloud of a depth image."""
    rows, cols = np.indices(depth.shape)
    return np.stack([(cols - self.cx) / self.fx * depth, (rows - self.cy) / self.fy * depth, depth], axis=-1)


def _downsample(image: np.ndarray, factor: int) -> np.ndarray:
  rows = (np.arange(image.shape[0] // factor) + 0.5) * factor - 0.5
  cols = (np.arange(image.shape[1] // factor) + 0.5) * factor - 0.5
  return snd.map_coordinates(image, np.meshgrid(rows, cols, indexing='ij'), order=1, mode='nearest')


def _edge_pixels(smoothed: np.ndarray, factor: int, threshold: float) -> np.ndarray:
  small = _downsample(smoothed, factor) if factor > 1 else smoothed.copy()
  g_row, g_col = np.gradient(small)
  small[np.hypot(g_row, g_col) > threshold] = 0.0
  return (factor * np.argwhere(small == 0)).astype(np.int16)


def antipodal_grasps(rng: np.random.Generator, scene: Scene, n: int, s) -> dict:
  """Up to n parallel-jaw grasps (spec 4.1); ``s`` is dexjax's `AntipodalImageSampler` (its values)."""
  smoothed = snd.gaussian_filter(scene.depth, s.gaussian_sigma)
  edges = _edge_pixels(smoothed, s.downsample, s.depth_grad_threshold)
  edges = edges[scene.segmask[edges[:, 0], edges[:, 1]]]
  if len(edges) < MIN_EDGE_PIXELS:
    edges = _edge_pixels(smoothed, 1, s.depth_grad_threshold)
    edges = edges[scene.segmask[edges[:, 0], edges[:, 1]]]
  masked = np.where(scene.segmask, smoothed, 0.0)
  cloud = scene.deproject(masked)
  min_depth = masked[masked > 0].min() + s.min_depth_offset
  span_px = scene.fx * s.gripper_width / min_depth
  g_row, g_col = np.gradient(smoothed)
  normals = np.stack([g_row, g_col], axis=-1)[edges[:, 0], edges[:, 1]]
  norm = np.linalg.norm(normals, axis=1)
  normals = np.where(norm[:, None] > 0, normals / np.maximum(norm, 1e-30)[:, None], [1.0, 0.0])
  dists = ssd.squareform(ssd.pdist(edges))
  cos_cone = np.cos(np.arctan(s.friction))
  i, j = np.nonzero((normals @ normals.T < -cos_cone) & (dists < span_px) & (dists > 0))
  v = (edges[i] - edges[j]).astype(np.float64)
  v /= np.linalg.norm(v, axis=1)[:, None]
  beta1 = np.arccos(np.clip(np.sum(normals[i] * v, axis=1), -1, 1))
  beta2 = np.arccos(np.clip(np.sum(normals[j] * -v, axis=1), -1, 1))
  pairs = np.flatnonzero((beta1 < np.arctan(s.friction)) & (beta2 < np.arctan(s.friction)))
  h, w = scene.depth.shape
  out = []
  for p in rng.choice(pairs, size=min(MAX_PAIRS, len(pairs)), replace=False):
    if len(out) >= n:
      break
    p1, p2 = edges[i[p]].astype(int), edges[j[p]].astype(int)
    center = (p1 + p2) // 2
    axis = p2 - p1
    theta = np.arctan2(axis[0], axis[1]) if axis[1] != 0 else np.pi / 2
    if np.linalg.norm(cloud[p2[0], p2[1]] - cloud[p1[0], p1[1]]) > s.gripper_width:
      continue
    b = s.boundary
    if center[0] < b or center[1] < b or center[0] > h - b or center[1] > w - b:
      continue
    for _ in range(s.depth_samples):
      z_c = np.min(smoothed[center[0] - 1:center[0] + 1, center[1] - 1:center[1] + 1])
      if z_c == 0 or np.isnan(z_c):
        continue
      depth = z_c + s.min_depth_offset + (s.max_depth_offset - s.min_depth_offset) * rng.random()
      out.append((center[1], center[0], theta, depth))
  g = np.array(out[:n], np.float64).reshape(-1, 4)
  return {'center': g[:, :2], 'angle': g[:, 2], 'depth': g[:, 3]}


def normal_cloud(scene: Scene, depth: np.ndarray) -> np.ndarray:
  """(H, W, 3) unit normals towards the camera (autolab_core's ``normal_cloud_im``; 0 on zero depth)."""
  d_row, d_col = np.gradient(scene.deproject(depth), axis=(0, 1))
  n = np.cross(d_row, d_col)
  norm = np.linalg.norm(n, axis=-1, keepdims=True)
  n = np.where(norm > 0, n / np.maximum(norm, 1e-30), [0.0, 0.0, -1.0])
  n[depth == 0] = 0.0
  return n


def _suction_angles(approach: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
  """(crop angle, approach angle) of approaches (N, 3): r = a x z = (a_y, -a_x) (``SuctionPoint2D.angle``)."""
  rx, ry = approach[:, 1], -approach[:, 0]
  angle = np.where(np.hypot(rx, ry) > 0, np.arctan2(ry, rx), 0.0)
  return angle, np.arccos(np.clip(approach[:, 2], -1.0, 1.0))


def suction_points(rng: np.random.Generator, scene: Scene, n: int, s) -> dict:
  """Up to n suction grasps (spec 4.2); ``s`` is dexjax's `SuctionImageSampler`."""
  masked = np.where(scene.segmask, scene.depth, 0.0)
  normals = normal_cloud(scene, masked)
  nonzero = np.argwhere(masked > 0)
  h, w = masked.shape
  out = []
  for k in rng.choice(len(nonzero), size=min(MAX_SUCTION_TRIES, len(nonzero)), replace=False):
    if len(out) >= n:
      break
    row, col = nonzero[k]
    if col < s.boundary or row < s.boundary or col > w - s.boundary or row > h - s.boundary:
      continue
    depth = masked[row, col] + rng.normal(0.0, DEPTH_JITTER)
    axis = -normals[row, col]
    if np.arccos(max(min(axis[2], 1.0), -1.0)) < s.max_approach_angle:
      out.append((col, row, depth, *axis))
  g = np.array(out, np.float64).reshape(-1, 6)
  angle, psi = _suction_angles(g[:, 3:])
  return {'center': g[:, :2], 'angle': angle, 'depth': g[:, 2], 'approach_angle': psi}


class Scorer:
  """``GQCnnQualityFunction``: per-grasp crops, then the Flax model jitted per padded batch size."""

  def __init__(self, model, gripper: str, buckets: tuple[int, ...]):
    self.model, self.gripper, self.buckets = model, gripper, tuple(sorted(buckets))
    window, size = model.crop_window, model.config.crop_size
    self.bilinear = window != size
    offsets = (np.arange(size) - size // 2) * (window / size)
    self.y, self.x = np.meshgrid(offsets, offsets, indexing='ij')

  def crop(self, depth: np.ndarray, center: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    u = center[0] + self.x * c - self.y * s
    v = center[1] + self.x * s + self.y * c
    if not self.bilinear:
      return _read(depth, np.floor(u + 0.5).astype(int), np.floor(v + 0.5).astype(int))
    u0, v0 = np.floor(u), np.floor(v)
    fu, fv = u - u0, v - v0
    c0, r0 = u0.astype(int), v0.astype(int)
    top = (1 - fu) * _read(depth, c0, r0) + fu * _read(depth, c0 + 1, r0)
    bottom = (1 - fu) * _read(depth, c0, r0 + 1) + fu * _read(depth, c0 + 1, r0 + 1)
    return (1 - fv) * top + fv * bottom

  def poses(self, grasps: dict) -> np.ndarray:
    if self.gripper == 'suction':
      return np.stack([grasps['depth'], grasps['approach_angle']], axis=-1)
    return grasps['depth'][:, None]

  def __call__(self, depth: np.ndarray, grasps: dict, clock: dict) -> np.ndarray:
    t = time.perf_counter()
    crops = np.stack([self.crop(depth, c, a) for c, a in zip(grasps['center'], grasps['angle'])])
    t = _tick(clock, 'crops', t)
    size = next(b for b in self.buckets if b >= len(crops))
    pad = lambda x: np.pad(x, [(0, size - len(x))] + [(0, 0)] * (x.ndim - 1)).astype(np.float32)
    q = np.asarray(predict(self.model, jnp.asarray(pad(crops)[..., None]), jnp.asarray(pad(self.poses(grasps)))))
    _tick(clock, 'network', t)
    return q[:len(crops)].astype(np.float64)


def _read(image: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
  h, w = image.shape
  inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
  return np.where(inside, image[np.clip(row, 0, h - 1), np.clip(col, 0, w - 1)], 0.0)


def _tick(clock: dict, stage: str, start: float) -> float:
  now = time.perf_counter()
  clock[stage] = clock.get(stage, 0.0) + now - start
  return now


def features(grasps: dict, gripper: str, fx: float, width: float) -> np.ndarray:
  """gqcnn's feature vectors: [p1, p2, depth] (jaw endpoints, pixels) or [u, v]."""
  if gripper == 'suction':
    return grasps['center'].copy()
  half = 0.5 * fx * width / grasps['depth']
  offset = half[:, None] * np.stack([np.cos(grasps['angle']), np.sin(grasps['angle'])], axis=-1)
  return np.concatenate([grasps['center'] - offset, grasps['center'] + offset, grasps['depth'][:, None]], axis=1)


def decode(vecs: np.ndarray, gripper: str, scene: Scene, normals: np.ndarray, s) -> tuple[dict, np.ndarray]:
  """Grasps of feature vectors and which are valid (on the segmask, inside the border, in the approach cone)."""
  h, w = scene.depth.shape
  if gripper == 'suction':
    center = vecs[:, :2]
    row, col = np.clip(vecs[:, 1], 0, h - 1).astype(int), np.clip(vecs[:, 0], 0, w - 1).astype(int)
    angle, psi = _suction_angles(-normals[row, col])
    grasps = {'center': center, 'angle': angle, 'depth': scene.depth[row, col], 'approach_angle': psi}
    ok = psi < s.max_approach_angle
  else:
    p1, p2 = vecs[:, 0:2], vecs[:, 2:4]
    axis = p2 - p1
    grasps = {'center': 0.5 * (p1 + p2), 'angle': np.arctan2(axis[:, 1], axis[:, 0]), 'depth': vecs[:, 4]}
    ok = np.ones(len(vecs), bool)
  u, v = grasps['center'][:, 0], grasps['center'][:, 1]
  ok &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
  ok &= (u >= s.boundary) & (v >= s.boundary) & (u <= w - s.boundary) & (v <= h - s.boundary)
  ok[ok] &= scene.segmask[v[ok].astype(int), u[ok].astype(int)]
  return grasps, ok


def _take(grasps: dict, index) -> dict:
  return {k: x[index] for k, x in grasps.items()}


def _refit(rng: np.random.Generator, grasps: dict, q: np.ndarray, gripper: str, scene: Scene, normals, s, cem,
           clock: dict) -> dict:
  """One CEM iteration after scoring: elite, sklearn mixture, rejection sampling of c grasps."""
  t = time.perf_counter()
  num_refit = max(int(np.ceil(cem.elite_fraction * len(q))), 1)
  elite = np.argsort(-q, kind='stable')[:num_refit]
  f = features(_take(grasps, elite), gripper, scene.fx, getattr(s, 'gripper_width', 0.0))
  mean, std = f.mean(axis=0), f.std(axis=0)
  std[std == 0] = 1e-6
  k = min(cem.num_components, num_refit)
  gmm = GaussianMixture(n_components=k, weights_init=np.full(k, 1.0 / k), reg_covar=cem.reg_covar,
                        random_state=np.random.RandomState(rng.integers(2 ** 31)))
  with warnings.catch_warnings():
    warnings.simplefilter('ignore', ConvergenceWarning)
    gmm.fit((f - mean) / std)
  kept, count, tries = [], 0, 0
  while count < cem.num_resample and tries < MAX_RESAMPLES:
    vecs, _ = gmm.sample(n_samples=cem.num_resample)
    new, ok = decode(std * vecs + mean, gripper, scene, normals, s)
    kept.append(_take(new, ok))
    count, tries = count + int(ok.sum()), tries + 1
  _tick(clock, 'gmm', t)
  return {key: np.concatenate([g[key] for g in kept])[:cem.num_resample] for key in kept[0]}


def cem(rng: np.random.Generator, scene: Scene, scorer: Scorer, s, cem_params, clock: dict) -> tuple[dict, float]:
  """One gripper's CEM plan: (best grasp of the last set, its probability); (None, -inf) when none is valid."""
  t = time.perf_counter()
  gripper = scorer.gripper
  if gripper == 'suction':
    grasps = suction_points(rng, scene, cem_params.num_seed, s)
    normals = normal_cloud(scene, scene.depth)
  else:
    grasps, normals = antipodal_grasps(rng, scene, cem_params.num_seed, s), None
  _tick(clock, 'sampling', t)
  for _ in range(cem_params.num_iterations):
    if len(grasps['depth']) == 0:
      return None, -np.inf
    q = scorer(scene.depth, grasps, clock)
    grasps = _refit(rng, grasps, q, gripper, scene, normals, s, cem_params, clock)
  if len(grasps['depth']) == 0:
    return None, -np.inf
  q = scorer(scene.depth, grasps, clock)
  best = int(np.argmax(q))
  return _take(grasps, best), float(q[best])


def plan(rng: np.random.Generator, scene: Scene, subs: list[tuple[Scorer, object, object]]) -> tuple[dict, dict]:
  """The ambidextrous plan over ``subs`` = [(scorer, sampler, CEMParams)]: ({gripper, grasp, probability},
  seconds per stage)."""
  clock = {stage: 0.0 for stage in STAGES}
  with threadpool_limits(limits=1):
    results = [(scorer.gripper, *cem(rng, scene, scorer, s, c, clock)) for scorer, s, c in subs]
  gripper, grasp, q = max(results, key=lambda r: r[2])
  return {'gripper': gripper, 'grasp': grasp, 'probability': q}, clock


__all__ = ['STAGES', 'Scene', 'Scorer', 'antipodal_grasps', 'cem', 'decode', 'features', 'normal_cloud', 'plan',
           'suction_points']
