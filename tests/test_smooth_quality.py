"""The smooth robust quality (`dexjax.quality.smooth`) and grasp optimisation on it: the limit of the hard metric,
gradients against central finite differences and exact geometry, and ascent judged by the hard metric."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dexjax.geometry.sdf import first_crossing, ray_cast
from dexjax.geometry.transforms import so3_exp
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality import (parallel_jaw_perturbations, robust_parallel_jaw_quality, robust_suction_quality,
                            suction_perturbations)
from dexjax.quality.grasp_optimization import AscentSettings, move_grasp
from dexjax.quality.grasp_quality import QualityConfig
from dexjax.quality.robust import sample_attempt
from dexjax.quality.smooth import (Smoothing, parallel_jaw_margins, smooth_parallel_jaw_quality,
                                   smooth_robust_parallel_jaw_quality, smooth_robust_suction_quality,
                                   smooth_suction_quality, soft_pass, suction_margins)
from dexjax.sampling.object_samplers import sample_antipodal_grasps, sample_suction_grasps

WIDE = ParallelJawGripper(max_width=0.08, palm_width=0.1)  # opens around the 6 cm builtin sphere
DRAWS = 8


def _take(tree, mask, count):
  idx = np.flatnonzero(np.asarray(mask))[:count]
  return jax.tree.map(lambda x: x[idx], tree)


def _away_from_box_edges(points, extents, margin):
  """(N,) bool: every point (N, K, 3) lies on a face of the centred box with ``extents``, at least ``margin``
  from that face's edges (its two in-face coordinates)."""
  half = np.asarray(extents) / 2
  p = np.asarray(points)
  on_face = np.abs(np.abs(p) - half) < 2e-3  # (N, K, 3): which coordinate sits on a face
  inside = np.abs(p) < half - margin
  return np.all(np.sum(on_face, -1) == 1, -1) & np.all(np.sum(on_face | inside, -1) == 3, -1)


# --- contact search gradients ----------------------------------------------------------------------------------

def test_crossing_gradients_match_the_exact_sphere(sphere):
  """A jaw closing along x at height y on the sphere of radius R = 3 cm meets it at t = 0.1 - sqrt(R^2 - y^2):
  dt/dy = y / sqrt(R^2 - y^2), for the line search and the ray cast alike (implicit gradient on the tangent
  plane of the interpolated normal)."""
  def crossing(y):
    t, _, _, _ = first_crossing(sphere, jnp.array([-0.1, y, 0.0]), jnp.array([1.0, 0.0, 0.0]), 0.2, 64)
    return t

  def ray(y):
    return ray_cast(sphere, jnp.array([-0.1, y, 0.0]), jnp.array([1.0, 0.0, 0.0]))[0]

  for f in (crossing, ray):
    grad = jax.jit(jax.grad(f))
    for y in (0.004, 0.01, 0.015, 0.02):
      exact = y / np.sqrt(0.03**2 - y**2)
      assert float(grad(y)) == pytest.approx(exact, rel=0.03), (f.__name__, y)


# --- the hard limit ------------------------------------------------------------------------------------------------

def _sampled(sampler, models):
  """[(model, up to 24 valid grasps of 48 sampled)] for each model."""
  return [(model, _take(*sampler(jax.random.key(0), model, 48), 24)) for model in models]


@pytest.fixture(scope="module")
def pj_grasps(box, cylinder):
  return _sampled(sample_antipodal_grasps, (box, cylinder))


@pytest.fixture(scope="module")
def suction_grasps(box, cylinder):
  return _sampled(sample_suction_grasps, (box, cylinder))


@functools.partial(jax.jit, static_argnames=("suction",))
def _per_draw(model, grasps, keys, smoothing, suction):
  """(hard resists (N, M), smooth pass (N, M)) of N grasps on the robust quality's own draws (M = DRAWS)."""
  from dexjax.quality.gripper_geometry import NEAREST_SAMPLES, nearest_jaw_samples

  def one(key, grasp):
    if suction:
      p = suction_perturbations(DRAWS)
      hard = robust_suction_quality(key, model, grasp, perturbations=p).outcomes.resists
      smooth = lambda g, c: smooth_suction_quality(model, g, SuctionGripper(), c, smoothing=smoothing)
    else:
      p = parallel_jaw_perturbations(DRAWS)
      hard = robust_parallel_jaw_quality(key, model, grasp, perturbations=p).outcomes.resists
      samples = nearest_jaw_samples(model, grasp, ParallelJawGripper(), QualityConfig().geometry, NEAREST_SAMPLES)
      smooth = lambda g, c: smooth_parallel_jaw_quality(model, g, ParallelJawGripper(), c, smoothing=smoothing,
                                                        jaw_samples=samples)
    return hard, jax.vmap(lambda k: smooth(*sample_attempt(k, grasp, p)))(jax.random.split(key, DRAWS))

  return jax.vmap(one)(keys, grasps)


@pytest.mark.parametrize("suction", [False, True], ids=["parallel_jaw", "suction"])
def test_low_temperature_recovers_the_hard_metric(suction, pj_grasps, suction_grasps):
  """At temperature 0 the smooth pass is the hard pass on every draw; at 1e-3 its pass / fail (> 0.5) agrees on
  at least 99 % of them; at the default temperature it is a smooth, different function."""
  results = {}
  for temperature in (0.0, 1e-3, 1.0):
    hard, smooth = [], []
    for model, grasps in (suction_grasps if suction else pj_grasps):
      keys = jax.random.split(jax.random.key(7), grasps.center.shape[0])
      h, s = _per_draw(model, grasps, keys, Smoothing(jnp.float32(temperature)), suction)
      hard.append(np.asarray(h).ravel())
      smooth.append(np.asarray(s).ravel())
    results[temperature] = (np.concatenate(hard), np.concatenate(smooth))
  hard, exact = results[0.0]
  assert 0.05 < hard.mean() < 0.95  # both outcomes occur
  np.testing.assert_array_equal(exact, hard.astype(np.float32))
  _, cold = results[1e-3]
  assert np.mean((cold > 0.5) == hard) >= 0.99
  _, warm = results[1.0]
  assert np.mean((warm > 1e-3) & (warm < 1 - 1e-3)) > 0.05  # not a step any more


# --- gradients against central differences -------------------------------------------------------------------------

def _central_difference(f, x, h):
  x = np.asarray(x, np.float64)
  out = np.zeros_like(x)
  for i in range(x.size):
    e = np.zeros_like(x)
    e[i] = h
    out[i] = (float(f(jnp.asarray(x + e, jnp.float32))) - float(f(jnp.asarray(x - e, jnp.float32)))) / (2 * h)
  return out


def _moved_quality(model, grasp, translation, rotation, gripper):
  """Smooth robust quality (fixed draws) of ``grasp`` moved by (translation, rotation) (`move_grasp`)."""
  moved = move_grasp(grasp, translation, rotation)
  if isinstance(grasp, SuctionGrasp):
    return smooth_robust_suction_quality(jax.random.key(3), model, moved, gripper)
  return smooth_robust_parallel_jaw_quality(jax.random.key(3), model, moved, gripper)


_moved_value = jax.jit(_moved_quality)
_moved_gradient = jax.jit(jax.grad(_moved_quality, argnums=(2, 3)))


def _check_pose_gradients(model, grasp, gripper, h_translation=1e-4, h_rotation=3e-4, rel=0.1):
  """Gradient of the quality of ``grasp`` moved by (t, omega), at (0, 0), against central differences: within
  10 % of the largest component (plus 5e-3 per radian for turns, which change little on a sphere)."""
  zero = jnp.zeros(3, jnp.float32)
  grads = _moved_gradient(model, grasp, zero, zero, gripper)
  for index, (grad, h, floor) in enumerate(zip(grads, (h_translation, h_rotation), (0.0, 5e-3))):
    def f(v, index=index):
      return _moved_value(model, grasp, v if index == 0 else zero, v if index == 1 else zero, gripper)
    grad = np.asarray(grad)
    fd = _central_difference(f, np.zeros(3), h)
    scale = max(np.abs(fd).max(), np.abs(grad).max())
    if index == 0:
      assert scale > 0.05, (grad, fd)  # a non-trivial gradient
    np.testing.assert_allclose(grad, fd, atol=rel * scale + floor)


def _on_the_slope(model, grasps, candidates, gripper, count=2):
  """The first ``count`` grasps among ``candidates`` (indices) whose smooth quality is in (0.05, 0.95): where the
  gradient says something."""
  chosen = []
  zero = jnp.zeros(3, jnp.float32)
  for i in candidates:
    grasp = jax.tree.map(lambda x: x[i], grasps)
    if 0.05 < float(_moved_value(model, grasp, zero, zero, gripper)) < 0.95:
      chosen.append(grasp)
    if len(chosen) == count:
      break
  assert len(chosen) == count
  return chosen


def test_suction_gradients_match_central_differences_on_the_sphere_and_box_faces(sphere, box):
  """Sampled suction grasps with their approach tilted off the normal (so the seal and the torques depend on the
  pose), on the sphere and on the box's faces at least 1.5 cm from an edge."""
  tilt = jax.vmap(so3_exp)(0.2 * jnp.asarray(np.random.default_rng(0).normal(size=(64, 3)), jnp.float32))
  for model in (sphere, box):
    grasps, valid = sample_suction_grasps(jax.random.key(1), model, 64)
    grasps = grasps.replace(approach=jnp.einsum('nij,nj->ni', tilt, grasps.approach))
    keep = np.array(valid)
    if model is box:
      keep &= _away_from_box_edges(np.asarray(grasps.center)[:, None], box.extents, 0.015)
    for grasp in _on_the_slope(model, grasps, np.flatnonzero(keep), SuctionGripper()):
      _check_pose_gradients(model, grasp, SuctionGripper())


def test_parallel_jaw_gradients_match_central_differences_on_the_sphere_and_box_faces(sphere, box):
  """Sampled antipodal grasps on the sphere (a gripper that opens to 8 cm) and on the box, with both contacts
  on faces at least 8 mm from an edge."""
  from dexjax.contacts.parallel_jaw import close_jaws
  grasps, valid = sample_antipodal_grasps(jax.random.key(1), sphere, 32, gripper=WIDE)
  for grasp in _on_the_slope(sphere, grasps, np.flatnonzero(np.asarray(valid)), WIDE):
    _check_pose_gradients(sphere, grasp, WIDE)
  grasps, valid = sample_antipodal_grasps(jax.random.key(2), box, 96, gripper=WIDE)
  points = jax.vmap(lambda g: close_jaws(box, g, WIDE).points)(grasps)
  faces = np.asarray(valid) & _away_from_box_edges(points, box.extents, 0.008)
  for grasp in _on_the_slope(box, grasps, np.flatnonzero(faces), WIDE):  # one gripper: one compiled program
    _check_pose_gradients(box, grasp, WIDE)


@jax.jit
def _design_quality(model, grasp, gripper, perturbations):
  if isinstance(grasp, SuctionGrasp):
    return smooth_robust_suction_quality(jax.random.key(4), model, grasp, gripper, perturbations)
  return smooth_robust_parallel_jaw_quality(jax.random.key(4), model, grasp, gripper, perturbations)


def test_gripper_parameter_gradients_match_central_differences(cylinder):
  """Design studies: d quality / d (cup radius, elastic limit, jaw force limit, fingertip radius) and / d (mean
  friction, mean mass) of the perturbations, each against a central difference of that field."""
  suction = SuctionGrasp(center=jnp.array([0.01, 0.0, 0.04]), approach=jnp.array([0.0, 0.0, -1.0]))
  pj = ParallelJawGrasp(center=jnp.zeros(3), axis=jnp.array([1.0, 0.0, 0.0]), approach=jnp.array([0.0, 0.0, -1.0]),
                        width=jnp.float32(0.08))  # across the 5 cm cylinder, below its top
  weak = ParallelJawGripper(max_width=0.08, palm_width=0.1, force_limit=3.0)
  slippery = parallel_jaw_perturbations(DRAWS, friction_mean=0.5)
  cases = [  # (grasp, gripper, perturbations, which of the two gets the field, field, step)
      (suction, SuctionGripper(), suction_perturbations(DRAWS), 0, 'cup_radius', 1e-4),
      (suction, SuctionGripper(), suction_perturbations(DRAWS), 0, 'elastic_limit', 0.02),
      (suction, SuctionGripper(), suction_perturbations(DRAWS), 1, 'mass_mean', 5e-3),
      (pj, weak, slippery, 0, 'force_limit', 0.05),
      (pj, weak, slippery, 0, 'finger_radius', 1e-4),
      (pj, weak, slippery, 1, 'friction_mean', 5e-3),
      (pj, weak, slippery, 1, 'mass_mean', 5e-3),
  ]
  grad_fn = jax.jit(jax.grad(_design_quality, argnums=(2, 3)))
  for grasp, gripper, perturbations, which, field, h in cases:
    gripper = jax.tree.map(jnp.float32, gripper)
    perturbations = jax.tree.map(jnp.float32, perturbations)
    grad = float(getattr(grad_fn(cylinder, grasp, gripper, perturbations)[which], field))
    parts = [gripper, perturbations]
    base = float(getattr(parts[which], field))

    def f(v):
      changed = list(parts)
      changed[which] = parts[which].replace(**{field: jnp.float32(v[0])})
      return _design_quality(cylinder, grasp, *changed)

    fd = float(_central_difference(f, np.array([base]), h)[0])
    assert np.isfinite(grad), field
    assert grad == pytest.approx(fd, rel=0.1, abs=0.02 * max(1.0, abs(fd))), field
    assert abs(fd) > 0.01, field  # every case is on the slope


def test_gradients_are_finite_for_misses_collisions_and_edges(box_with_hole):
  """Random poses around an object with a hole: every test fails somewhere, no gradient is NaN."""
  rng = np.random.default_rng(0)
  n = 32
  dirs = rng.normal(size=(n, 3))
  dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
  perp = np.cross(dirs, rng.normal(size=(n, 3)))
  perp /= np.linalg.norm(perp, axis=1, keepdims=True)
  centers = rng.uniform(-0.05, 0.05, (n, 3))
  pj = ParallelJawGrasp(center=jnp.asarray(centers, jnp.float32), axis=jnp.asarray(dirs, jnp.float32),
                        approach=jnp.asarray(perp, jnp.float32), width=jnp.full((n,), 0.05, jnp.float32))
  su = SuctionGrasp(center=jnp.asarray(centers, jnp.float32), approach=jnp.asarray(dirs, jnp.float32))
  key = jax.random.key(0)
  for quality, grasps in ((smooth_robust_parallel_jaw_quality, pj), (smooth_robust_suction_quality, su)):
    grads = jax.jit(jax.vmap(jax.grad(lambda g: quality(key, box_with_hole, g))))(grasps)
    for leaf in jax.tree.leaves(grads):
      assert np.all(np.isfinite(np.asarray(leaf)))


def test_margins_are_the_hard_tests(box):
  """The margins' signs are the hard tests: a suction grasp off the box misses, one in the middle of the top
  face seals; jaws started inside the box collide."""
  cond = sample_attempt(jax.random.key(0), SuctionGrasp(center=jnp.zeros(3), approach=jnp.array([0.0, 0.0, -1.0])),
                        suction_perturbations())[1]
  margins = jax.jit(suction_margins)
  top = margins(box, SuctionGrasp(center=jnp.array([0.0, 0.0, 0.02]), approach=jnp.array([0.0, 0.0, -1.0])),
                        SuctionGripper(), cond)
  assert float(top.contact) > 0 and float(top.holes) > 0 and float(top.strain) > 0 and float(top.lip) > 0
  off = margins(box, SuctionGrasp(center=jnp.array([0.09, 0.0, 0.02]), approach=jnp.array([0.0, 0.0, -1.0])),
                        SuctionGripper(), cond)
  assert float(off.contact) < 0 and float(soft_pass(off, Smoothing(0.0))) == 0.0
  # A cup 5 mm from the +x edge overhangs it by 5 mm: the lip margin is minus that overhang (the ray through the
  # farthest lip point passes the side face at that distance), and the smooth pass climbs back onto the face.
  over = lambda x: SuctionGrasp(center=jnp.array([x, 0.0, 0.02]), approach=jnp.array([0.0, 0.0, -1.0]))
  edge = margins(box, over(0.035), SuctionGripper(), cond)
  assert -0.0055 < float(edge.lip) < -0.0035 and float(soft_pass(edge, Smoothing(0.0))) == 0.0
  slope = jax.jit(jax.grad(lambda x: soft_pass(suction_margins(box, over(x), SuctionGripper(), cond))))(0.035)
  assert float(slope) < 0  # inwards (-x) raises it
  inside = ParallelJawGrasp(center=jnp.zeros(3), axis=jnp.array([1.0, 0.0, 0.0]), approach=jnp.array([0.0, 0.0, -1.0]),
                            width=jnp.float32(0.05))
  m = jax.jit(parallel_jaw_margins)(box, inside, ParallelJawGripper(), cond)
  assert np.all(np.asarray(m.jaw_start) < 0)  # both jaws start inside the 8 cm box


# --- optimisation ------------------------------------------------------------------------------------------------------

def test_move_grasp_is_a_rigid_motion_and_the_identity_at_zero():
  g = ParallelJawGrasp(center=jnp.array([0.01, 0.02, 0.03]), axis=jnp.array([1.0, 0.0, 0.0]),
                       approach=jnp.array([0.0, 0.0, -1.0]), width=jnp.float32(0.05))
  same = move_grasp(g, jnp.zeros(3), jnp.zeros(3))
  for a, b in zip(jax.tree.leaves(same), jax.tree.leaves(g)):
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-7)
  moved = move_grasp(g, jnp.array([0.001, 0.0, 0.0]), jnp.array([0.0, 0.0, np.pi / 2]))
  np.testing.assert_allclose(np.asarray(moved.center), [0.011, 0.02, 0.03], atol=1e-7)
  np.testing.assert_allclose(np.asarray(moved.axis), [0.0, 1.0, 0.0], atol=1e-6)  # x turned 90 degrees about z
  assert abs(float(jnp.dot(moved.axis, moved.approach))) < 1e-6


# The ascent on an unseen object (procedural:L1/4@23, 16 starts, 20 steps, judged by 100 independent draws) is
# tested by running notebooks/gradients.ipynb: tests/test_notebook_gradients.py.


def test_the_ascent_guard_keeps_the_start_when_the_last_iterate_is_worse(box):
  """`optimize_grasp`'s final guard: of a cup centred on the box's top face and one overhanging its edge by 5 mm,
  the centred one is returned whichever of the two is the start."""
  from dexjax.quality.grasp_optimization import _guarded
  centred = SuctionGrasp(center=jnp.array([0.0, 0.0, 0.02]), approach=jnp.array([0.0, 0.0, -1.0]))
  over = SuctionGrasp(center=jnp.array([0.035, 0.0, 0.02]), approach=jnp.array([0.0, 0.0, -1.0]))
  guarded = jax.jit(lambda start, final: _guarded(jax.random.key(0), start, final, 20, AscentSettings(), box,
                                                  SuctionGripper(), suction_perturbations(), QualityConfig()))
  for start, final in ((centred, over), (over, centred)):
    np.testing.assert_array_equal(np.asarray(guarded(start, final).center), np.asarray(centred.center))
  unguarded = _guarded(jax.random.key(0), centred, over, 20, AscentSettings(guard_samples=0), box, SuctionGripper(),
                       suction_perturbations(), QualityConfig())
  assert unguarded is over
