"""Cameras: projection against a NumPy pinhole, look_at geometry, the Dex-Net 4.0 camera distribution, sensor
noise statistics (against SciPy / NumPy references) and intrinsics / camera files (ours and ROS CameraInfo)."""

from __future__ import annotations

import json
import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from dexjax.render.camera import Camera, Intrinsics, deproject, look_at, project
from dexjax.render.distribution import (CameraDistribution, _sample_pose_and_intrinsics, camera_from_spherical,
                                        sample_camera, spherical_from_camera)
from dexjax.render.intrinsics_io import load_camera, load_intrinsics, save_camera, save_intrinsics
from dexjax.render.noise import (SensorNoise, _interpolation_matrix, apply_sensor_noise, dropout,
                                 gamma_depth_noise, gaussian_process_noise)

# One jitted function per kind, shared by the tests below (the Gamma noise runs eagerly: jax.random.gamma
# is jitted inside jax and takes seconds to compile, so every test reuses that one compilation).
_project = jax.jit(project)
_round_trip = jax.jit(lambda camera, depth: project(camera, deproject(camera, depth)))
_look_at = jax.jit(jax.vmap(look_at))
_from_spherical = jax.jit(jax.vmap(camera_from_spherical, in_axes=(0, 0, 0, 0, None)))
_sample = jax.jit(jax.vmap(sample_camera, in_axes=(0, None)))
_sample_params = jax.jit(jax.vmap(_sample_pose_and_intrinsics, in_axes=(0, None)))
_dropout = jax.jit(dropout)
_gp = jax.jit(jax.vmap(gaussian_process_noise, in_axes=(0, None, None, None)), static_argnums=3)
_apply = jax.jit(apply_sensor_noise)

_SMALL = Intrinsics(fx=40.0, fy=35.0, cx=15.3, cy=11.7, width=32, height=24)  # non-square: catches u/v swaps


def _numpy_project(rotation, position, k, points):
  """Reference pinhole: camera-frame p = R^T (x - t), (u, v) = (fx p_x / p_z + cx, fy p_y / p_z + cy)."""
  p = (np.asarray(points, np.float64) - position) @ rotation
  return np.stack([k[0] * p[:, 0] / p[:, 2] + k[2], k[1] * p[:, 1] / p[:, 2] + k[3]], axis=1), p[:, 2]


# ----------------------------------------------------------------------------------------------- projection


def test_project_matches_numpy_pinhole():
  rotation = Rotation.from_euler('xyz', [170.0, 12.0, -35.0], degrees=True).as_matrix()
  position = np.array([0.1, -0.2, 0.8])
  camera = Camera(_SMALL, jnp.asarray(rotation, jnp.float32), jnp.asarray(position, jnp.float32))
  rng = np.random.default_rng(0)
  points = position + (rotation @ np.concatenate([rng.uniform(-0.2, 0.2, (20, 2)),
                                                  rng.uniform(0.3, 1.0, (20, 1))], axis=1).T).T
  uv, depth = _project(camera, jnp.asarray(points, jnp.float32))
  uv_ref, depth_ref = _numpy_project(rotation, position, (40.0, 35.0, 15.3, 11.7), points)
  np.testing.assert_allclose(uv, uv_ref, atol=2e-3)
  np.testing.assert_allclose(depth, depth_ref, rtol=1e-5)
  # the camera matrix gives the same pixels, and a point behind the camera gets NaN pixels
  homogeneous = (np.asarray(_SMALL.matrix) @ ((points - position) @ rotation).T).T
  np.testing.assert_allclose(uv, homogeneous[:, :2] / homogeneous[:, 2:], atol=2e-3)
  behind, z = _project(camera, jnp.asarray(position - rotation[:, 2], jnp.float32)[None])
  assert np.isnan(behind).all() and z[0] == pytest.approx(-1.0, abs=1e-6)


def test_deproject_then_project_returns_the_pixels():
  camera = camera_from_spherical(jnp.array([0.02, -0.01, 0.0]), 0.8, math.radians(260.0), math.radians(7.0),
                                 _SMALL)
  depth = jax.random.uniform(jax.random.key(1), (24, 32), minval=0.5, maxval=1.5)
  depth = depth.at[3, 4].set(jnp.nan).at[5, 6].set(0.0)
  uv, z = _round_trip(camera, depth)
  rows, cols = np.mgrid[0:24, 0:32]
  valid = np.isfinite(np.asarray(depth)) & (np.asarray(depth) > 0)
  np.testing.assert_allclose(np.asarray(uv)[valid], np.stack([cols, rows], -1)[valid], atol=1e-3)
  np.testing.assert_allclose(np.asarray(z)[valid], np.asarray(depth)[valid], rtol=1e-5)
  assert np.isnan(np.asarray(uv)[~valid]).all()


def test_look_at_is_a_right_handed_frame_facing_the_target_with_image_up_world_up():
  rng = np.random.default_rng(2)
  eyes = rng.uniform(-1.0, 1.0, (50, 3))
  targets = rng.uniform(-1.0, 1.0, (50, 3))
  r = np.asarray(_look_at(jnp.asarray(eyes, jnp.float32), jnp.asarray(targets, jnp.float32)), np.float64)
  np.testing.assert_allclose(np.einsum('nji,njk->nik', r, r), np.broadcast_to(np.eye(3), r.shape), atol=1e-5)
  np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-5)
  forward = (targets - eyes) / np.linalg.norm(targets - eyes, axis=1, keepdims=True)
  np.testing.assert_allclose(r[:, :, 2], forward, atol=1e-5)
  assert np.abs(r[:, 2, 0]).max() < 1e-5  # image x (right) is horizontal
  up_in_image = -r[:, 2, 1]  # world +z . (image up = -y)
  np.testing.assert_allclose(up_in_image, np.sqrt(1.0 - forward[:, 2]**2), atol=1e-5)  # world up, projected
  # degenerate: the axis parallel to ``up`` still gives a rotation (world +z, and +y with up = +y)
  for eye, target, up in [([0, 0, 1], [0, 0, 0], [0, 0, 1]), ([0, 0, 0], [0, 2, 0], [0, 1, 0])]:
    rotation = np.asarray(look_at(*(jnp.asarray(v, jnp.float32) for v in (eye, target, up))))
    np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-6)
    assert np.linalg.det(rotation) == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_allclose(rotation[:, 2], np.subtract(target, eye) / np.linalg.norm(np.subtract(target, eye)))
  # the target projects onto the principal point
  camera = Camera(_SMALL, jnp.asarray(r[0], jnp.float32), jnp.asarray(eyes[0], jnp.float32))
  uv, _ = _project(camera, jnp.asarray(targets[:1], jnp.float32))
  np.testing.assert_allclose(uv[0], [15.3, 11.7], atol=1e-3)


# --------------------------------------------------------------------------------------------- distribution


def _spherical(center, r, theta_deg, phi_deg):
  """Vectorised `camera_from_spherical` with _SMALL intrinsics; angles in degrees."""
  to = lambda x: jnp.asarray(np.broadcast_to(x, np.shape(r)), jnp.float32)
  return _from_spherical(jnp.asarray(center, jnp.float32), to(r), jnp.deg2rad(to(theta_deg)),
                         jnp.deg2rad(to(phi_deg)), _SMALL)


def test_camera_from_spherical_exact_geometry():
  center = np.array([[0.03, -0.02, 0.0]] * 4)
  theta = np.array([270.0, 270.0, 250.0, 0.0])
  phi = np.array([0.0, 10.0, 5.0, 60.0])
  cams = _spherical(center, np.full(4, 0.8), theta, phi)
  t, p = np.radians(theta), np.radians(phi)
  expected = center + 0.8 * np.stack([np.sin(p) * np.cos(t), np.sin(p) * np.sin(t), np.cos(p)], axis=1)
  np.testing.assert_allclose(cams.position, expected, atol=1e-6)
  # straight overhead at theta = 270: image right = world +x, image down = world -y, axis = world -z
  np.testing.assert_allclose(cams.rotation[0], [[1, 0, 0], [0, -1, 0], [0, 0, -1]], atol=1e-6)
  # theta = 0, phi = 60: camera on +x looking back and down; right = world +y (i.e. forward x up)
  np.testing.assert_allclose(cams.rotation[3][:, 0], [0.0, 1.0, 0.0], atol=1e-6)
  # the roll is continuous at phi = 0 (no jump to look_at's fallback)
  near = _spherical(center[:2], np.full(2, 0.8), np.array([250.0, 250.0]), np.array([0.0, 1e-4]))
  np.testing.assert_allclose(near.rotation[0], near.rotation[1], atol=1e-5)
  angle = math.degrees(math.atan2(float(near.rotation[0][1, 0]), float(near.rotation[0][0, 0])))
  assert angle == pytest.approx(250.0 - 270.0, abs=1e-3)  # image right rotated with the azimuth


@pytest.fixture(scope='module')
def sampled():
  keys = jax.random.split(jax.random.key(3), 2000)
  dist = CameraDistribution()
  return _sample(keys, dist), _sample_params(keys, dist)


def _recover(cameras):
  """(center (N, 3), r, theta deg in [0, 360), phi deg) of each camera from its pose alone (exact geometry)."""
  position = np.asarray(cameras.position, np.float64)
  axis = np.asarray(cameras.rotation, np.float64)[:, :, 2]
  t = -position[:, 2] / axis[:, 2]  # optical axis meets the floor z = 0
  center = position + t[:, None] * axis
  offset = position - center
  r = np.linalg.norm(offset, axis=1)
  theta = np.degrees(np.arctan2(offset[:, 1], offset[:, 0])) % 360.0
  phi = np.degrees(np.arccos(offset[:, 2] / r))
  return center, r, theta, phi


def test_sampled_cameras_lie_in_and_cover_the_seed_ranges(sampled):
  cameras, _ = sampled
  center, r, theta, phi = _recover(cameras)
  k = cameras.intrinsics
  assert k.width == 500 and k.height == 500
  np.testing.assert_array_equal(k.fx, k.fy)
  for name, values, low, high, tol in [('r', r, 0.7, 0.9, 1e-5), ('theta', theta, 250.0, 290.0, 1e-2),
                                       ('phi', phi, 0.0, 10.0, 2e-2), ('x', center[:, 0], -0.05, 0.05, 1e-5),
                                       ('y', center[:, 1], -0.05, 0.05, 1e-5),
                                       ('f', np.asarray(k.fx), 550.0, 600.0, 1e-3),
                                       ('cx', np.asarray(k.cx), 257.5, 262.5, 1e-3),
                                       ('cy', np.asarray(k.cy), 257.5, 262.5, 1e-3)]:
    assert values.min() >= low - tol and values.max() <= high + tol, name
    width = high - low
    assert values.min() < low + 0.01 * width and values.max() > high - 0.01 * width, name  # P(fail) < 1e-8
    assert stats.kstest((values - low) / width, 'uniform').pvalue > 1e-3, name
  assert np.corrcoef(np.asarray(k.cx), np.asarray(k.cy))[0, 1] < 0.1  # drawn independently
  assert np.asarray(cameras.position)[:, 2].min() > 0.7 * math.cos(math.radians(10.0)) - 1e-5  # above the bin


def test_spherical_from_camera_inverts_camera_from_spherical(sampled):
  cameras, (center, r, theta, phi, *_) = sampled
  got = jax.jit(jax.vmap(spherical_from_camera))(cameras)
  reference = _recover(cameras)  # NumPy, float64
  np.testing.assert_allclose(got[0], center, atol=2e-5)
  np.testing.assert_allclose(got[1], r, atol=2e-5)
  np.testing.assert_allclose(np.degrees(got[2]), reference[2], atol=2e-2)
  np.testing.assert_allclose(np.degrees(got[3]), reference[3], atol=2e-2)
  np.testing.assert_allclose(got[2], theta, atol=4e-4)  # the sampled angles (float32 pose, float32 recovery)
  np.testing.assert_allclose(got[3], phi, atol=4e-4)
  # A floor 0.1 m higher: the same axis meets it 0.1 / cos(phi) sooner.
  higher = jax.vmap(spherical_from_camera, in_axes=(0, None))(cameras, 0.1)
  np.testing.assert_allclose(higher[1], np.asarray(r) - 0.1 / np.cos(np.asarray(phi)), atol=2e-5)
  first = jax.tree.map(lambda x: x[0], cameras)
  looking_up = first.replace(rotation=first.rotation * jnp.array([1.0, -1.0, -1.0]))  # y and z axes flipped
  below = first.replace(position=jnp.array([0.0, 0.0, -0.5]))
  assert not np.any(np.isnan(np.concatenate([np.ravel(v) for v in spherical_from_camera(first)])))
  for camera in (looking_up, below):
    assert all(np.all(np.isnan(v)) for v in spherical_from_camera(camera))


def test_optical_axis_passes_through_the_sampled_center(sampled):
  cameras, (center, r, theta, phi, f, cx, cy) = sampled
  position = np.asarray(cameras.position, np.float64)
  axis = np.asarray(cameras.rotation, np.float64)[:, :, 2]
  to_center = np.asarray(center, np.float64) - position
  np.testing.assert_allclose(np.asarray(center)[:, 2], 0.0)
  np.testing.assert_allclose(np.linalg.norm(to_center, axis=1), r, rtol=1e-5)
  np.testing.assert_allclose(np.linalg.norm(np.cross(axis, to_center), axis=1), 0.0, atol=2e-6)
  assert (np.einsum('ni,ni->n', axis, to_center) > 0).all()
  np.testing.assert_allclose(cameras.intrinsics.cx, cx)
  # image right stays within the seed's +-20 degree roll of world +x
  assert (np.asarray(cameras.rotation)[:, 0, 0] > math.cos(math.radians(20.0)) - 1e-5).all()


@pytest.mark.parametrize('changes, field', [
    (dict(radius=(0.9, 0.7)), 'radius'), (dict(radius=(0.0, 0.9)), 'radius'),
    (dict(phi_deg=(0.0, 95.0)), 'phi_deg'), (dict(phi_deg=(-1.0, 5.0)), 'phi_deg'),
    (dict(focal=(float('nan'), 600.0)), 'focal'), (dict(cx=(1.0,)), 'cx'),
    (dict(center_y=(0.1, -0.1)), 'center_y'), (dict(width=0), 'width'), (dict(height=499.5), 'height')])
def test_distribution_validation(changes, field):
  CameraDistribution().validate()
  with pytest.raises(ValueError, match=f'CameraDistribution: {field}: expected'):
    CameraDistribution(**changes).validate()


# -------------------------------------------------------------------------------------------------- noise


def _depth_with_invalid(shape=(200, 200), value=0.8):
  depth = jnp.full(shape, value, jnp.float32)
  return depth.at[0, 0].set(jnp.nan).at[1, 1].set(0.0).at[2, 2].set(jnp.inf)


def _valid_pixels(image):
  """The pixels of ``image`` other than the three invalid ones set by `_depth_with_invalid`, flattened."""
  mask = np.ones(np.shape(image), bool)
  mask[[0, 1, 2], [0, 1, 2]] = False
  return np.asarray(image)[mask]


def _assert_invalid_kept(noisy, depth):
  assert np.isnan(noisy[0, 0]) and noisy[1, 1] == 0.0 and np.isposinf(noisy[2, 2])


def test_gamma_noise_is_one_gamma_multiplier_per_image():
  """gqcnn's multiplicative noise (spec 3.4): one Gamma(k, 1/k) factor per image, the same for every pixel."""
  depth = _depth_with_invalid()
  noisy = np.asarray(gamma_depth_noise(jax.random.key(4), depth, 1000.0))  # eager: jax compiles it once
  _assert_invalid_kept(noisy, depth)
  ratio = _valid_pixels(noisy) / 0.8
  np.testing.assert_allclose(ratio, ratio[0], rtol=1e-6)  # one factor for the whole image
  assert ratio[0] != pytest.approx(1.0, abs=1e-6)
  small = jnp.full((2, 2), 0.8, jnp.float32)
  keys = jax.random.split(jax.random.key(7), 4000)
  factor = np.asarray(jax.vmap(lambda k: gamma_depth_noise(k, small, 1000.0)[0, 0])(keys)) / 0.8
  assert factor.mean() == pytest.approx(1.0, abs=2e-3)
  assert factor.var() == pytest.approx(1e-3, rel=0.08)
  assert stats.kstest(factor, stats.gamma(a=1000.0, scale=1e-3).cdf).pvalue > 1e-3
  np.testing.assert_array_equal(noisy, gamma_depth_noise(jax.random.key(4), depth, 1000.0))
  assert not np.array_equal(noisy, gamma_depth_noise(jax.random.key(5), depth, 1000.0))


def test_dropout_fraction_and_untouched_pixels():
  depth = _depth_with_invalid()
  noisy = np.asarray(_dropout(jax.random.key(6), depth, 0.2))
  _assert_invalid_kept(noisy, depth)
  dropped = np.isnan(_valid_pixels(noisy))
  assert dropped.mean() == pytest.approx(0.2, abs=0.01)  # binomial std 0.002
  np.testing.assert_array_equal(_valid_pixels(noisy)[~dropped], np.float32(0.8))
  np.testing.assert_array_equal(noisy, _dropout(jax.random.key(6), depth, 0.2))
  assert np.isnan(_dropout(jax.random.key(6), depth, 1.0)).sum() == 200 * 200 - 2
  np.testing.assert_array_equal(_dropout(jax.random.key(6), depth, 0.0), depth)


def test_interpolation_matrix_matches_numpy_interp():
  for n, s in [(24, 4), (25, 4), (7, 3), (1, 4), (5, 1)]:
    weights = _interpolation_matrix(n, s)
    n_grid = weights.shape[1]
    assert (n_grid - 1) * s >= n - 1 > (n_grid - 2) * s
    reference = np.stack([np.interp(np.arange(n) / s, np.arange(n_grid), np.eye(n_grid)[j])
                          for j in range(n_grid)], axis=1)
    np.testing.assert_allclose(weights, reference, atol=1e-6)


def test_gaussian_process_noise_is_correlated_with_std_sigma():
  keys = jax.random.split(jax.random.key(7), 8)
  depth = _depth_with_invalid((64, 64))
  noisy = np.asarray(_gp(keys, depth, 0.005, 4))
  for image in noisy:
    _assert_invalid_kept(image, depth)
  noise = noisy[:, 4:, 4:] - 0.8  # away from the invalid pixels
  assert noise.std() == pytest.approx(0.005, rel=0.1)
  assert noise[:, ::4, ::4].std() == pytest.approx(0.005, rel=0.1)  # on grid nodes
  assert noise[:, 2::4, 2::4].std() == pytest.approx(0.005, rel=0.1)  # mid-cell: same std
  corr = lambda a, b: np.corrcoef(a.ravel(), b.ravel())[0, 1]
  # expected lag-1 correlation from NumPy interpolation weights (unit-norm rows)
  a = np.stack([np.interp(np.arange(64) / 4, np.arange(17), np.eye(17)[j]) for j in range(17)], axis=1)
  a /= np.linalg.norm(a, axis=1, keepdims=True)
  expected = np.mean(np.einsum('ij,ij->i', a[4:-1], a[5:]))
  assert expected > 0.8
  assert corr(noise[:, :, :-1], noise[:, :, 1:]) == pytest.approx(expected, abs=0.05)
  assert corr(noise[:, :-1, :], noise[:, 1:, :]) == pytest.approx(expected, abs=0.05)
  assert abs(corr(noise[:, :, :-16], noise[:, :, 16:])) < 0.1  # no shared grid nodes: uncorrelated
  np.testing.assert_array_equal(noisy, _gp(keys, depth, 0.005, 4))


def test_apply_sensor_noise_order_keys_and_defaults():
  depth = _depth_with_invalid()
  key = jax.random.key(8)
  np.testing.assert_array_equal(apply_sensor_noise(key, depth), depth)  # off by default
  everything = SensorNoise(use_gamma=True, use_gp=True, use_dropout=True, dropout_rate=0.1)
  noisy = np.asarray(apply_sensor_noise(key, depth, everything))  # eager: reuses the compiled Gamma sampler
  k1, k2, k3 = jax.random.split(key, 3)
  manual = _dropout(k3, _gp(k2[None], gamma_depth_noise(k1, depth, 1000.0), 0.005, 4)[0], 0.1)
  np.testing.assert_allclose(noisy, manual, rtol=1e-6)
  _assert_invalid_kept(noisy, depth)
  no_gamma = SensorNoise(use_gp=True, use_dropout=True, dropout_rate=0.1)
  jitted = np.asarray(_apply(key, depth, no_gamma))
  np.testing.assert_allclose(jitted, _dropout(k3, _gp(k2[None], depth, 0.005, 4)[0], 0.1), rtol=1e-6)
  np.testing.assert_array_equal(np.isnan(jitted), np.isnan(noisy))  # same dropout mask without the Gamma


@pytest.mark.parametrize('changes, field', [
    (dict(gamma_shape=0.0), 'gamma_shape'), (dict(gp_sigma=-1.0), 'gp_sigma'),
    (dict(dropout_rate=1.5), 'dropout_rate'), (dict(gp_scale_factor=0), 'gp_scale_factor')])
def test_sensor_noise_validation(changes, field):
  with pytest.raises(ValueError, match=f'SensorNoise: {field}: expected'):
    apply_sensor_noise(jax.random.key(0), jnp.ones((4, 4)), SensorNoise(**changes))


# ---------------------------------------------------------------------------------------------------- files

_GOOD = dict(fx=575.5, fy=570.25, cx=260.0, cy=259.0, width=500, height=480)
_ROS1_JSON = dict(header=dict(seq=1, frame_id='camera'), height=480, width=500, distortion_model='plumb_bob',
                  D=[0.0] * 5, K=[575.5, 0.0, 260.0, 0.0, 570.25, 259.0, 0.0, 0.0, 1.0],
                  R=np.eye(3).ravel().tolist(), binning_x=0,
                  P=[575.5, 0.0, 260.0, 0.0, 0.0, 570.25, 259.0, 0.0, 0.0, 0.0, 1.0, 0.0])
_ROS2_YAML = """header:
  stamp: {sec: 1, nanosec: 2}
  frame_id: camera_depth_optical_frame
height: 480
width: 500
distortion_model: plumb_bob
d: [0.1, -0.2, 0.0, 0.0, 0.0]
k: [575.5, 0.0, 260.0, 0.0, 570.25, 259.0, 0.0, 0.0, 1.0]
r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
p: [575.5, 0.0, 260.0, 0.0, 0.0, 570.25, 259.0, 0.0, 0.0, 0.0, 1.0, 0.0]
---
"""
_CALIBRATION_YAML = """image_width: 500
image_height: 480
camera_name: depth
camera_matrix: {rows: 3, cols: 3, data: [575.5, 0, 260, 0, 570.25, 259, 0, 0, 1]}
distortion_model: plumb_bob
distortion_coefficients: {rows: 1, cols: 5, data: [0, 0, 0, 0, 0]}
"""


def _assert_good(k):
  assert (k.width, k.height) == (500, 480)
  np.testing.assert_array_equal([k.fx, k.fy, k.cx, k.cy], [575.5, 570.25, 260.0, 259.0])


def test_intrinsics_round_trip(tmp_path):
  path = tmp_path / 'camera.json'
  k = Intrinsics(fx=jnp.float32(575.123), fy=jnp.float32(570.5), cx=jnp.float32(260.25),
                 cy=jnp.float32(258.75), width=500, height=480)
  save_intrinsics(path, k)
  assert json.loads(path.read_text())['width'] == 500
  assert '"fx": 575.123,' in path.read_text()  # the float32's shortest decimal, not 575.1229858398438
  loaded = load_intrinsics(path)
  assert (loaded.width, loaded.height) == (500, 480)
  for field in ('fx', 'fy', 'cx', 'cy'):
    assert getattr(loaded, field) == getattr(k, field)
  path.write_text(json.dumps(_GOOD))
  _assert_good(load_intrinsics(str(path)))


def test_ros_camera_info_json_and_yaml(tmp_path):
  (tmp_path / 'info.json').write_text(json.dumps(_ROS1_JSON))
  (tmp_path / 'info.yaml').write_text(_ROS2_YAML)
  (tmp_path / 'ost.yaml').write_text(_CALIBRATION_YAML)
  with warnings.catch_warnings():
    warnings.simplefilter('error')  # zero distortion: no warning
    _assert_good(load_intrinsics(tmp_path / 'info.json'))
    _assert_good(load_intrinsics(tmp_path / 'ost.yaml'))
  with pytest.warns(UserWarning, match=r'info\.yaml: d: non-zero distortion'):
    _assert_good(load_intrinsics(tmp_path / 'info.yaml'))
  nested = dict(_ROS1_JSON, K=[[575.5, 0.0, 260.0], [0.0, 570.25, 259.0], [0.0, 0.0, 1.0]])
  (tmp_path / 'nested.json').write_text(json.dumps(nested))
  _assert_good(load_intrinsics(tmp_path / 'nested.json'))


def test_camera_round_trip(tmp_path):
  camera = sample_camera(jax.random.key(9))
  save_camera(tmp_path / 'posed.json', camera)
  loaded = load_camera(tmp_path / 'posed.json')
  written = json.loads((tmp_path / 'posed.json').read_text())
  digits = lambda v: len(repr(abs(v)).split('e')[0].replace('.', '').lstrip('0'))
  assert max(digits(v) for v in written['position'] + sum(written['rotation'], [])) <= 9  # float32's, not 17
  np.testing.assert_array_equal(loaded.rotation, camera.rotation)
  np.testing.assert_array_equal(loaded.position, camera.position)
  assert loaded.intrinsics.fx == camera.intrinsics.fx and loaded.intrinsics.width == 500
  bad = Camera(camera.intrinsics, camera.rotation * 1.01, camera.position)
  with pytest.raises(ValueError, match=r'bad\.json: rotation: expected'):
    save_camera(tmp_path / 'bad.json', bad)


_R = np.eye(3).tolist()
_BAD_INTRINSICS = [
    ({k: v for k, v in _GOOD.items() if k != 'fx'}, 'fx'),
    ({k: v for k, v in _GOOD.items() if k != 'cy'}, 'cy'),
    (dict(_GOOD, fx=-3), 'fx'), (dict(_GOOD, fy=float('nan')), 'fy'), (dict(_GOOD, cx=float('inf')), 'cx'),
    (dict(_GOOD, fx='575'), 'fx'), (dict(_GOOD, width=0), 'width'), (dict(_GOOD, width=500.5), 'width'),
    (dict(_GOOD, height=True), 'height'), (dict(_ROS1_JSON, K=[1.0] * 8), 'K'),
    (dict(_ROS1_JSON, K=[575.5, 0, 260, 0, 570.25, 259, 0, 1, 1]), 'K'),
    (dict(_ROS1_JSON, K=[0.0] * 9), r'K\[0\] \(fx\)'),
    (dict(_ROS1_JSON, K=[575.5, 0, 'a', 0, 1, 1, 0, 0, 1]), r'K\[2\]'),
    ({k: v for k, v in _ROS1_JSON.items() if k != 'width'}, 'width'),
]
_BAD_CAMERAS = [
    (dict(_GOOD, position=[0, 0, 1]), 'rotation'),
    (dict(_GOOD, rotation=[[1, 0, 0], [0, 1, 0], [0, 0, -1]], position=[0, 0, 1]), 'rotation'),  # det -1
    (dict(_GOOD, rotation=[[1, 0.1, 0], [0, 1, 0], [0, 0, 1]], position=[0, 0, 1]), 'rotation'),
    (dict(_GOOD, rotation=[[1, 0, 0], [0, 1, 0]], position=[0, 0, 1]), 'rotation'),
    (dict(_GOOD, rotation=_R, position=[0, 1]), 'position'),
    (dict(_GOOD, rotation=_R, position=[0, 1, float('nan')]), r'position\[2\]'),
    (dict(_GOOD, fx=0, rotation=_R, position=[0, 0, 1]), 'fx'),
]


@pytest.mark.parametrize('data, field', _BAD_INTRINSICS)
def test_bad_intrinsics_files_name_the_file_and_field(tmp_path, data, field):
  path = tmp_path / 'cam_file.json'
  path.write_text(json.dumps(data))  # json writes NaN / Infinity, which json.loads reads back
  with pytest.raises(ValueError, match=rf'cam_file\.json: {field}: (expected|missing field)'):
    load_intrinsics(path)


@pytest.mark.parametrize('data, field', _BAD_CAMERAS)
def test_bad_camera_files_name_the_file_and_field(tmp_path, data, field):
  path = tmp_path / 'posed_file.json'
  path.write_text(json.dumps(data))
  with pytest.raises(ValueError, match=rf'posed_file\.json: {field}: (expected|missing field)'):
    load_camera(path)


def test_unparsable_files(tmp_path):
  (tmp_path / 'broken.json').write_text('{"fx": 1,')
  (tmp_path / 'broken.yaml').write_text('fx: [1, 2\n')
  (tmp_path / 'list.json').write_text('[1, 2]')
  with pytest.raises(ValueError, match=r'broken\.json: expected a JSON mapping'):
    load_intrinsics(tmp_path / 'broken.json')
  with pytest.raises(ValueError, match=r'broken\.yaml: expected a YAML mapping'):
    load_intrinsics(tmp_path / 'broken.yaml')
  with pytest.raises(ValueError, match=r'list\.json: expected a mapping'):
    load_intrinsics(tmp_path / 'list.json')
