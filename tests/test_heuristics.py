"""Heuristic scorers (suction planarity-centroid, parallel-jaw force-closure-centroid, composite choice) on
analytic 64 x 64 depth images with known answers.

Scenes (as tests/test_image_samplers.py): a camera 0.7 m straight above a floor, fx = 200 px; a raised box whose
top is at depth 0.66 m, 10 px (0.033 m, narrower than the 0.05 m jaws) across columns and 30 px (0.099 m) along
rows; a hemisphere of radius 0.05 m and a cylinder of radius 0.015 m lying on the floor. The planarity MSE is
checked against a float64 NumPy reference on the same window.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from dexjax.policy.heuristics import (ParallelJawForceClosureCentroid, SuctionPlanarityCentroid,
                                      composite_heuristic_choice, suction_window)
from dexjax.policy.observation import observation
from dexjax.policy.scorers import GRIPPERS
from dexjax.render.camera import Camera, Intrinsics, look_at
from dexjax.sampling.image_grasps import ImageParallelJawGrasp, ImageSuctionGrasp

H = W = 64
FLOOR, TOP = 0.7, 0.66
ROWS, COLS = (17, 47), (27, 37)  # box top pixels [r0, r1) x [c0, c1); mask centroid (row, col) = (31.5, 31.5)
_K = Intrinsics(fx=200.0, fy=200.0, cx=31.5, cy=31.5, width=W, height=H)
_EYE = jnp.array([0.0, 0.0, FLOOR])
CAMERA = Camera(_K, look_at(_EYE, jnp.zeros(3)), _EYE)

SUCTION = SuctionPlanarityCentroid(window=9)  # the 1 cm disc is 3 px across at 0.66 m
PJ = ParallelJawForceClosureCentroid()
N = 1024  # every batch is padded to N grasps (repeating its last): one compilation per scorer and call


def _padded(fn, grasps, n=N):
  """``fn(grasps padded to n)`` cut back to the batch's length, as NumPy arrays."""
  k = grasps.center.shape[0]
  out = fn(jax.tree.map(lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], n - k, axis=0)]), grasps))
  return jax.tree.map(lambda x: np.asarray(x)[:k], out)


_jit_score = jax.jit(lambda scorer, obs, grasps: scorer(obs, grasps))


def _score(scorer, obs, grasps):
  """(k,) jitted scores."""
  return _padded(lambda g: _jit_score(scorer, obs, g), grasps)


def _mse(obs, grasps):
  return _padded(lambda g: SUCTION.planarity_mse(obs, g), grasps)  # the method runs a jitted function


def _box(cols=COLS):
  d = np.full((H, W), FLOOR, np.float32)
  d[ROWS[0]:ROWS[1], cols[0]:cols[1]] = TOP
  m = np.zeros((H, W), bool)
  m[ROWS[0]:ROWS[1], cols[0]:cols[1]] = True
  return observation(jnp.asarray(d), CAMERA, jnp.asarray(m))


def _rays(u, v):
  return np.stack([(u - _K.cx) / _K.fx, (v - _K.cy) / _K.fy, np.ones_like(u)], -1)


def _sphere_depth(u, v, radius=0.05, center=(0.0, 0.0, FLOOR)):
  """Depth (metres) at pixel coordinates (u, v) of a sphere (camera-frame centre) on the floor."""
  r, c = _rays(np.asarray(u, np.float64), np.asarray(v, np.float64)), np.asarray(center)
  b, rr = r @ c, np.sum(r * r, -1)
  disc = b * b - rr * (c @ c - radius**2)
  t = (b - np.sqrt(np.maximum(disc, 0.0))) / rr
  return np.where(disc > 0, np.minimum(t, FLOOR), FLOOR)


def _sphere():
  v, u = np.mgrid[0:H, 0:W].astype(np.float64)
  d = _sphere_depth(u, v)
  return observation(jnp.asarray(d, jnp.float32), CAMERA, jnp.asarray(d < FLOOR))


def _cylinder(radius=0.015):
  """A half cylinder along the image rows (axis = camera y at the floor's depth): top at 0.685 m."""
  v, u = np.mgrid[0:H, 0:W].astype(np.float64)
  x = (u - _K.cx) / _K.fx  # the ray t (x, ., 1) meets X^2 + (Z - 0.7)^2 = R^2 first at the smaller root t
  a, b, c = x * x + 1, FLOOR, FLOOR**2 - radius**2
  disc = b * b - a * c
  d = np.where(disc > 0, (b - np.sqrt(np.maximum(disc, 0.0))) / a, FLOOR)
  return observation(jnp.asarray(d, jnp.float32), CAMERA, jnp.asarray(d < FLOOR - 1e-4))


def _suction_grasps(uv, depth, angle=0.0, psi=0.0):
  uv = np.atleast_2d(np.asarray(uv, np.float32))
  n = uv.shape[0]
  return ImageSuctionGrasp(center=jnp.asarray(uv), angle=jnp.broadcast_to(jnp.float32(angle), (n,)),
                           depth=jnp.asarray(np.broadcast_to(depth, (n,)), jnp.float32),
                           approach_angle=jnp.broadcast_to(jnp.float32(psi), (n,)))


def _pj_grasps(uv, angle=0.0, depth=0.68, width=0.05):
  uv = np.atleast_2d(np.asarray(uv, np.float32))
  n = uv.shape[0]

  def full(x):
    return jnp.asarray(np.broadcast_to(np.asarray(x, np.float32), (n,)))

  return ImageParallelJawGrasp(center=jnp.asarray(uv), angle=full(angle), depth=full(depth), width=full(width))


def _np_disc_mse(depth, uv, z, angle, psi, radius, window):
  """float64 reference: mean squared approach-axis distance of the window points within the tangential disc."""
  a = np.array([-math.sin(angle) * math.sin(psi), math.cos(angle) * math.sin(psi), math.cos(psi)])
  p0 = np.array([(uv[0] - _K.cx) / _K.fx * z, (uv[1] - _K.cy) / _K.fy * z, z])
  r0, c0, half = int(math.floor(uv[1] + 0.5)), int(math.floor(uv[0] + 0.5)), window // 2
  rows, cols = np.mgrid[r0 - half:r0 + half + 1, c0 - half:c0 + half + 1].reshape(2, -1)
  keep = (rows >= 0) & (rows < H) & (cols >= 0) & (cols < W)
  rows, cols = rows[keep], cols[keep]
  pts = _rays(cols.astype(np.float64), rows.astype(np.float64)) * np.asarray(depth, np.float64)[rows, cols, None]
  off = pts - p0
  along = off @ a
  disc = np.sum(off * off, -1) - along**2 <= radius**2
  return np.mean(along[disc]**2)


def test_suction_best_at_top_centre_and_zero_on_edges():
  obs = _box()
  v, u = np.mgrid[0:H, 0:W]
  on_box = np.asarray(obs.mask).ravel()
  uv = np.stack([u.ravel(), v.ravel()], -1)[on_box]  # candidates on the mask, as a policy's
  q = np.asarray(_score(SUCTION, obs, _suction_grasps(uv, TOP)))
  assert np.all(np.isfinite(q)) and q.min() >= 0.0 and q.max() <= 1.0
  best = uv[np.argmax(q)]
  assert tuple(best) in {(31, 31), (31, 32), (32, 31), (32, 32)}  # nearest pixels to the centroid
  np.testing.assert_allclose(q.max(), (math.exp(-math.sqrt(0.5) / 64) - math.exp(-1)) / (1 - math.exp(-1)),
                             rtol=1e-5)
  edge = (uv[:, 0] == COLS[0]) | (uv[:, 0] == COLS[1] - 1) | (uv[:, 1] == ROWS[0]) | (uv[:, 1] == ROWS[1] - 1)
  assert np.all(q[edge] == 0.0)  # the disc straddles the 4 cm step
  assert np.all(q[(uv[:, 0] >= 30) & (uv[:, 0] <= 33) & (uv[:, 1] >= 20) & (uv[:, 1] <= 43)] > 0.5)


def test_suction_ranks_planar_points_by_centroid_distance():
  uv = [(32, 32), (32, 35), (32, 38), (33, 41), (31, 20)]  # increasing distance from (31.5, 31.5)
  q = np.asarray(_score(SUCTION, _box(), _suction_grasps(uv, TOP)))
  assert np.all(q > 0) and np.all(np.diff(q) < 0)
  d = np.hypot(np.array(uv)[:, 1] - 31.5, np.array(uv)[:, 0] - 31.5)
  np.testing.assert_allclose(q, (np.exp(-d / 64) - math.exp(-1)) / (1 - math.exp(-1)), rtol=1e-5)


def test_suction_planarity_decreases_away_from_the_sphere_top():
  u = 31.5 + np.arange(0, 10, 2.0)  # the sphere top is at the principal point
  v = np.full_like(u, 31.5)
  g = _suction_grasps(np.stack([u, v], -1), _sphere_depth(u, v))  # vertical approach
  obs = _sphere()
  q_p = _padded(lambda x: SUCTION.planarity(obs, x), g)
  assert np.all(np.diff(q_p) < 0) and q_p[0] > math.exp(-1) > q_p[-1]  # planar at the top only
  q = np.asarray(_score(SUCTION, obs, g))
  assert q[0] > 0.9 and q[-1] == 0.0


def test_planarity_mse_matches_numpy():
  cases = []
  sphere = _sphere()
  for u, v in [(31.5, 31.5), (36.2, 29.7), (27.0, 38.0), (40.0, 31.0)]:
    z = float(_sphere_depth(u, v))
    n = np.array([0.0, 0.0, FLOOR]) - _rays(np.float64(u), np.float64(v)) * z  # inward normal: the approach
    n /= np.linalg.norm(n)
    angle, psi = math.atan2(-n[0], n[1]), math.acos(n[2])
    cases.append((sphere, (u, v), z, angle, psi))
  box = _box()
  cases += [(box, (27.0, 32.0), TOP, 0.0, 0.0), (box, (33.0, 20.0), TOP, 0.4, 0.3),
            (box, (1.0, 62.0), FLOOR, 0.0, 0.0)]  # an edge, a tilted approach, a window cut by the image corner
  for obs, uv, z, angle, psi in cases:
    got = float(_mse(obs, _suction_grasps(uv, z, angle, psi))[0])
    want = _np_disc_mse(np.asarray(obs.depth), uv, z, angle, psi, SUCTION.cup_radius, SUCTION.window)
    np.testing.assert_allclose(got, want, rtol=2e-4, atol=1e-12)  # float32 points vs float64: ~7e-5
  # a tilted plane approached along its normal is exactly planar
  a = np.array([0.2, -0.3, 0.9]) / np.linalg.norm([0.2, -0.3, 0.9])
  v, u = np.mgrid[0:H, 0:W].astype(np.float64)
  plane = FLOOR * a[2] / (_rays(u, v) @ a)
  g = _suction_grasps((30.0, 34.0), plane[34, 30], math.atan2(-a[0], a[1]), math.acos(a[2]))
  assert float(_mse(observation(jnp.asarray(plane, jnp.float32), CAMERA), g)[0]) < 1e-10


def test_suction_labels_use_each_objects_centroid():
  d = np.full((H, W), FLOOR, np.float32)
  labels = np.zeros((H, W), np.int32)
  for k, cols in enumerate([(10, 22), (40, 52)]):
    d[20:44, cols[0]:cols[1]] = TOP
    labels[20:44, cols[0]:cols[1]] = k + 1
  obs = observation(jnp.asarray(d), CAMERA, jnp.asarray(labels > 0))
  g = _suction_grasps([(45.5, 31.5), (16.0, 31.5), (30.0, 31.5)], [TOP, TOP, FLOOR])  # box 2, box 1, floor
  q_mask = np.asarray(_score(SUCTION, obs, g))
  q_lab = np.asarray(_score(SUCTION.replace(labels=jnp.asarray(labels)), obs, g))
  np.testing.assert_allclose(q_lab[:2], [1.0, (math.exp(-0.5 / 64) - math.exp(-1)) / (1 - math.exp(-1))],
                             rtol=1e-5)
  assert q_lab[2] == 0.0 and q_mask[2] > q_mask[0]  # background: label 0; the mask centroid lies between boxes


def test_instance_jump_segments_the_image_into_the_labelled_objects():
  # Two boxes 5 mm apart in height touch along a column: the depth jump separates them, so the scorers' own
  # instances give the same scores as the true labels; without the jump they are one object (the segmask's).
  d = np.full((H, W), FLOOR, np.float32)
  labels = np.zeros((H, W), np.int32)
  for k, (cols, top) in enumerate([((10, 31), TOP), ((31, 52), TOP - 0.005)]):
    d[20:44, cols[0]:cols[1]] = top
    labels[20:44, cols[0]:cols[1]] = k + 1
  obs = observation(jnp.asarray(d), CAMERA, jnp.asarray(labels > 0))
  g = _suction_grasps([(41.0, 31.5), (20.0, 31.5), (12.0, 25.0)], [TOP - 0.005, TOP, TOP])
  q_lab = np.asarray(_score(SUCTION.replace(labels=jnp.asarray(labels)), obs, g))
  q_own = np.asarray(_score(SUCTION.replace(instance_jump=0.004), obs, g))
  q_merged = np.asarray(_score(SUCTION.replace(instance_jump=0.006), obs, g))
  np.testing.assert_allclose(q_own, q_lab, rtol=1e-6)
  np.testing.assert_allclose(q_merged, np.asarray(_score(SUCTION, obs, g)), rtol=1e-6)
  assert q_own[0] == q_own[1] == 1.0 and q_merged[0] < 1.0
  # The jaws' scorer: a 4 cm box (12 px) held across, another box apart; its own centroid, not the segmask's.
  d = np.full((H, W), FLOOR, np.float32)
  labels = np.zeros((H, W), np.int32)
  d[20:44, 19:31], labels[20:44, 19:31] = TOP, 1
  d[40:60, 40:60], labels[40:60, 40:60] = TOP, 2
  obs = observation(jnp.asarray(d), CAMERA, jnp.asarray(labels > 0))
  pj_g = _pj_grasps([(24.5, 31.5)])
  q_own = _score(PJ.replace(instance_jump=0.004), obs, pj_g)
  np.testing.assert_allclose(q_own, [1.0], rtol=1e-6)
  np.testing.assert_allclose(q_own, _score(PJ.replace(labels=jnp.asarray(labels)), obs, pj_g), rtol=1e-6)
  assert 0.0 < float(_score(PJ, obs, pj_g)[0]) < 0.9


def test_pj_force_closure_across_the_box_best_near_centroid():
  obs = _box()
  g = _pj_grasps([(31.5, 31.5), (31.5, 35.0), (31.5, 39.0), (31.5, 43.0)])
  q = np.asarray(_score(PJ, obs, g))
  assert q[0] == 1.0 and np.all(q > 0) and np.all(np.diff(q) < 0)
  contacts, normals, found, free = _padded(lambda x: PJ.contacts(obs, x), g)
  assert np.all(np.asarray(found)) and np.all(np.asarray(free))
  c = np.asarray(contacts)
  assert np.all(np.floor(c[:, 0, 0] + 0.5) == COLS[0]) and np.all(np.floor(c[:, 1, 0] + 0.5) == COLS[1] - 1)
  np.testing.assert_allclose(normals[:, 0], np.broadcast_to([-1.0, 0.0], (4, 2)), atol=1e-2)  # outward
  np.testing.assert_allclose(normals[:, 1], np.broadcast_to([1.0, 0.0], (4, 2)), atol=1e-2)


def test_pj_zero_scores():
  obs = _box()
  cases = [
      _pj_grasps((31.5, 31.5), angle=math.pi / 2),  # along the 0.099 m box: the jaws land on its top
      _pj_grasps((10.0, 10.0)),  # bare floor: nothing between the jaws
      _pj_grasps((10.0, 10.0), depth=0.72),  # below the floor: the tips collide
      _pj_grasps((31.5, 31.5), depth=0.65),  # above the box: closes on air
      _pj_grasps((31.5, 31.5), angle=math.radians(60), width=0.1),  # 60 deg > arctan 0.8 = 38.7 deg
      _pj_grasps((31.5, 31.5), width=0.1, depth=0.0),  # bad depth
  ]
  for g in cases:
    assert float(_score(PJ, obs, g)[0]) == 0.0
  # the wide-open controls: across the box, and slanted inside the friction cone, are force closure
  inside = _pj_grasps([(31.5, 31.5), (31.5, 31.5)], angle=np.array([0.0, math.radians(30)]), width=0.1)
  assert np.all(np.asarray(_score(PJ, obs, inside)) > 0.99)
  assert float(_score(PJ.replace(friction=0.5), obs, inside)[1]) == 0.0  # 30 deg > arctan 0.5 = 26.6 deg


def test_jit_and_plain_calls_agree_and_never_nan():
  obs = _box()
  rng = np.random.default_rng(0)
  uv = np.concatenate([rng.uniform(-10, 74, (12, 2)), [[np.nan, 3.0], [0.0, 0.0], [63.0, 63.0], [1e9, -1e9]]])
  n = uv.shape[0]
  sg = _suction_grasps(uv, np.where(np.arange(n) == 1, np.nan, TOP), angle=0.3, psi=0.2)
  pg = _pj_grasps(uv, angle=rng.uniform(-3, 3, n), width=np.where(np.arange(n) == 2, np.nan, 0.05))
  for scorer, g in [(SUCTION, sg), (PJ, pg)]:
    q_jit, q = _score(scorer, obs, g), _padded(lambda x: scorer(obs, x), g)
    np.testing.assert_allclose(q_jit, q, rtol=1e-6, atol=1e-7)
    assert q.dtype == np.float32 and q.shape == (n,) and np.all(np.isfinite(q)) and np.all(q >= 0)
    off = ~np.all((uv > -0.5) & (uv < 63.5), axis=-1) | np.isnan(uv).any(-1)
    assert np.all(q[off] == 0.0)
  assert SUCTION.gripper == 'suction' and PJ.gripper == 'parallel_jaw'
  assert suction_window(CAMERA, 0.66) == 9 and suction_window(CAMERA, 0.3, 0.02) == 29


def test_composite_choice():
  pj, suction = GRIPPERS.index('parallel_jaw'), GRIPPERS.index('suction')
  s = jnp.array([0.9, 0.2, 0.0, 0.3, 0.5, jnp.nan])
  p = jnp.array([0.8, 0.8, 0.0, 0.0, 0.9, 0.0])
  np.testing.assert_array_equal(composite_heuristic_choice(s, p), [suction, pj, suction, suction, suction, suction])
  assert int(composite_heuristic_choice(0.6, 0.9, suction_threshold=0.7)) == pj
  # end to end: the flat box top goes to suction; a 3 cm cylinder (curved, narrow) to the jaws
  for obs, want in [(_box(), suction), (_cylinder(), pj)]:
    v, u = np.nonzero(np.asarray(obs.mask))
    uv = np.stack([u, v], -1).astype(np.float32)
    s_best = float(np.max(_score(SUCTION, obs, _suction_grasps(uv, np.asarray(obs.depth)[v, u]))))
    p_best = float(np.max(_score(PJ, obs, _pj_grasps(uv, depth=0.69))))
    assert int(composite_heuristic_choice(s_best, p_best)) == want, (s_best, p_best)


def test_named_heuristics_centre_on_each_objects_depth_instance():
  from dexjax.policy.instances import DEFAULT_MAX_JUMP
  from dexjax.policy.presets import make_policy
  suction = make_policy('suction_heuristic', {}).policies[0].scorer
  composite = make_policy('composite_heuristic', {})
  assert suction.instance_jump == DEFAULT_MAX_JUMP == 0.004 and suction.labels is None
  assert composite.suction.scorer.instance_jump == composite.parallel_jaw.scorer.instance_jump == DEFAULT_MAX_JUMP
  assert SuctionPlanarityCentroid().instance_jump is None  # the scorers' own default stays gqcnn's


# ---------------------------------------------------------------------------------------------------------
# Best-fit approach (`SuctionPlanarityCentroid.refine`).

_FIT = SuctionPlanarityCentroid(window=25, fit_approach=2)  # a 1 cm disc at 0.7 m is 6 px across at fx = 200


def _tilted_plane(normal, noise, seed=0):
  """Observation of the plane through (0, 0, FLOOR) with camera-frame unit ``normal`` (pointing at the camera),
  i.i.d. Gaussian depth noise ``noise`` metres; its true approach is -normal."""
  v, u = np.mgrid[0:H, 0:W].astype(np.float64)
  r = _rays(u, v)
  depth = FLOOR * normal[2] / (r @ normal)  # z of the ray's hit: r t . n = FLOOR n_z with r_z = 1
  depth = depth + noise * np.random.default_rng(seed).standard_normal(depth.shape)
  return observation(jnp.asarray(depth, jnp.float32), CAMERA, jnp.ones((H, W), bool)), depth


def _numpy_fit(depth, center, approach, radius=0.01, iterations=2, half=12):
  """Float64 reference: the disc of the 25 x 25 window about the approach, its SVD plane normal, refitted."""
  col, row = int(round(center[0])), int(round(center[1]))
  v, u = np.mgrid[row - half:row + half + 1, col - half:col + half + 1].astype(np.float64)
  points = (_rays(u, v) * depth[row - half:row + half + 1, col - half:col + half + 1, None]).reshape(-1, 3)
  contact = _rays(np.float64(center[0]), np.float64(center[1])) * depth[row, col]
  for _ in range(iterations):
    offset = points - contact
    along = offset @ approach
    disc = points[np.sum(offset * offset, -1) - along**2 <= radius**2]
    normal = np.linalg.svd(disc - disc.mean(0))[2][-1]
    approach = normal if normal[2] > 0 else -normal
  return approach


def test_refine_turns_noisy_approaches_to_the_disc_plane_normal():
  """On a plane tilted 20 degrees under 0.5 mm i.i.d. noise, each candidate's fitted approach is within 4 degrees
  of the plane's from starts 10-40 degrees off (the disc holds ~26 pixels of this coarse camera: the fit's own
  spread is ~1 degree), equals a float64 SVD fit of the same disc, and centres and depths are kept; ``fit_approach = 0`` (gqcnn) keeps the sampler's approach."""
  tilt = math.radians(20.0)
  normal = np.array([math.sin(tilt), 0.0, -math.cos(tilt)])
  obs, depth = _tilted_plane(normal, noise=0.0005)
  centers = np.array([[20.0, 20.0], [32.0, 32.0], [44.0, 40.0], [25.0, 41.0]], np.float32)
  noisy = np.array([[0.3, 0.1, 0.95], [-0.2, 0.25, 0.9], [0.0, 0.0, 1.0], [0.5, -0.1, 0.8]])
  noisy /= np.linalg.norm(noisy, axis=1, keepdims=True)
  from dexjax.sampling.image_grasps import angles_from_approach, approach_from_angles
  angle, approach_angle = jax.vmap(angles_from_approach)(jnp.asarray(noisy, jnp.float32))
  rows, cols = centers[:, 1].astype(int), centers[:, 0].astype(int)
  grasps = ImageSuctionGrasp(center=jnp.asarray(centers), depth=jnp.asarray(depth[rows, cols], jnp.float32),
                             angle=angle, approach_angle=approach_angle)
  fitted = _padded(lambda g: _FIT.refine(obs, g), grasps)
  got = np.asarray(jax.vmap(approach_from_angles)(jnp.asarray(fitted.angle), jnp.asarray(fitted.approach_angle)))
  truth = -normal
  errors = np.degrees(np.arccos(np.clip(got @ truth, -1, 1)))
  assert np.all(errors < 4.0), errors
  assert np.all(np.degrees(np.arccos(np.clip(noisy @ truth, -1, 1))) > 10.0)  # the starts were far off
  for i in range(len(centers)):
    reference = _numpy_fit(depth, centers[i], noisy[i])
    np.testing.assert_allclose(got[i], reference, atol=2e-3)
  np.testing.assert_array_equal(fitted.center, centers)
  np.testing.assert_array_equal(fitted.depth, np.asarray(grasps.depth))
  kept = SuctionPlanarityCentroid(window=25).refine(obs, grasps)
  np.testing.assert_array_equal(np.asarray(kept.angle), np.asarray(angle))
