"""Policies on analytic depth images with known optima: CEM against ranking with the same number of evaluations,
the ambidextrous choice, feature round trips, poses, the GQ-CNN scorer's crops against the training crops, and
jit / vmap / plain calls agreeing.

Scene: a camera 0.7 m above a floor; a raised disc (top at 0.66 m) whose rim gives antipodal edge pairs in every
direction. The synthetic scorers are pytrees peaked at one pixel (and, for the parallel jaw, one angle).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from dexjax.models import GQCNNConfig, GraspQualityModel, Normalization, init_gqcnn
from dexjax.policy.candidates import grasp_features, grasps_from_features, sample_candidates
from dexjax.policy.cem import CEMParams, CEMPolicy
from dexjax.policy.composite import GreedyComposite, RandomComposite, plan_grasp
from dexjax.policy.observation import observation
from dexjax.policy.ranking import RandomPolicy, RankingPolicy
from dexjax.policy.scorers import GQCNNScorer, PARALLEL_JAW, SUCTION
from dexjax.render.camera import Camera, Intrinsics, look_at
from dexjax.sampling.image_grasps import ImageParallelJawGrasp
from dexjax.sampling.image_samplers import AntipodalImageSampler, SuctionImageSampler, sample_antipodal_image_grasps
from dexjax.train.data import gripper_examples

H = W = 96
FLOOR, TOP = 0.7, 0.66
DISC_CENTER, DISC_RADIUS = np.array([47.0, 49.0]), 6.0  # (u, v), pixels: 0.04 m across, under the 0.05 m jaws
_K = Intrinsics(fx=200.0, fy=200.0, cx=47.5, cy=47.5, width=W, height=H)
_EYE = jnp.array([0.0, 0.0, FLOOR])
CAMERA = Camera(_K, look_at(_EYE, jnp.zeros(3)), _EYE)
PJ = AntipodalImageSampler(boundary=6.0, downsample=1, num_edges=256, num_grasps=60)
SUCTION_SAMPLER = SuctionImageSampler(boundary=6.0, num_grasps=60)
SMALL_CEM = CEMParams(num_seed=60, num_resample=20, num_components=3, em_iterations=10)


def _disc_observation(mask_disc: bool = True):
  v, u = np.mgrid[0:H, 0:W]
  inside = (u - DISC_CENTER[0]) ** 2 + (v - DISC_CENTER[1]) ** 2 <= DISC_RADIUS ** 2
  depth = np.where(inside, TOP, FLOOR).astype(np.float32)
  return observation(depth, CAMERA, inside if mask_disc else None)


DISC = _disc_observation()
FLAT = observation(np.full((H, W), FLOOR, np.float32), CAMERA)


@struct.dataclass
class PeakScorer:
  """exp(-|c - c*|^2 / (2 sigma^2)) (times cos^2 of the angle error for the parallel jaw): one optimum."""

  target: jax.Array
  angle: jax.Array
  sigma: float
  gripper: str = struct.field(pytree_node=False, default=SUCTION)

  def __call__(self, obs, grasps):
    q = jnp.exp(-jnp.sum((grasps.center - self.target) ** 2, axis=-1) / (2 * self.sigma ** 2))
    return q * jnp.cos(grasps.angle - self.angle) ** 2 if self.gripper == PARALLEL_JAW else q


@struct.dataclass
class ConstantScorer:
  value: float
  gripper: str = struct.field(pytree_node=False, default=SUCTION)

  def __call__(self, obs, grasps):
    return jnp.full(grasps.center.shape[:1], self.value, jnp.float32)


@struct.dataclass
class RecentringScorer(ConstantScorer):
  """A constant score, with the optional ``refine`` of the scorer protocol moving every candidate to ``target``."""

  target: jax.Array = None

  def refine(self, obs, grasps):
    return grasps.replace(center=jnp.broadcast_to(self.target, grasps.center.shape))


_plan = jax.jit(plan_grasp, static_argnames='samples')
_vplan = jax.jit(jax.vmap(plan_grasp, in_axes=(0, None, None)))


def _keys(n, seed=0):
  return jax.random.split(jax.random.key(seed), n)


BIG = 200  # a 200 x 200 floor: ~35,000 admissible pixels, so 400 uniform draws land ~5 px from a peak
_BIG_K = Intrinsics(fx=200.0, fy=200.0, cx=99.5, cy=99.5, width=BIG, height=BIG)
BIG_FLAT = observation(np.full((BIG, BIG), FLOOR, np.float32), Camera(_BIG_K, CAMERA.rotation, CAMERA.position))


def test_cem_finds_a_peaked_optimum_far_better_than_ranking_with_as_many_evaluations():
  """The seed's CEM (n 250, m 3, c 50, k 5, gamma 0.25) against ranking 400 uniform candidates (as many scorer
  calls): its last set concentrates on the optimum (5x closer than uniform draws), and the best grasp it scored
  beats the ranking's best on average. (With m = 3 the last set is still ~10 px wide: its best grasp is not
  better than the ranking's, which is why ``select='best'`` exists.)"""
  target = jnp.array([70.0, 120.0])
  scorer = PeakScorer(target, jnp.float32(0.0), 5.0)
  params = CEMParams(em_iterations=10)
  evaluations = params.num_seed + params.num_iterations * params.num_resample
  ranking = RankingPolicy(scorer, SUCTION_SAMPLER.replace(num_grasps=evaluations))
  keys = _keys(12)
  last = jax.vmap(lambda k: plan_grasp(k, BIG_FLAT, GreedyComposite((CEMPolicy(scorer, SUCTION_SAMPLER, params),)),
                                       samples=True))
  a_last = jax.jit(last)(keys)
  a_best = _vplan(keys, BIG_FLAT, GreedyComposite((CEMPolicy(scorer, SUCTION_SAMPLER, params.replace(select='best')),)))
  a_rank = _vplan(keys, BIG_FLAT, ranking)
  assert np.all(a_last.valid) and np.all(a_best.valid) and np.all(a_rank.valid)
  distance = lambda c: np.linalg.norm(np.asarray(c) - np.asarray(target), axis=-1)
  final = a_last.samples
  d_final = distance(final.center[:, 0, -1])[np.asarray(final.valid[:, 0, -1])]
  d_uniform = distance(final.center[:, 0, 0])[np.asarray(final.valid[:, 0, 0])]
  assert np.median(d_final) < 0.2 * np.median(d_uniform), (np.median(d_final), np.median(d_uniform))
  d_best, d_rank = distance(a_best.center), distance(a_rank.center)
  assert np.median(d_best) < np.median(d_rank), (d_best, d_rank)
  assert np.mean(a_best.probability) > np.mean(a_rank.probability)
  # 'last' (gqcnn's rule) returns the best of the final set only: never better than 'best' with the same draws.
  assert np.all(np.asarray(a_last.probability) <= np.asarray(a_best.probability) + 1e-6)


def test_parallel_jaw_cem_optimises_pixel_and_angle():
  target, angle = jnp.array([DISC_CENTER[0] + 3.0, DISC_CENTER[1] - 2.0]), jnp.float32(0.6)
  scorer = PeakScorer(target, angle, 3.0, gripper=PARALLEL_JAW)
  cem = CEMPolicy(scorer, PJ, SMALL_CEM)
  ranking = RankingPolicy(scorer, PJ.replace(num_grasps=120))
  keys = _keys(8, seed=1)
  a_cem, a_rank = _vplan(keys, DISC, cem), _vplan(keys, DISC, ranking)
  assert np.all(a_cem.valid)
  assert np.mean(a_cem.probability) > np.mean(a_rank.probability) + 0.08
  assert np.median(np.linalg.norm(np.asarray(a_cem.center) - np.asarray(target), axis=-1)) < 2.0
  error = np.abs((np.asarray(a_cem.angle) - float(angle) + np.pi / 2) % np.pi - np.pi / 2)  # jaws: mod pi
  assert np.median(error) < 0.25
  # The CEM also refines the depth, but only within the sampler's range below the surface.
  assert np.all((np.asarray(a_cem.depth) >= TOP + PJ.min_depth_offset - 1e-5)
                & (np.asarray(a_cem.depth) <= TOP + PJ.max_depth_offset + 1e-5))


def test_features_round_trip_and_decoded_grasps_stay_on_the_mask():
  grasps, valid = sample_candidates(jax.random.key(3), DISC, PJ)
  assert int(valid.sum()) > 10
  decoded, ok = grasps_from_features(DISC, grasp_features(DISC, grasps), PJ)
  np.testing.assert_allclose(decoded.center[valid], grasps.center[valid], atol=1e-4)
  np.testing.assert_allclose(np.cos(decoded.angle - grasps.angle)[valid], 1.0, atol=1e-5)
  np.testing.assert_allclose(decoded.depth[valid], grasps.depth[valid], atol=1e-6)
  assert np.all(ok[valid])
  off = jnp.array([[5.0, 5.0, 9.0, 5.0, 0.68], [40.0, 49.0, 54.0, 49.0, 0.68]])  # off the disc; on it
  assert list(np.asarray(grasps_from_features(DISC, off, PJ)[1])) == [False, True]
  suction, ok_s = grasps_from_features(DISC, jnp.array([[47.2, 48.8], [10.0, 10.0]]), SUCTION_SAMPLER)
  assert list(np.asarray(ok_s)) == [True, False]
  np.testing.assert_allclose(suction.center[0], [47.0, 49.0])
  assert float(suction.depth[0]) == pytest.approx(TOP) and float(suction.approach_angle[0]) < 1e-3


def test_jaw_candidates_between_two_objects_are_not_centred_off_the_mask():
  """Two 4-pixel-wide blocks 5 pixels apart: their facing edges are antipodal, so the sampler pairs them, but the
  midpoint lies in the gap; such candidates are invalid (grasp centres stay on the mask)."""
  depth = np.full((H, W), FLOOR, np.float32)
  depth[30:60, 40:44] = depth[30:60, 49:53] = TOP
  obs = observation(depth, CAMERA, depth < FLOOR)
  grasps, valid = sample_candidates(jax.random.key(0), obs, PJ.replace(num_grasps=200))
  center = np.floor(np.asarray(grasps.center) + 0.5).astype(int)
  assert np.all(np.asarray(obs.mask)[center[:, 1], center[:, 0]][np.asarray(valid)])
  raw = sample_antipodal_image_grasps(jax.random.key(0), obs.depth, CAMERA, PJ.replace(num_grasps=200), obs.mask)
  assert np.any(np.asarray(raw[1]) & ~np.asarray(valid))  # the sampler alone does centre some in the gap


def test_ambidextrous_policy_returns_the_gripper_of_higher_probability():
  for p_jaw, p_suction, expected in ((0.3, 0.7, 1), (0.8, 0.4, 0)):
    policy = GreedyComposite((CEMPolicy(ConstantScorer(p_jaw, PARALLEL_JAW), PJ, SMALL_CEM),
                              CEMPolicy(ConstantScorer(p_suction), SUCTION_SAMPLER, SMALL_CEM)))
    action = _plan(jax.random.key(0), DISC, policy)
    assert bool(action.valid) and int(action.gripper) == expected
    assert float(action.probability) == pytest.approx(max(p_jaw, p_suction))
    np.testing.assert_allclose(action.per_gripper.probability, [p_jaw, p_suction], rtol=1e-6)
    assert list(np.asarray(action.per_gripper.gripper)) == [0, 1]


def test_no_candidates_gives_an_invalid_action_not_nan():
  empty = observation(DISC.depth, CAMERA, jnp.zeros((H, W), bool))
  policy = GreedyComposite((CEMPolicy(ConstantScorer(0.5, PARALLEL_JAW), PJ, SMALL_CEM),
                            CEMPolicy(ConstantScorer(0.5), SUCTION_SAMPLER, SMALL_CEM)))
  action = _plan(jax.random.key(0), empty, policy)
  assert not bool(action.valid) and not np.any(np.asarray(action.per_gripper.valid))
  assert np.all(np.isfinite(np.asarray(action.pose)))


def test_poses_follow_the_camera_frame_conventions():
  grasp = ImageParallelJawGrasp(center=jnp.array([60.0, 40.0]), angle=jnp.float32(0.5), depth=jnp.float32(0.68),
                                width=jnp.float32(0.05))
  from dexjax.policy.actions import action_from_grasp  # pylint: disable=g-import-not-at-top
  pose = np.asarray(action_from_grasp(DISC, grasp, jnp.float32(0.9), jnp.bool_(True)).pose)
  point = np.array([(60.0 - 47.5) / 200.0 * 0.68, (40.0 - 47.5) / 200.0 * 0.68, 0.68])
  np.testing.assert_allclose(pose[:3, 3], point, atol=1e-6)
  np.testing.assert_allclose(pose[:3, 0], [0, 0, 1], atol=1e-6)  # x = approach = optical axis
  np.testing.assert_allclose(pose[:3, 1], [math.cos(0.5), math.sin(0.5), 0], atol=1e-6)  # y = jaw axis
  np.testing.assert_allclose(pose[:3, :3].T @ pose[:3, :3], np.eye(3), atol=1e-6)


def test_jit_vmap_and_plain_calls_agree():
  policy = GreedyComposite((CEMPolicy(PeakScorer(jnp.array([47.0, 45.0]), jnp.float32(0.3), 4.0, PARALLEL_JAW),
                                      PJ, SMALL_CEM),
                            CEMPolicy(PeakScorer(jnp.array([40.0, 50.0]), jnp.float32(0.0), 4.0), SUCTION_SAMPLER,
                                      SMALL_CEM)))
  keys = _keys(2, seed=5)
  batched = _vplan(keys, DISC, policy)
  for i in range(2):
    plain = plan_grasp(keys[i], DISC, policy)
    jitted = _plan(keys[i], DISC, policy)
    for a in (plain, jitted):
      assert int(a.gripper) == int(batched.gripper[i])
      np.testing.assert_allclose(a.center, batched.center[i], atol=1e-3)
      np.testing.assert_allclose(a.probability, batched.probability[i], rtol=1e-4, atol=1e-6)


def test_cem_samples_record_every_round():
  action = _plan(jax.random.key(2), DISC,
                 GreedyComposite((CEMPolicy(PeakScorer(jnp.array([47.0, 45.0]), jnp.float32(0.3), 4.0,
                                                       PARALLEL_JAW), PJ, SMALL_CEM),)), samples=True)
  s = action.samples
  assert s.valid.shape == (1, SMALL_CEM.num_iterations + 1, SMALL_CEM.num_seed)
  assert int(s.valid[0, 0].sum()) > 0 and not np.any(np.asarray(s.valid[0, 1:, SMALL_CEM.num_resample:]))
  best_per_round = np.max(np.where(s.valid[0], s.quality[0], -np.inf), axis=-1)
  assert best_per_round[-1] >= best_per_round[0] and float(action.probability) == pytest.approx(best_per_round[-1])


def test_ranking_scores_and_returns_the_candidates_a_scorer_refines():
  """A scorer's optional ``refine`` (`dexjax.policy.scorers.refined_candidates`) turns the candidates before the
  ranking policy scores them, under jit too; a scorer without one gets the sampled candidates."""
  target = jnp.array([40.0, 50.0])
  refined = _plan(jax.random.key(3), DISC, RankingPolicy(RecentringScorer(0.5, target=target), SUCTION_SAMPLER))
  assert bool(refined.valid) and float(refined.probability) == pytest.approx(0.5)
  np.testing.assert_allclose(refined.center, target)
  sampled = _plan(jax.random.key(3), DISC, RankingPolicy(ConstantScorer(0.5), SUCTION_SAMPLER))
  assert bool(sampled.valid) and not np.allclose(sampled.center, target)


def test_random_policy_draws_valid_candidates_of_both_grippers():
  policy = RandomComposite((RandomPolicy(PJ), RandomPolicy(SUCTION_SAMPLER, ConstantScorer(0.25))))
  actions = _vplan(_keys(24, seed=7), DISC, policy)
  assert np.all(actions.valid)
  grippers = np.asarray(actions.gripper)
  assert 0 < grippers.sum() < len(grippers)  # both grippers drawn
  np.testing.assert_allclose(np.asarray(actions.probability)[grippers == 1], 0.25)
  assert np.all(np.isnan(np.asarray(actions.probability)[grippers == 0]))  # no scorer: no probability


@pytest.mark.parametrize('window, gripper', [(32, SUCTION), (96, PARALLEL_JAW)])
def test_gqcnn_scorer_uses_the_training_crops(window, gripper):
  config = GQCNNConfig.small(pose_dim=2 if gripper == SUCTION else 1)
  model = GraspQualityModel(params=init_gqcnn(jax.random.key(0), config),
                            normalization=Normalization(jnp.float32(0.68), jnp.float32(0.02),
                                                        jnp.full(config.pose_dim, 0.5), jnp.ones(config.pose_dim)),
                            config=config, gripper=gripper, crop_window=window)
  sampler = PJ if gripper == PARALLEL_JAW else SUCTION_SAMPLER
  grasps, valid = sample_candidates(jax.random.key(4), DISC, sampler)
  n = int(valid.sum())
  rows = {'gripper': np.full(n, 0 if gripper == PARALLEL_JAW else 1), 'center': np.asarray(grasps.center)[valid],
          'angle': np.asarray(grasps.angle)[valid], 'grasp_depth': np.asarray(grasps.depth)[valid],
          'approach_angle': np.asarray(getattr(grasps, 'approach_angle', grasps.depth))[valid],
          'depth': np.stack([np.asarray(DISC.depth)] * n), 'reward': np.zeros(n), 'robust_probability': np.zeros(n)}
  examples = gripper_examples(rows, gripper, config.crop_size, window)
  scorer = GQCNNScorer(model)
  np.testing.assert_allclose(np.asarray(scorer.crops(DISC, grasps))[np.asarray(valid)], examples['crops'], atol=3e-5)
  expected = model(examples['crops'], examples['poses'])
  np.testing.assert_allclose(np.asarray(scorer(DISC, grasps))[np.asarray(valid)], expected, atol=1e-5)
  assert np.ptp(np.asarray(expected)) > 1e-4


def test_bad_policy_settings_name_the_field():
  with pytest.raises(ValueError, match='CEMParams.elite_fraction'):
    CEMParams(elite_fraction=0.0).validate()
  with pytest.raises(ValueError, match='CEMParams.num_seed'):
    CEMParams(num_seed=0).validate()
  with pytest.raises(ValueError, match='one sub-policy per gripper'):
    plan_grasp(jax.random.key(0), DISC, GreedyComposite((RandomPolicy(PJ), RandomPolicy(PJ))))
