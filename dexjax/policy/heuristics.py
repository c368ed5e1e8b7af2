"""Heuristic grasp scorers: the analytic baselines of the Dex-Net 4.0 benchmark (spec section 4.6).

Both are scorers (`dexjax.policy.scorers`): frozen pytrees with a static ``gripper`` called as
``scorer(observation, grasps) -> (N,) float32`` on one `Observation` and N image grasps; jittable, static shapes,
never NaN (centres off the image, non-finite or non-positive grasp fields score 0). Scores lie in [0, 1] but are
not success probabilities: only rankings within one heuristic are meaningful.

Centroid term (shared, gqcnn's): q_c = (exp(-d / max(H, W)) - e^-1) / (1 - e^-1), clipped to [0, 1], with d the
pixel distance of the grasp centre to the object centroid: the mean (row, col) of ``observation.mask`` (the image
centre if the mask is empty), or, when the scorer's optional ``labels`` field holds an (H, W) int instance image,
the centroid of the pixels sharing the label of the grasp centre's pixel (label 0 = background: score 0), as
gqcnn's ``obj_segmask``. ``labels`` describes one scene: set it per observation with ``scorer.replace(labels=...)``.
Without ``labels``, a scorer whose static ``instance_jump`` is set (metres) segments each observation itself into
instances by depth jumps (`dexjax.policy.depth_instances`: 4-neighbours of the mask within ``instance_jump`` in
depth share an object), so the centroid is the grasped object's own, read from the image alone; the benchmark's
heuristics (`dexjax.policy.make_policy`) do, because in a bin of 25 objects the segmask's centroid is the bin's
centre (docs/deviations.md). ``instance_jump = None`` (the scorers' default) is gqcnn's segmask centroid.
The scorers do not restrict centres to ``observation.mask`` (a policy's candidates already are).

* `SuctionPlanarityCentroid` (gqcnn ``suction_com_disc_approach_planarity``, Dex-Net 3.0 "Planarity-Centroid"):
  the depth image is deprojected; the points of a static ``window`` x ``window`` pixel square around the centre
  pixel whose distance to the contact c (the centre deprojected at the grasp depth) perpendicular to the
  approach a is at most the cup radius form the disc; MSE = mean ((p - c) . a)^2, the squared distance to the
  plane through c perpendicular to a. Rule: planar iff MSE <= ``planarity_threshold`` (default 1e-6 m^2, a 1 mm
  RMS deviation: the 10 % strain of the 1 cm cup cone); planarity q_p = exp(-MSE / planarity_threshold), so
  planar iff q_p >= e^-1. Score = q_c if planar else 0. Deviations from gqcnn: gqcnn thresholds exp(-||r||) of
  the camera-z residual norm r (metres, unscaled) at the batch's ``planarity_pctile`` percentile or an absolute
  threshold; we use the true point-plane distance and an absolute threshold only, so a grasp's score does not
  depend on the other candidates (a percentile always calls some candidates planar, even on a sphere). The
  window (gqcnn ``window_size``, default 25 px) must hold the disc: at least 2 fx r / z_min + 1 pixels
  (`suction_window`); a larger window only costs time. Approach: gqcnn keeps the sampler's, the normal of the
  depth's central differences at the pixel, which a noisy sensor tilts (0.5 mm noise: 5-7 degrees median on
  level 1, where the cup seals on a flat face up to ~11 degrees and on a 4 cm can's side ~3); with a static
  ``fit_approach`` of k > 0, ``refine`` turns each candidate to the normal of the plane best fitting its disc
  points (the disc's covariance's smallest eigenvector, k refits; gqcnn's "best-fit planarity" plane), and the
  benchmark's heuristics (`dexjax.policy.make_policy`) do, with k = 2 (docs/deviations.md).
* `ParallelJawForceClosureCentroid` (gqcnn ``parallel_jaw_com_force_closure``, Dex-Net 2.1's image-based force
  closure): each jaw starts at its tip, the centre -/+ half the opening (width projected at the grasp depth:
  (fx, fy) width / (2 depth) along the axis), and moves to the centre in ``num_steps`` samples (nearest pixels);
  its contact is the first sample whose depth is less than the grasp depth (the surface is above the jaw tip).
  The grasp is collision-free iff both tips' pixels are not above the grasp depth (the jaws can descend).
  Contact normals: n = normalise(d/dcol, d/drow) of the depth smoothed by ``gaussian_sigma`` (`masked_blur`),
  pointing out of a raised object, as the antipodal sampler's. Force closure iff collision-free, both contacts
  found and each jaw's closing direction lies inside its contact's friction cone: -n_1 . axis > cos(arctan mu)
  and n_2 . axis > cos(arctan mu) (the contacts lie on the axis, the contact line). Score = q_c if force
  closure else 0. mu defaults to 0.8 (Dex-Net 2.1; gqcnn's example config uses 0.5). Deviations: gqcnn reads the
  sampler's stored contacts; we find them from the grasp alone (any grasp, e.g. CEM-refined, can be scored).
  Pixels off the image (or with invalid depth) read as occupied: a tip off the image is a collision. gqcnn's
  ``antipodality_pctile`` escape (near-force-closure grasps pass) is not kept.
* `composite_heuristic_choice` (the paper's "Composite Heuristic", whose exact rule is unpublished): use the
  suction cup when the best suction candidate is planar and near its object's centroid, q_c >=
  ``suction_threshold`` (default 0.5: within ~0.38 max(H, W) px of it), or when no parallel-jaw candidate is in
  force closure; otherwise the parallel jaws. Why: a cup needs only one flat patch reachable from above, the
  common case in a bin (Dex-Net 3.0's Planarity-Centroid premise), and a seal near the centroid resists the
  gravity torque; the jaws take over where no such patch exists (curved or small objects), which is where
  force closure is the better test. The two heuristic scores are not calibrated probabilities, so comparing them
  greedily (as the learned ambidextrous policy does) would be meaningless: a priority rule with a threshold, as
  gqcnn's ``PriorityCompositeGraspingPolicy`` (``min_q_value``), is used instead.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.policy.instances import depth_instances
from dexjax.policy.observation import Observation
from dexjax.policy.scorers import GRIPPERS, PARALLEL_JAW, SUCTION
from dexjax.render.camera import Camera, pixel_rays
from dexjax.sampling.image_grasps import (ImageParallelJawGrasp, ImageSuctionGrasp, angles_from_approach,
                                          approach_from_angles, camera_point)
from dexjax.sampling.image_samplers import masked_blur

_E1 = math.exp(-1.0)
_MIN_GRADIENT = 1e-6  # metres per pixel: smaller smoothed-depth gradients (flat, or rounding noise) give no normal


def _nearest(uv: jax.Array, shape: tuple[int, int]) -> tuple[jax.Array, jax.Array]:
  """(row, col) int32 nearest pixels of (..., 2) (u, v) points; non-finite points map to (-1, -1) (off image)."""
  uv = jnp.clip(jnp.floor(jnp.where(jnp.isfinite(uv), uv, -2.0) + 0.5), -1, max(shape) + 1)
  return uv[..., 1].astype(jnp.int32), uv[..., 0].astype(jnp.int32)


def _read(image: jax.Array, row: jax.Array, col: jax.Array, fill) -> jax.Array:
  """image[row, col], ``fill`` where (row, col) is off the image (safe for any int indices)."""
  h, w = image.shape
  inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
  return jnp.where(inside, image[jnp.clip(row, 0, h - 1), jnp.clip(col, 0, w - 1)], fill)


@jax.jit
def _centroid_quality(observation: Observation, center: jax.Array, labels: jax.Array | None) -> jax.Array:
  """(N,) centroid term q_c in [0, 1] of N grasp centres (N, 2) (u, v) pixels (module doc); 0 if non-finite or,
  with ``labels`` (H, W) int, where the centre's label is 0 or off the image."""
  h, w = observation.shape
  rows = jnp.arange(h, dtype=jnp.float32)[:, None]
  cols = jnp.arange(w, dtype=jnp.float32)[None, :]
  if labels is None:
    objects = observation.mask[None]  # (1, H, W)
    has_object = jnp.ones(center.shape[0], bool)
  else:
    own = _read(labels, *_nearest(center, (h, w)), 0)
    objects = labels[None] == own[:, None, None]  # (N, H, W)
    has_object = own != 0
  count = jnp.sum(objects, axis=(1, 2))
  safe = jnp.maximum(count, 1).astype(jnp.float32)
  c_row = jnp.where(count > 0, jnp.sum(objects * rows, axis=(1, 2)) / safe, (h - 1) / 2.0)
  c_col = jnp.where(count > 0, jnp.sum(objects * cols, axis=(1, 2)) / safe, (w - 1) / 2.0)
  dist = jnp.hypot(center[:, 1] - c_row, center[:, 0] - c_col)
  q = jnp.clip((jnp.exp(-dist / max(h, w)) - _E1) / (1.0 - _E1), 0.0, 1.0)
  return jnp.where(has_object & jnp.isfinite(q), q, 0.0).astype(jnp.float32)


def _object_labels(observation: Observation, labels: jax.Array | None,
                   instance_jump: float | None) -> jax.Array | None:
  """The (H, W) instance labels a scorer's centroid term uses: its own ``labels``, else the observation's depth
  instances when ``instance_jump`` (metres) is set, else None (the segmask's centroid)."""
  if labels is not None or instance_jump is None:
    return labels
  return depth_instances(observation.depth, observation.mask, instance_jump)


def suction_window(camera: Camera, min_depth: float, cup_radius: float = 0.01) -> int:
  """Smallest odd static ``window`` (pixels) of `SuctionPlanarityCentroid` holding a cup disc of ``cup_radius``
  (metres) seen face-on at the nearest depth ``min_depth`` (metres): 2 ceil(max(fx, fy) r / z) + 1. Eager."""
  k = camera.intrinsics
  return 2 * math.ceil(max(float(k.fx), float(k.fy)) * cup_radius / min_depth) + 1


def _disc_window(points: jax.Array, valid: jax.Array, grasp: ImageSuctionGrasp, size: int):
  """(window (size, size, 3) points, ok (size, size) bool, inside ()) around one grasp's centre pixel.

  ``points`` (H + size - 1, W + size - 1, 3) camera-frame points and ``valid`` (same, bool) are padded by
  size // 2 on each side, so the window of centre pixel (r, c) starts at padded (r, c).
  """
  h, w = points.shape[0] - size + 1, points.shape[1] - size + 1
  row, col = _nearest(grasp.center, (h, w))
  inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
  start = (jnp.clip(row, 0, h - 1), jnp.clip(col, 0, w - 1))
  window = jax.lax.dynamic_slice(points, (*start, 0), (size, size, 3))
  return window, jax.lax.dynamic_slice(valid, start, (size, size)), inside


def _in_disc(window: jax.Array, ok: jax.Array, contact: jax.Array, approach: jax.Array, radius: jax.Array):
  """((size, size) bool disc membership, (size, size) distances along the approach) of window points."""
  offset = window - contact
  along = offset @ approach
  return ok & (jnp.sum(offset * offset, axis=-1) - along * along <= radius * radius), along


def _disc_mse(points: jax.Array, valid: jax.Array, camera: Camera, grasp: ImageSuctionGrasp, radius: jax.Array,
              size: int) -> jax.Array:
  """() mean squared distance along the approach of the disc points of one grasp; inf if it cannot be scored
  (``points``, ``valid``: padded, `_disc_window`)."""
  window, ok, inside = _disc_window(points, valid, grasp, size)
  contact = camera_point(camera, grasp.center, grasp.depth)
  approach = approach_from_angles(grasp.angle, grasp.approach_angle)
  in_disc, along = _in_disc(window, ok, contact, approach, radius)
  count = jnp.sum(in_disc)
  mse = jnp.sum(jnp.where(in_disc, along * along, 0.0)) / jnp.maximum(count, 1)
  good = inside & (grasp.depth > 0) & jnp.all(jnp.isfinite(contact)) & jnp.all(jnp.isfinite(approach))
  return jnp.where(good & (count > 0) & jnp.isfinite(mse), mse, jnp.inf)


def _disc_plane_approach(points: jax.Array, valid: jax.Array, camera: Camera, grasp: ImageSuctionGrasp,
                         radius: jax.Array, size: int, iterations: int) -> jax.Array:
  """(3,) camera-frame unit approach of one grasp along the normal of the plane best fitting its disc points
  (least squares: the covariance's smallest eigenvector), pointing away from the camera (a_z > 0). The disc is
  taken about the current approach and refitted ``iterations`` times; the grasp's own approach is kept where a
  fit has fewer than 3 points or is not finite."""
  window, ok, _ = _disc_window(points, valid, grasp, size)
  contact = camera_point(camera, grasp.center, grasp.depth)
  approach = approach_from_angles(grasp.angle, grasp.approach_angle)
  for _ in range(iterations):
    in_disc, _ = _in_disc(window, ok, contact, approach, radius)
    count = jnp.sum(in_disc)
    weight = in_disc[..., None].astype(window.dtype)
    mean = jnp.sum(weight * window, axis=(0, 1)) / jnp.maximum(count, 1)
    centred = (jnp.where(in_disc[..., None], window, mean) - mean).reshape(-1, 3)
    normal = jnp.linalg.eigh(centred.T @ centred)[1][:, 0]
    normal = jnp.where(normal[2] < 0, -normal, normal)
    approach = jnp.where((count >= 3) & jnp.all(jnp.isfinite(normal)), normal, approach)
  return approach


@functools.partial(jax.jit, static_argnums=(3, 4))
def _fitted_approaches(observation: Observation, grasps: ImageSuctionGrasp, radius: jax.Array, half: int,
                       iterations: int) -> ImageSuctionGrasp:
  """N grasps with their approach replaced by their disc's best-fit plane normal (`_disc_plane_approach`)."""
  points, valid = _padded_points(observation, half)
  approach = jax.vmap(_disc_plane_approach, in_axes=(None, None, None, 0, None, None, None))(
      points, valid, observation.camera, grasps, radius, 2 * half + 1, iterations)
  angle, approach_angle = jax.vmap(angles_from_approach)(approach)
  return grasps.replace(angle=angle.astype(grasps.angle.dtype),
                        approach_angle=approach_angle.astype(grasps.approach_angle.dtype))


def _padded_points(observation: Observation, half: int) -> tuple[jax.Array, jax.Array]:
  """Camera-frame points (H + 2 half, W + 2 half, 3) of the observation's valid pixels and their mask, padded."""
  depth = observation.depth
  valid = jnp.isfinite(depth) & (depth > 0)
  points = pixel_rays(observation.camera.intrinsics) * jnp.where(valid, depth, 0.0)[..., None]
  return jnp.pad(points, ((half, half), (half, half), (0, 0))), jnp.pad(valid, half)


@functools.partial(jax.jit, static_argnums=3)
def _planarity_mse(observation: Observation, grasps: ImageSuctionGrasp, radius: jax.Array, half: int) -> jax.Array:
  """(N,) float32 disc MSE of N grasps (`SuctionPlanarityCentroid.planarity_mse`), window 2 half + 1 pixels."""
  points, valid = _padded_points(observation, half)
  mse = jax.vmap(_disc_mse, in_axes=(None, None, None, 0, None, None))(points, valid, observation.camera, grasps,
                                                                         radius, 2 * half + 1)
  return mse.astype(jnp.float32)


@struct.dataclass
class SuctionPlanarityCentroid:
  """Suction planarity-centroid heuristic (gqcnn ``suction_com_disc_approach_planarity``; module doc).

  Attributes:
    cup_radius: disc radius, metres (the Dex-Net 4.0 cup, `dexjax.grippers.SuctionGripper`: 0.01).
    planarity_threshold: largest disc MSE of a planar grasp, m^2 (1e-6: 1 mm RMS); also the scale of q_p.
    labels: optional (H, W) int instance labels of the scene (0 = background) for per-object centroids.
    instance_jump: static, without ``labels``: None (the segmask's centroid, gqcnn's default) or the depth jump
      (metres) separating the instances the centroid term segments each observation into (module doc).
    window: static, side of the pixel window holding the disc (odd; an even value is rounded up), pixels.
    fit_approach: static, 0 (gqcnn: each candidate keeps its sampler's approach, the local surface normal) or
      the number of best-fit plane refits of `refine`, which turns each candidate's approach to the normal of
      the plane best fitting its disc (module doc).
  """

  cup_radius: float = 0.01
  planarity_threshold: float = 1e-6
  labels: jax.Array | None = None
  instance_jump: float | None = struct.field(pytree_node=False, default=None)
  window: int = struct.field(pytree_node=False, default=25)
  fit_approach: int = struct.field(pytree_node=False, default=0)

  @property
  def gripper(self) -> str:
    return SUCTION

  def planarity_mse(self, observation: Observation, grasps: ImageSuctionGrasp) -> jax.Array:
    """(N,) float32 mean squared distance (m^2) of each grasp's disc points to the plane through the contact
    perpendicular to the approach; +inf where a grasp cannot be scored (centre off the image, bad fields)."""
    return _planarity_mse(observation, grasps, jnp.asarray(self.cup_radius, jnp.float32), self.window // 2)

  def refine(self, observation: Observation, grasps: ImageSuctionGrasp) -> ImageSuctionGrasp:
    """N candidates as the policy executes them: with ``fit_approach`` > 0 each approach is the normal of the
    plane best fitting the depth points of its cup disc (``fit_approach`` refits, each taking the disc about
    the last normal), else unchanged. Centres and depths are kept."""
    if self.fit_approach <= 0:
      return grasps
    return _fitted_approaches(observation, grasps, jnp.asarray(self.cup_radius, jnp.float32), self.window // 2,
                              self.fit_approach)

  def planarity(self, observation: Observation, grasps: ImageSuctionGrasp) -> jax.Array:
    """(N,) planarity q_p = exp(-MSE / planarity_threshold) in [0, 1] (0 where unscorable)."""
    return jnp.exp(-self.planarity_mse(observation, grasps) / self.planarity_threshold)

  def __call__(self, observation: Observation, grasps: ImageSuctionGrasp) -> jax.Array:
    """(N,) float32 scores: the centroid term q_c of planar grasps, 0 for the others."""
    planar = self.planarity_mse(observation, grasps) <= self.planarity_threshold
    labels = _object_labels(observation, self.labels, self.instance_jump)
    return jnp.where(planar, _centroid_quality(observation, grasps.center, labels), 0.0)


def _jaw_contacts(depth: jax.Array, grad: jax.Array, focal: jax.Array, grasp: ImageParallelJawGrasp,
                  num_steps: int) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
  """Closes both jaws of one grasp: (contacts (2, 2) (u, v) pixels, unit normals (2, 2) (u, v) (0 if the
  gradient is below _MIN_GRADIENT), found (2,) bool, tip_free (2,) bool); jaw 0 comes from centre - axis,
  jaw 1 from centre + axis. ``grad`` (2, H, W) is the smoothed depth's (d/dcol, d/drow); ``focal`` (2,) = (fx, fy)."""
  axis = jnp.stack([jnp.cos(grasp.angle), jnp.sin(grasp.angle)])
  half = 0.5 * grasp.width / grasp.depth * focal * axis
  tips = jnp.stack([grasp.center - half, grasp.center + half])  # (2, 2)
  t = jnp.linspace(0.0, 1.0, num_steps)[None, :, None]
  path = tips[:, None, :] + t * (grasp.center - tips)[:, None, :]  # (2, S, 2): tip -> centre
  rows, cols = _nearest(path, depth.shape)
  occupied = _read(depth, rows, cols, 0.0) < grasp.depth  # (2, S)
  first = jnp.argmax(occupied, axis=1)
  contacts = jnp.take_along_axis(path, first[:, None, None], axis=1)[:, 0]
  at = (rows[jnp.arange(2), first], cols[jnp.arange(2), first])
  g = jnp.stack([_read(grad[0], *at, 0.0), _read(grad[1], *at, 0.0)], axis=-1)  # (2 jaws, 2)
  norm = jnp.linalg.norm(g, axis=-1, keepdims=True)
  normals = jnp.where(norm > _MIN_GRADIENT, g / jnp.maximum(norm, _MIN_GRADIENT), 0.0)
  return contacts, normals, jnp.any(occupied, axis=1), ~occupied[:, 0]


@functools.partial(jax.jit, static_argnums=(2, 3))
def _pj_contacts(observation: Observation, grasps: ImageParallelJawGrasp, sigma: float,
                 num_steps: int) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
  """`ParallelJawForceClosureCentroid.contacts` of N grasps (smoothing ``sigma`` px, ``num_steps`` per jaw)."""
  g_row, g_col = jnp.gradient(masked_blur(observation.depth, sigma))
  k = observation.camera.intrinsics
  focal = jnp.stack([jnp.asarray(k.fx, jnp.float32), jnp.asarray(k.fy, jnp.float32)])
  depth = jnp.where(jnp.isfinite(observation.depth) & (observation.depth > 0), observation.depth, 0.0)
  return jax.vmap(_jaw_contacts, in_axes=(None, None, None, 0, None))(depth, jnp.stack([g_col, g_row]), focal,
                                                                       grasps, num_steps)


@struct.dataclass
class ParallelJawForceClosureCentroid:
  """Parallel-jaw force-closure-centroid heuristic (gqcnn ``parallel_jaw_com_force_closure``; module doc).

  Attributes:
    friction: friction coefficient mu of the 2-D friction cones (Dex-Net 2.1: 0.8).
    labels: optional (H, W) int instance labels of the scene (0 = background) for per-object centroids.
    instance_jump: static, as `SuctionPlanarityCentroid`'s.
    gaussian_sigma: static, smoothing of the depth before the contact normals, pixels (the sampler's 1.0).
    num_steps: static, samples along each jaw's path from its tip to the grasp centre.
  """

  friction: float = 0.8
  labels: jax.Array | None = None
  instance_jump: float | None = struct.field(pytree_node=False, default=None)
  gaussian_sigma: float = struct.field(pytree_node=False, default=1.0)
  num_steps: int = struct.field(pytree_node=False, default=32)

  @property
  def gripper(self) -> str:
    return PARALLEL_JAW

  def contacts(self, observation: Observation,
               grasps: ImageParallelJawGrasp) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """Image contacts of N grasps: (contacts (N, 2, 2) (u, v) pixels, unit 2-D normals (N, 2, 2) (u, v), found
    (N, 2) bool, tip_free (N, 2) bool); index 1 is the jaw on the +axis side. Entries of unfound contacts are
    meaningless."""
    return _pj_contacts(observation, grasps, self.gaussian_sigma, self.num_steps)

  def force_closure(self, observation: Observation, grasps: ImageParallelJawGrasp) -> jax.Array:
    """(N,) bool: collision-free at the open width, both contacts found, both inside their friction cones."""
    _, normals, found, free = self.contacts(observation, grasps)
    axis = jnp.stack([jnp.cos(grasps.angle), jnp.sin(grasps.angle)], axis=-1)  # (N, 2)
    cos_cone = jnp.cos(jnp.arctan(self.friction))
    in_cone = (jnp.sum(-normals[:, 0] * axis, axis=-1) > cos_cone) & (jnp.sum(normals[:, 1] * axis, axis=-1)
                                                                       > cos_cone)
    fields = jnp.concatenate([grasps.center, jnp.stack([grasps.angle, grasps.depth, grasps.width], -1)], -1)
    ok = jnp.all(jnp.isfinite(fields), axis=-1) & (grasps.depth > 0) & (grasps.width > 0)
    return ok & jnp.all(found & free, axis=-1) & in_cone

  def __call__(self, observation: Observation, grasps: ImageParallelJawGrasp) -> jax.Array:
    """(N,) float32 scores: the centroid term q_c of force-closure grasps, 0 for the others."""
    fc = self.force_closure(observation, grasps)
    labels = _object_labels(observation, self.labels, self.instance_jump)
    return jnp.where(fc, _centroid_quality(observation, grasps.center, labels), 0.0)


def composite_heuristic_choice(suction_best_q: jax.Array, pj_best_q: jax.Array,
                               suction_threshold: float | jax.Array = 0.5) -> jax.Array:
  """Gripper of the Composite Heuristic (module doc): the index into `dexjax.policy.scorers.GRIPPERS`.

  Args:
    suction_best_q: best `SuctionPlanarityCentroid` score of the scene (0: no planar candidate); any shape.
    pj_best_q: best `ParallelJawForceClosureCentroid` score (0: no force-closure candidate); broadcastable.
    suction_threshold: smallest suction score that takes priority over the parallel jaws.

  Returns:
    int32 array: GRIPPERS.index('parallel_jaw') iff suction_best_q < suction_threshold and pj_best_q > 0, else
    GRIPPERS.index('suction') (also when neither heuristic has a candidate; NaN scores count as none).
  """
  use_jaws = (jnp.asarray(suction_best_q) < suction_threshold) & (jnp.asarray(pj_best_q) > 0)
  return jnp.where(use_jaws, GRIPPERS.index(PARALLEL_JAW), GRIPPERS.index(SUCTION)).astype(jnp.int32)


__all__ = ['ParallelJawForceClosureCentroid', 'SuctionPlanarityCentroid', 'composite_heuristic_choice',
           'suction_window']
