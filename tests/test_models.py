"""GQ-CNN models: the Dex-Net 4.0 architecture's exact size, initialisation, and the fully convolutional score map
equal to the patch model at every sampled crop."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dexjax.models import (GQCNN, GQCNNConfig, SUCTION_POSE_DIM, init_gqcnn, num_parameters, score_map,
                           score_map_shape, success_probability)


def test_dexnet4_architecture_has_the_released_parameter_counts():
  """631,410 (parallel jaw) and 631,426 (suction) parameters: the sizes of the released checkpoints (spec 2.2)."""
  assert GQCNNConfig().feature_size() == 17
  pj = jax.eval_shape(lambda k: init_gqcnn(k, GQCNNConfig()), jax.random.key(0))
  suction = jax.eval_shape(lambda k: init_gqcnn(k, GQCNNConfig(pose_dim=SUCTION_POSE_DIM)), jax.random.key(0))
  assert num_parameters(pj) == 631_410 and num_parameters(suction) == 631_426
  assert pj['fc3']['kernel'].shape == (17 * 17 * 16, 128)


def test_initialisation_is_truncated_he_with_a_zero_final_bias():
  params = init_gqcnn(jax.random.key(1), GQCNNConfig())
  kernel = np.asarray(params['fc3']['kernel'])
  sigma = np.sqrt(2.0 / kernel.shape[0])
  assert np.abs(kernel).max() <= 2 * sigma + 1e-7  # truncated at 2 sigma
  # The std of a standard normal truncated to [-2, 2] is 0.8796.
  assert kernel.std() == pytest.approx(0.8796 * sigma, rel=0.02)
  assert np.all(np.asarray(params['fc5']['bias']) == 0) and np.any(np.asarray(params['fc3']['bias']) != 0)
  assert 'bias' not in params['fc4_image']  # one merge bias, as the original


def test_bad_configs_name_the_field():
  with pytest.raises(ValueError, match='crop_size 16 is too small'):
    GQCNNConfig(crop_size=16).validate()
  with pytest.raises(ValueError, match='pool_after'):
    GQCNNConfig(pool_after=(7,)).validate()
  with pytest.raises(ValueError, match='pose_dim'):
    GQCNNConfig(pose_dim=0).validate()


@pytest.mark.parametrize('config', [GQCNNConfig.small(pose_dim=SUCTION_POSE_DIM), GQCNNConfig()],
                         ids=['small', 'dexnet4'])
def test_score_map_equals_the_patch_model_at_every_sampled_crop(config):
  params = init_gqcnn(jax.random.key(2), config)
  s, stride = config.crop_size, 2 ** len(config.pool_after)
  h, w = s + 5 * stride, s + 3 * stride + 2  # a ragged edge: the last columns are not a whole stride
  rng = np.random.default_rng(0)
  image = jnp.asarray(rng.normal(size=(h, w, 1)), jnp.float32)
  pose = jnp.asarray(rng.normal(size=config.pose_dim), jnp.float32)
  scores = np.asarray(jax.jit(score_map, static_argnums=1)(params, config, image, pose))
  assert scores.shape == score_map_shape(config, h, w) == (6, 4)
  cells = [(0, 0), (5, 3), (2, 1), (4, 0), (1, 3)]
  crops = jnp.stack([image[stride * i:stride * i + s, stride * j:stride * j + s] for i, j in cells])
  logits = GQCNN(config).apply({'params': params}, crops, jnp.broadcast_to(pose, (len(cells), config.pose_dim)))
  patch = np.asarray(success_probability(logits))
  np.testing.assert_allclose(scores[tuple(np.array(cells).T)], patch, atol=2e-5)
  assert np.ptp(patch) > 1e-4  # the cells differ, so the match is not trivial
  # One pose per cell gives each cell its own pose.
  poses = jnp.asarray(rng.normal(size=(6, 4, config.pose_dim)), jnp.float32)
  per_cell = np.asarray(score_map(params, config, image, poses))
  logits = GQCNN(config).apply({'params': params}, crops[1:2], poses[5:6, 3])
  assert per_cell[5, 3] == pytest.approx(float(success_probability(logits)[0]), abs=2e-5)


def test_normalization_streams_the_statistics_of_the_concatenation():
  rng = np.random.default_rng(3)
  crops = [rng.normal(0.75, 0.07, size=(n, 8, 8, 1)) for n in (5, 11, 3)]
  crops[1][0, 2, 3, 0] = np.nan  # invalid depth is left out
  poses = [np.c_[rng.normal(0.7, 0.05, len(c)), rng.normal(0.0, 0.6, len(c))] for c in crops]
  from dexjax.models import Normalization, fit_normalization
  norm = fit_normalization(zip(crops, poses))
  every = np.concatenate([c.ravel() for c in crops])
  every = every[np.isfinite(every)]
  all_poses = np.concatenate(poses)
  np.testing.assert_allclose([norm.image_mean, norm.image_std], [every.mean(), every.std()], rtol=1e-5)
  np.testing.assert_allclose(norm.pose_mean, all_poses.mean(0), rtol=1e-5, atol=1e-6)
  np.testing.assert_allclose(norm.pose_std, all_poses.std(0), rtol=1e-5)
  image, pose = norm.apply(jnp.asarray(crops[0]), jnp.asarray(poses[0]))
  np.testing.assert_allclose(np.asarray(image), (crops[0] - every.mean()) / every.std(), rtol=1e-4, atol=1e-5)
  assert pose.shape == (5, 2)
  constant = fit_normalization([(np.full((2, 4, 4), 0.5), np.zeros((2, 1)))])
  assert float(constant.image_std) == 1.0 and float(constant.pose_std[0]) == 1.0
  with pytest.raises(ValueError, match='at least one batch'):
    fit_normalization([])
  assert float(Normalization.identity(2).apply(jnp.ones((1, 4, 4, 1)), jnp.ones((1, 2)))[0].sum()) == 16.0


def test_im_depth_sub_takes_crops_relative_to_the_grasp_depth():
  """input_depth_mode 'im_depth_sub': statistics of crop - grasp depth, and a model that sees a heap moved
  farther from the camera together with its grasp depth only through its pose stream."""
  from dexjax.models import GQCNN, GQCNNConfig, GraspQualityModel, fit_normalization, init_gqcnn
  rng = np.random.default_rng(4)
  crops = [rng.normal(0.75, 0.07, size=(n, 16, 16, 1)) for n in (6, 9)]
  poses = [np.c_[rng.normal(0.7, 0.05, len(c)), rng.normal(0.0, 0.6, len(c))] for c in crops]
  norm = fit_normalization(zip(crops, poses), subtract_depth=True)
  relative = np.concatenate([(c - p[:, :1, None, None]).ravel() for c, p in zip(crops, poses)])
  np.testing.assert_allclose([norm.image_mean, norm.image_std], [relative.mean(), relative.std()], rtol=1e-5)
  config = GQCNNConfig(crop_size=16, conv_filters=(4,), conv_kernels=(3,), pool_after=(0,), fc_size=8,
                       pose_size=4, merge_size=8, pose_dim=2, input_depth_mode='im_depth_sub').validate()
  model = GraspQualityModel(params=init_gqcnn(jax.random.key(0), config), normalization=norm, config=config,
                            gripper='suction', crop_window=16)
  c, p = jnp.asarray(crops[0], jnp.float32), jnp.asarray(poses[0], jnp.float32)
  expected = GQCNN(config).apply({'params': model.params}, ((crops[0] - poses[0][:, :1, None, None]) - relative.mean())
                                 / relative.std(), (poses[0] - norm.pose_mean) / norm.pose_std, train=False)
  np.testing.assert_allclose(np.asarray(model.logits(c, p)), np.asarray(expected), rtol=1e-4, atol=1e-4)
  # The image stream (fc3) sees the same input when the crop and the grasp move 10 cm away together; in
  # 'pose_stream' mode it does not.
  from dexjax.models.feature_analysis import layer_activations
  absolute = GraspQualityModel(params=model.params, normalization=norm, config=dataclasses.replace(
      config, input_depth_mode='pose_stream'), gripper='suction', crop_window=16)
  moved = (c + 0.1, p.at[:, 0].add(0.1))
  for m, invariant in ((model, True), (absolute, False)):
    before, after = layer_activations(m, c, p), layer_activations(m, *moved)
    assert np.allclose(before['fc3'], after['fc3'], atol=1e-4) == invariant
    assert not np.allclose(before['pc1'], after['pc1'], atol=1e-4)
  with pytest.raises(ValueError, match="input_depth_mode: expected one of"):
    GQCNNConfig(input_depth_mode='im_only').validate()


@pytest.fixture(scope="module")
def small_suction_model():
  from dexjax.models import GraspQualityModel, Normalization
  config = GQCNNConfig(crop_size=8, conv_filters=(4,), conv_kernels=(3,), pool_after=(0,), fc_size=8,
                       pose_size=4, merge_size=8, pose_dim=SUCTION_POSE_DIM,
                       input_depth_mode='im_depth_sub').validate()
  norm = Normalization(image_mean=jnp.float32(0.01), image_std=jnp.float32(0.02),
                       pose_mean=jnp.array([0.7, 0.0], jnp.float32), pose_std=jnp.array([0.05, 0.3], jnp.float32))
  return GraspQualityModel(params=init_gqcnn(jax.random.key(3), config), normalization=norm, config=config,
                           gripper='suction', crop_window=8)


def test_symmetric_views_average_the_four_reflections_of_each_grasp(small_suction_model, numpy_symmetric_view):
  """p(success) with ``symmetric_views`` is the mean of the single-view model's p over the identity, the
  180-degree rotation (suction angle negated), the left-right flip and the up-down flip (angle negated), each
  built here in NumPy; it is unchanged when the input itself is one of its views."""
  from dexjax.models import predict
  from dexjax.models.symmetry import NUM_VIEWS, symmetric_views
  single = small_suction_model
  averaged = dataclasses.replace(single, symmetric_views=True)
  rng = np.random.default_rng(0)
  crops = rng.uniform(0.6, 0.8, (5, 8, 8, 1)).astype(np.float32)
  crops[:, 0, :] = crops[:, :, 0] = 0.0  # so that each reflection is undone by itself (nothing is cut off)
  poses = np.c_[rng.uniform(0.6, 0.8, 5), rng.uniform(-0.5, 0.5, 5)].astype(np.float32)
  flags = [(False, False, False), (True, False, False), (False, True, False), (False, False, True)]
  expected = np.zeros(5)
  for rotate, flip_lr, flip_ud in flags:
    view = np.stack([numpy_symmetric_view(c, rotate, flip_lr, flip_ud) for c in crops])
    angle = poses[:, 1] * (-1.0 if rotate != flip_ud else 1.0)
    expected += np.asarray(predict(single, jnp.asarray(view), jnp.asarray(np.c_[poses[:, 0], angle]))) / NUM_VIEWS
  got = np.asarray(predict(averaged, jnp.asarray(crops), jnp.asarray(poses)))
  np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)
  assert not np.allclose(got, np.asarray(predict(single, jnp.asarray(crops), jnp.asarray(poses))), atol=1e-4)
  view_crops, view_poses = symmetric_views(jnp.asarray(crops[0]), jnp.asarray(poses[0]), suction=True)
  assert view_crops.shape == (NUM_VIEWS, 8, 8, 1) and view_poses.shape == (NUM_VIEWS, 2)
  for k in range(NUM_VIEWS):
    again = np.asarray(predict(averaged, view_crops[k:k + 1], view_poses[k:k + 1]))
    np.testing.assert_allclose(again, got[:1], rtol=1e-5, atol=1e-6)


def test_symmetric_views_are_saved_with_the_model(small_suction_model, tmp_path):
  from dexjax.models import load, load_model_file, save_model, save_model_file
  averaged = dataclasses.replace(small_suction_model, symmetric_views=True)
  for model in (small_suction_model, averaged):
    from_file = load_model_file(save_model_file(tmp_path / f'{model.symmetric_views}.msgpack', model))
    from_orbax = load(save_model(tmp_path / f'orbax-{model.symmetric_views}', 1, model).parent)
    assert from_file.symmetric_views == from_orbax.symmetric_views == model.symmetric_views
