"""Gradient polishing of image grasps (`dexjax.policy.polish`): the GQ-CNN's smooth score against the scorer and
central differences, a climb to a known optimum within the trust region and the masks, and the CEM policy with
polishing never below the same CEM without it.

Scene: a camera 0.7 m above a floor (200 x 200 pixels) with a smooth bump and a tilt, so crops and normals vary
continuously; networks are untrained quick-start GQ-CNNs (96-pixel windows resampled to 32 x 32).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from dexjax.models import GQCNNConfig, GraspQualityModel, Normalization, init_gqcnn
from dexjax.policy import make_policy
from dexjax.policy.candidates import grasps_from_features, sample_candidates
from dexjax.policy.cem import CEMParams, CEMPolicy
from dexjax.policy.composite import GreedyComposite, plan_grasp
from dexjax.policy.observation import observation
from dexjax.policy.polish import PolishParams, moved_grasps, polish_grasps
from dexjax.policy.scorers import PARALLEL_JAW, SUCTION, GQCNNScorer
from dexjax.render.camera import Camera, Intrinsics, look_at
from dexjax.sampling.image_grasps import ImageParallelJawGrasp
from dexjax.sampling.image_samplers import AntipodalImageSampler, SuctionImageSampler, surface_normals

N = 200
FLOOR = 0.7
_K = Intrinsics(fx=250.0, fy=250.0, cx=99.5, cy=99.5, width=N, height=N)
_EYE = jnp.array([0.0, 0.0, FLOOR])
CAMERA = Camera(_K, look_at(_EYE, jnp.zeros(3)), _EYE)
PJ_SAMPLER = AntipodalImageSampler(boundary=50.0, downsample=1, num_edges=256, num_grasps=40)
SUCTION_SAMPLER = SuctionImageSampler(boundary=50.0, num_grasps=40)


def _scene(mask=None):
  v, u = np.mgrid[0:N, 0:N].astype(np.float32)
  bump = 0.03 * np.exp(-((u - 95.0) ** 2 + (v - 104.0) ** 2) / (2 * 14.0 ** 2))
  boxes = np.where((np.abs(u - 120) < 10) & (np.abs(v - 80) < 6), 0.025, 0.0)  # an edge for the jaws
  depth = FLOOR - bump - boxes + 0.0002 * (u - 100.0)
  return observation(depth.astype(np.float32), CAMERA, mask)


SCENE = _scene()


def _model(gripper: str, seed: int = 0) -> GraspQualityModel:
  pose_dim = 2 if gripper == SUCTION else 1
  config = GQCNNConfig.small(pose_dim=pose_dim)
  norm = Normalization(jnp.float32(0.69), jnp.float32(0.01), jnp.full(pose_dim, 0.3), jnp.full(pose_dim, 0.2))
  return GraspQualityModel(init_gqcnn(jax.random.key(seed), config), norm, config, gripper, 96)


@struct.dataclass
class SmoothPeak:
  """p = 0.9 exp(-|c - c*|^2 / (2 sigma^2)) (x cos^2 of the angle error for the parallel jaw): a known optimum,
  differentiable, so its ``smooth`` is itself."""

  target: jax.Array
  angle: jax.Array
  sigma: float
  gripper: str = struct.field(pytree_node=False, default=SUCTION)

  def __call__(self, obs, grasps):
    q = 0.9 * jnp.exp(-jnp.sum((grasps.center - self.target) ** 2, axis=-1) / (2 * self.sigma ** 2))
    return q * jnp.cos(grasps.angle - self.angle) ** 2 if self.gripper == PARALLEL_JAW else q

  def smooth(self, obs, grasps):
    return self(obs, grasps)


def _pj_starts(centers, angles):
  centers = jnp.asarray(centers, jnp.float32)
  k = centers.shape[0]
  return ImageParallelJawGrasp(center=centers, angle=jnp.asarray(angles, jnp.float32),
                               depth=jnp.full(k, FLOOR + 0.02, jnp.float32), width=jnp.full(k, 0.05, jnp.float32))


def _suction_starts(centers):
  decoded, ok = grasps_from_features(SCENE, jnp.asarray(centers, jnp.float32), SUCTION_SAMPLER)
  assert np.all(ok)
  return decoded


@pytest.mark.parametrize('gripper', [PARALLEL_JAW, SUCTION])
def test_smooth_score_is_the_scorer_and_its_gradient_matches_central_differences(gripper):
  scorer = GQCNNScorer(_model(gripper))
  sampler = PJ_SAMPLER if gripper == PARALLEL_JAW else SUCTION_SAMPLER
  grasps, valid = sample_candidates(jax.random.key(1), SCENE, sampler)
  grasps = jax.tree.map(lambda a: a[np.flatnonzero(np.asarray(valid))[:6]], grasps)
  # A 96-pixel window resampled to 32: the smooth score is the scorer's own.
  np.testing.assert_allclose(np.asarray(scorer.smooth(SCENE, grasps)), np.asarray(scorer(SCENE, grasps)), atol=1e-6)
  params = PolishParams()
  normals = surface_normals(CAMERA, SCENE.depth)
  # At zero offset the moved grasps are the starts (suction: re-read at integer pixels, as the sampler reads).
  same = moved_grasps(SCENE, grasps, jnp.zeros((6, 2 if gripper == SUCTION else 4)), params, normals)
  for a, b in zip(jax.tree.leaves(same), jax.tree.leaves(grasps)):
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=2e-4)
  rng = np.random.default_rng(0)
  x = jnp.asarray(rng.uniform(-0.8, 0.8, (6, 2 if gripper == SUCTION else 4)), jnp.float32)
  logit = lambda x: jnp.log(scorer.smooth(SCENE, moved_grasps(SCENE, grasps, x, params, normals)))
  f = jax.jit(lambda x: jnp.sum(logit(x)))
  grad = np.asarray(jax.grad(f)(x))
  eps = 2e-3
  numeric = np.zeros_like(grad)
  for i in range(grad.shape[0]):
    for j in range(grad.shape[1]):
      e = np.zeros(grad.shape, np.float32)
      e[i, j] = eps
      numeric[i, j] = (float(f(x + e)) - float(f(x - e))) / (2 * eps)
  assert np.abs(grad).max() > 1e-3  # the network sees the grasp move
  # Bilinear crops and ReLUs are piecewise linear: a difference straddling a kink averages two slopes.
  np.testing.assert_allclose(grad, numeric, atol=0.1 * np.abs(numeric).max())
  assert np.corrcoef(grad.ravel(), numeric.ravel())[0, 1] > 0.99


def test_polish_climbs_to_a_known_optimum_within_its_trust_region_and_the_mask():
  target = jnp.array([100.0, 100.0])
  params = PolishParams(steps=25, max_shift=8.0)
  # Parallel jaw: pixel and angle converge (depth has no gradient here and stays).
  pj = SmoothPeak(target, jnp.float32(0.4), 6.0, gripper=PARALLEL_JAW)
  starts = _pj_starts([[104.0, 97.0], [96.5, 103.0], [100.0, 94.5], [115.0, 100.0]], [0.2, 0.7, 0.45, 0.4])
  q0 = pj(SCENE, starts)
  out, q = jax.jit(polish_grasps, static_argnames=())(SCENE, starts, q0, pj, PJ_SAMPLER, params)
  centers = np.asarray(out.center)
  distance = np.linalg.norm(centers - np.asarray(target), axis=-1)
  assert np.all(distance[:3] < 0.7), distance
  assert np.all(np.abs(np.asarray(out.angle)[:3] - 0.4) < 0.03), out.angle
  assert np.linalg.norm(centers[3] - [115.0, 100.0]) <= 8.0 + 1e-4  # 15 px away: stopped at the trust region
  assert distance[3] == pytest.approx(7.0, abs=0.2)
  np.testing.assert_allclose(np.asarray(q), np.asarray(pj(SCENE, out)), rtol=1e-6)
  assert np.all(np.asarray(q) >= np.asarray(q0))
  # Suction: centres snap to pixels; a mask that excludes the optimum keeps every grasp on the mask.
  v, u = np.mgrid[0:N, 0:N]
  masked = _scene(mask=(u <= 97))
  suction = SmoothPeak(target, jnp.float32(0.0), 6.0)
  starts = _suction_starts([[104.0, 97.0], [95.0, 103.0], [100.0, 94.0]])
  out, q = polish_grasps(SCENE, starts, suction(SCENE, starts), suction, SUCTION_SAMPLER, params)
  assert np.all(np.linalg.norm(np.asarray(out.center) - np.asarray(target), axis=-1) < 1e-6)
  np.testing.assert_allclose(np.asarray(out.depth), np.asarray(SCENE.depth)[100, 100], rtol=1e-6)
  left = _suction_starts([[92.0, 97.0], [95.0, 103.0]])
  out, q = polish_grasps(masked, left, suction(masked, left), suction, SUCTION_SAMPLER, params)
  assert np.all(np.asarray(out.center)[:, 0] <= 97) and np.all(np.asarray(out.center)[:, 0] >= 95)
  # An invalid start (score -inf) is returned unchanged.
  out, q = polish_grasps(SCENE, starts, jnp.array([-jnp.inf, 0.1, 0.1]), suction, SUCTION_SAMPLER, params)
  assert np.asarray(q)[0] == -np.inf and np.array_equal(np.asarray(out.center)[0], np.asarray(starts.center)[0])


def test_cem_with_polish_never_scores_below_the_same_cem_and_often_above():
  """With the same key the CEM draws the same sets, so polishing can only raise the chosen grasp's probability."""
  models = {PARALLEL_JAW: _model(PARALLEL_JAW, 3), SUCTION: _model(SUCTION, 4)}
  cem = CEMParams(num_seed=40, num_resample=16, num_components=2, em_iterations=5)
  samplers = {PARALLEL_JAW: PJ_SAMPLER, SUCTION: SUCTION_SAMPLER}
  base = GreedyComposite(tuple(CEMPolicy(GQCNNScorer(models[g]), samplers[g], cem) for g in (PARALLEL_JAW, SUCTION)))
  polished = base.replace(policies=tuple(p.replace(polish=PolishParams(num_grasps=4, steps=4))
                                         for p in base.policies))
  plan = jax.jit(jax.vmap(lambda k, policy: plan_grasp(k, SCENE, policy), in_axes=(0, None)))
  keys = jax.random.split(jax.random.key(5), 4)
  a, b = plan(keys, base), plan(keys, polished)
  qa, qb = np.asarray(a.per_gripper.probability), np.asarray(b.per_gripper.probability)
  assert np.all(np.asarray(a.valid)) and np.all(np.asarray(b.valid))
  assert np.all(qb >= qa - 1e-6), (qa, qb)
  assert np.mean(qb > qa + 1e-4) >= 0.5, (qa, qb)
  assert np.all(np.asarray(SCENE.mask)[np.round(np.asarray(b.center)[:, 1]).astype(int),
                                       np.round(np.asarray(b.center)[:, 0]).astype(int)])


def test_bad_polish_settings_name_the_field():
  with pytest.raises(ValueError, match='PolishParams.steps'):
    PolishParams(steps=0).validate()
  with pytest.raises(ValueError, match='PolishParams.max_shift'):
    PolishParams(max_shift=-1.0).validate()
  models = {PARALLEL_JAW: _model(PARALLEL_JAW), SUCTION: _model(SUCTION)}
  with pytest.raises(ValueError, match="only the CEM policies"):
    make_policy('ranking', models, polish=PolishParams())
  with pytest.raises(TypeError, match='smooth'):
    polish_grasps(SCENE, _suction_starts([[100.0, 100.0]]), jnp.zeros(1), lambda obs, g: jnp.zeros(1),
                  SUCTION_SAMPLER)
