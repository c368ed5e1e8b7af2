"""Depth-image samplers, image grasps and grasp crops on analytic 64 x 64 depth images with known answers.

Scene: a camera 0.7 m straight above a floor (depth 0.7 m), a raised box whose top is at depth 0.66 m, narrow
across columns (10 px = 0.033 m < the 0.05 m jaws) and long across rows (30 px = 0.099 m). References are
NumPy / SciPy (the Gaussian smoothing, the crop gather, the pinhole projection).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage

from dexjax.render.camera import Camera, Intrinsics, look_at, project
from dexjax.sampling.crops import grasp_crop
from dexjax.sampling.image_grasps import (ImageParallelJawGrasp, ImageSuctionGrasp, angles_from_approach,
                                          approach_from_angles, parallel_jaw_grasp_3d, suction_grasp_3d)
from dexjax.sampling.image_samplers import (AntipodalImageSampler, SuctionImageSampler, gaussian_blur,
                                            sample_antipodal_image_grasps, sample_suction_image_grasps)

H = W = 64
FLOOR, TOP = 0.7, 0.66
ROWS, COLS = (17, 47), (27, 37)  # box top pixels [r0, r1) x [c0, c1)
_K = Intrinsics(fx=200.0, fy=200.0, cx=31.5, cy=31.5, width=W, height=H)
_EYE = jnp.array([0.0, 0.0, FLOOR])
CAMERA = Camera(_K, look_at(_EYE, jnp.zeros(3)), _EYE)

PJ = AntipodalImageSampler(boundary=8.0, downsample=2, num_edges=256, num_grasps=60)
SUCTION = SuctionImageSampler(boundary=4.0, num_grasps=50)

_antipodal = jax.jit(sample_antipodal_image_grasps)
_suction = jax.jit(sample_suction_image_grasps)
_crop = jax.jit(grasp_crop, static_argnames=('crop_size', 'scale', 'interpolation'))


def _box_image(cols=COLS, nan_fraction=0.0, seed=0):
  d = np.full((H, W), FLOOR, np.float32)
  d[ROWS[0]:ROWS[1], cols[0]:cols[1]] = TOP
  if nan_fraction:
    drop = np.random.default_rng(seed).random((H, W)) < nan_fraction
    drop[ROWS[0] - 3:ROWS[1] + 3, cols[0] - 3:cols[1] + 3] = False  # holes on the floor only
    d[drop] = np.nan
  return d


def _box_mask():
  m = np.zeros((H, W), bool)
  m[ROWS[0]:ROWS[1], COLS[0]:COLS[1]] = True
  return m


def test_gaussian_blur_matches_scipy():
  img = np.random.default_rng(1).random((20, 24)).astype(np.float32)
  np.testing.assert_allclose(gaussian_blur(jnp.asarray(img), 1.0), ndimage.gaussian_filter(img, 1.0),
                             atol=1e-6)


def test_antipodal_grasps_straddle_the_box():
  depth = _box_image(nan_fraction=0.05)
  g, valid = _antipodal(jax.random.PRNGKey(0), jnp.asarray(depth), CAMERA, PJ)
  valid = np.asarray(valid)
  assert valid.shape == (PJ.num_grasps,) and valid.sum() >= 10
  u, v = np.asarray(g.center[:, 0])[valid], np.asarray(g.center[:, 1])[valid]
  # centres between the two long edges, within the box's length
  assert np.all((u >= COLS[0]) & (u <= COLS[1] - 1)) and np.all((v >= ROWS[0] - 1) & (v <= ROWS[1]))
  assert not np.any(np.isnan(depth[v.astype(int), u.astype(int)]))
  # jaw axis across the long edges (perpendicular to them), within the mu = 1 friction cone (45 degrees)
  angle = np.asarray(g.angle)[valid]
  assert np.all(np.abs(np.cos(angle)) >= math.cos(math.atan(PJ.friction)) - 1e-6)
  np.testing.assert_allclose(np.asarray(g.width)[valid], PJ.gripper_width)
  # gripper depth = min smoothed depth in the 2 x 2 window at the centre + U[0.015, 0.05]
  ok = np.isfinite(depth)
  smooth = ndimage.gaussian_filter(np.where(ok, depth, 0.0), 1.0) / ndimage.gaussian_filter(ok * 1.0, 1.0)
  z_c = np.array([smooth[int(r) - 1:int(r) + 1, int(c) - 1:int(c) + 1].min() for c, r in zip(u, v)])
  offset = np.asarray(g.depth)[valid] - z_c
  assert np.all((offset >= PJ.min_depth_offset - 1e-5) & (offset <= PJ.max_depth_offset + 1e-5))
  assert np.ptp(offset) > 0.01  # depths really are sampled


def test_antipodal_no_grasps_on_flat_or_too_wide():
  flat = jnp.full((H, W), FLOOR, jnp.float32)
  wide = jnp.asarray(_box_image(cols=(20, 44)))  # 24 px = 0.079 m across: wider than the jaws both ways
  for image in (flat, wide):
    _, valid = _antipodal(jax.random.PRNGKey(1), image, CAMERA, PJ)
    assert not np.any(np.asarray(valid))


def test_antipodal_segmask_and_vmap_agree_with_plain_calls():
  depth = jnp.asarray(_box_image())
  mask = jnp.asarray(_box_mask())
  keys = jax.random.split(jax.random.PRNGKey(2), 2)
  batched = jax.jit(jax.vmap(sample_antipodal_image_grasps, in_axes=(0, None, None, None, None)))
  g_b, v_b = batched(keys, depth, CAMERA, PJ, mask)
  for i in range(2):
    g, v = sample_antipodal_image_grasps(keys[i], depth, CAMERA, PJ, mask)
    np.testing.assert_array_equal(v, v_b[i])
    np.testing.assert_allclose(g.center, g_b.center[i])
    np.testing.assert_allclose(g.depth, g_b.depth[i], atol=1e-6)
    assert np.asarray(v).sum() > 0
    u = np.asarray(g.center[:, 0])[np.asarray(v)]
    assert np.all((u >= COLS[0]) & (u <= COLS[1] - 1))


def test_suction_on_box_top_is_vertical_at_top_depth():
  g, valid = _suction(jax.random.PRNGKey(3), jnp.asarray(_box_image()), CAMERA, SUCTION, jnp.asarray(_box_mask()))
  valid = np.asarray(valid)
  u, v = np.asarray(g.center[:, 0]).astype(int), np.asarray(g.center[:, 1]).astype(int)
  assert valid.sum() >= 40  # the flat interior (8 x 28 px) fills most of the budget of 50
  assert np.all(_box_mask()[v[valid], u[valid]])
  np.testing.assert_allclose(np.asarray(g.depth)[valid], TOP, atol=1e-6)
  np.testing.assert_allclose(np.asarray(g.approach_angle)[valid], 0.0, atol=1e-3)
  assert len(set(zip(u[valid], v[valid]))) == valid.sum()  # without replacement


def test_suction_never_on_nan_pixels_and_respects_angle_limit():
  depth = _box_image(nan_fraction=0.2, seed=4)
  g, valid = _suction(jax.random.PRNGKey(4), jnp.asarray(depth), CAMERA, SUCTION)
  valid = np.asarray(valid)
  assert valid.sum() == SUCTION.num_grasps
  u, v = np.asarray(g.center[:, 0]).astype(int)[valid], np.asarray(g.center[:, 1]).astype(int)[valid]
  assert not np.any(np.isnan(depth[v, u]))
  assert np.all((u >= 4) & (v >= 4) & (u <= W - 4) & (v <= H - 4))
  assert np.all(np.asarray(g.approach_angle)[valid] <= SUCTION.max_approach_angle + 1e-6)
  np.testing.assert_allclose(np.asarray(g.depth)[valid], depth[v, u])


def _plane_image(approach):
  """Depth of the plane a . p = 0.7 a_z (through (0, 0, 0.7)) with inward normal ``approach`` (camera frame)."""
  rows, cols = np.mgrid[0:H, 0:W].astype(np.float64)
  rays = np.stack([(cols - _K.cx) / _K.fx, (rows - _K.cy) / _K.fy, np.ones_like(cols)], -1)
  return (FLOOR * approach[2] / (rays @ approach)).astype(np.float32)


def test_suction_on_tilted_plane_recovers_the_normal():
  a = np.array([0.2, -0.3, 0.9])
  a /= np.linalg.norm(a)  # 22.6 degrees from the optical axis
  g, valid = _suction(jax.random.PRNGKey(5), jnp.asarray(_plane_image(a)), CAMERA, SUCTION)
  assert np.asarray(valid).all()
  np.testing.assert_allclose(g.approach_angle, math.acos(a[2]), atol=2e-3)
  np.testing.assert_allclose(g.angle, math.atan2(-a[0], a[1]), atol=2e-3)  # r = (a_y, -a_x)
  approach = jax.vmap(approach_from_angles)(g.angle, g.approach_angle)
  np.testing.assert_allclose(approach, np.broadcast_to(a, approach.shape), atol=2e-3)
  steep = np.array([0.0, 0.7, 0.7])  # 45 degrees > the 30 degree limit
  _, valid = _suction(jax.random.PRNGKey(5), jnp.asarray(_plane_image(steep / np.linalg.norm(steep))), CAMERA,
                      SUCTION)
  assert not np.any(np.asarray(valid))


def test_suction_vmap_agrees_with_plain_call():
  depths = jnp.stack([jnp.asarray(_box_image()), jnp.asarray(_box_image(nan_fraction=0.1))])
  keys = jax.random.split(jax.random.PRNGKey(6), 2)
  g_b, v_b = jax.vmap(_suction, in_axes=(0, 0, None, None))(keys, depths, CAMERA, SUCTION)
  for i in range(2):
    g, v = _suction(keys[i], depths[i], CAMERA, SUCTION)
    np.testing.assert_array_equal(v, v_b[i])
    np.testing.assert_allclose(g.center, g_b.center[i])
    np.testing.assert_allclose(g.angle, g_b.angle[i], atol=1e-6)


def test_3d_conversion_round_trip():
  eye = jnp.array([0.3, -0.2, 0.6])
  camera = Camera(_K, look_at(eye, jnp.array([0.02, 0.01, 0.0])), eye)
  rng = np.random.default_rng(7)
  n = 8
  centers = jnp.asarray(rng.uniform(5, 59, (n, 2)), jnp.float32)
  angles = jnp.asarray(rng.uniform(-np.pi, np.pi, n), jnp.float32)
  depths = jnp.asarray(rng.uniform(0.5, 0.8, n), jnp.float32)
  pj = ImageParallelJawGrasp(center=centers, angle=angles, depth=depths, width=jnp.full(n, 0.05))
  g3 = jax.jit(jax.vmap(parallel_jaw_grasp_3d, in_axes=(None, 0)))(camera, pj)
  uv, z = project(camera, g3.center)
  np.testing.assert_allclose(uv, centers, atol=1e-3)
  np.testing.assert_allclose(z, depths, atol=1e-5)
  rot = np.asarray(camera.rotation)
  axis_cam = np.asarray(g3.axis) @ rot  # rows: R^T axis
  np.testing.assert_allclose(axis_cam, np.stack([np.cos(angles), np.sin(angles), np.zeros(n)], -1), atol=1e-5)
  np.testing.assert_allclose(g3.approach, np.broadcast_to(rot[:, 2], (n, 3)), atol=1e-6)
  psi = jnp.asarray(rng.uniform(0.05, 1.2, n), jnp.float32)
  sg = ImageSuctionGrasp(center=centers, angle=angles, depth=depths, approach_angle=psi)
  s3 = jax.vmap(suction_grasp_3d, in_axes=(None, 0))(camera, sg)
  uv, z = project(camera, s3.center)
  np.testing.assert_allclose(uv, centers, atol=1e-3)
  a_cam = np.asarray(s3.approach) @ rot
  np.testing.assert_allclose(np.arccos(a_cam[:, 2]), psi, atol=1e-4)
  back_angle, back_psi = jax.vmap(angles_from_approach)(jnp.asarray(a_cam))
  np.testing.assert_allclose(back_psi, psi, atol=1e-4)
  np.testing.assert_allclose(np.cos(back_angle - angles), 1.0, atol=1e-6)
  assert np.all(np.asarray(angles_from_approach(jnp.array([0.0, 0.0, 1.0]))) == 0.0)


def _marker_image(center, angle):
  """Background 0.7 with a 1-valued bar from 4 to 12 px along (cos a, sin a) from ``center`` (u, v)."""
  rows, cols = np.mgrid[0:H, 0:W].astype(np.float64)
  du, dv = cols - center[0], rows - center[1]
  s = du * math.cos(angle) + dv * math.sin(angle)
  t = -du * math.sin(angle) + dv * math.cos(angle)
  return np.where((s >= 3.5) & (s <= 12.5) & (np.abs(t) <= 1.2), 1.0, 0.7).astype(np.float32)


def _numpy_crop(image, center, angle, size):
  out = np.zeros((size, size), np.float32)
  for r in range(size):
    for c in range(size):
      x, y = c - size // 2, r - size // 2
      u = center[0] + x * math.cos(angle) - y * math.sin(angle)
      v = center[1] + x * math.sin(angle) + y * math.cos(angle)
      iu, iv = int(math.floor(u + 0.5)), int(math.floor(v + 0.5))
      if 0 <= iu < image.shape[1] and 0 <= iv < image.shape[0]:
        out[r, c] = image[iv, iu]
  return out


def test_crop_centres_and_aligns_the_marker():
  for center, angle, size in [((30.0, 34.0), 0.6, 32), ((36.0, 29.0), -2.2, 24), ((30.0, 34.0), 2.9, 24)]:
    image = _marker_image(center, angle)
    crop = np.asarray(_crop(jnp.asarray(image), jnp.asarray(center), jnp.asarray(angle), crop_size=size))
    assert crop.shape == (size, size)
    mid = size // 2
    np.testing.assert_array_equal(crop[mid, mid + 4:mid + 13], 1.0)  # bar to the right, on the centre row
    np.testing.assert_array_equal(crop[mid, :mid + 3], np.float32(0.7))  # nothing at or left of the centre
    np.testing.assert_array_equal(crop[mid + 3:, :], np.float32(0.7))  # horizontal: absent 3 rows away
    np.testing.assert_array_equal(crop[:mid - 2, :], np.float32(0.7))
    np.testing.assert_array_equal(crop, _numpy_crop(image, center, angle, size))


def test_crop_border_bilinear_and_vmap():
  image = jnp.asarray(np.random.default_rng(8).random((H, W)).astype(np.float32))
  c = jnp.array([3.0, 60.0])
  crop = np.asarray(_crop(image, c, jnp.asarray(0.0), crop_size=16))
  np.testing.assert_array_equal(crop[:, :5], 0.0)  # columns u < 0 are outside the image
  np.testing.assert_array_equal(crop[8 + 4:, :], 0.0)  # rows 64.. are outside the image: constant 0
  np.testing.assert_array_equal(crop[:8 + 4, 5:], np.asarray(image)[52:64, 0:11])
  bil = _crop(image, c, jnp.asarray(0.0), crop_size=16, interpolation='bilinear')
  np.testing.assert_allclose(bil[:12, 5:], crop[:12, 5:], atol=1e-6)  # integer grid: both read the pixels
  half = _crop(image, jnp.array([20.5, 30.0]), jnp.asarray(0.0), crop_size=16, interpolation='bilinear')
  expected = 0.5 * (np.asarray(image)[22:38, 12:28] + np.asarray(image)[22:38, 13:29])
  np.testing.assert_allclose(half, expected, atol=1e-6)
  centers = jnp.array([[30.0, 34.0], [20.0, 40.0], [45.0, 25.0]])
  angles = jnp.array([0.3, -1.0, 2.0])
  batched = jax.vmap(lambda cc, a: grasp_crop(image, cc, a, crop_size=16))(centers, angles)
  for i in range(3):
    np.testing.assert_array_equal(batched[i], _crop(image, centers[i], angles[i], crop_size=16))
