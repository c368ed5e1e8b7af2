"""GQ-CNN training pieces: the optimiser schedule, a step that lowers the loss, overfitting 64 examples, and the
validation metrics against a brute-force reference (scikit-learn for the bootstrap)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dexjax.models import GQCNNConfig
from dexjax.train import (OptimizerConfig, average_precision, bootstrap_intervals, classification_metrics, create_state,
                          cross_entropy, eval_logits, make_optimizer, train_step)
from dexjax.train.metrics import _resampled_metrics

SMALL = GQCNNConfig.small()
_step = jax.jit(train_step)
_logits = jax.jit(eval_logits)


def _batch(seed: int, n: int = 64) -> dict:
  """Crops with a raised square (label 1) or a pit (label 0) at a random place, plus noise: learnable."""
  rng = np.random.default_rng(seed)
  labels = rng.integers(0, 2, n)
  crops = rng.normal(0.0, 0.3, (n, 32, 32, 1))
  for i, label in enumerate(labels):
    r, c = rng.integers(4, 20, 2)
    crops[i, r:r + 8, c:c + 8, 0] += 1.0 if label else -1.0
  return {'crops': jnp.asarray(crops, jnp.float32), 'poses': jnp.asarray(rng.normal(size=(n, 1)), jnp.float32),
          'labels': jnp.asarray(labels, jnp.int32)}


def test_learning_rate_decays_by_095_every_half_epoch_and_weight_decay_is_l2():
  params = {'w': jnp.full(3, 2.0)}
  # No momentum, no decay, unit gradient: the update is -lr(step); 10 steps per epoch -> a decay every 5 steps.
  tx = make_optimizer(OptimizerConfig(momentum=0.0, weight_decay=0.0), steps_per_epoch=10)
  state, rates = tx.init(params), []
  for _ in range(12):
    updates, state = tx.update({'w': jnp.ones(3)}, state, params)
    rates.append(-float(updates['w'][0]))
  np.testing.assert_allclose(rates, [0.01] * 5 + [0.0095] * 5 + [0.009025] * 2, rtol=1e-5)
  # Zero gradient: the update is the weight decay alone, -lr * 5e-4 * w (biases are ordinary parameters).
  tx = make_optimizer(OptimizerConfig(momentum=0.0), steps_per_epoch=10)
  updates, _ = tx.update({'w': jnp.zeros(3)}, tx.init(params), params)
  np.testing.assert_allclose(np.asarray(updates['w']), -0.01 * 5e-4 * 2.0, rtol=1e-5)
  # Momentum 0.9 (classical): the second update of a constant gradient is lr * (1 + 0.9).
  tx = make_optimizer(OptimizerConfig(weight_decay=0.0), steps_per_epoch=100)
  state = tx.init(params)
  _, state = tx.update({'w': jnp.ones(3)}, state, params)
  updates, _ = tx.update({'w': jnp.ones(3)}, state, params)
  assert -float(updates['w'][0]) == pytest.approx(0.01 * 1.9, rel=1e-5)


def test_one_step_lowers_the_loss_on_a_fixed_batch():
  batch = _batch(0)
  state = create_state(jax.random.key(0), SMALL, make_optimizer(OptimizerConfig(), steps_per_epoch=100))
  before = float(cross_entropy(_logits(state, batch), batch['labels']))
  state, stats = _step(state, batch, jax.random.key(1))
  after = float(cross_entropy(_logits(state, batch), batch['labels']))
  assert float(stats['loss']) == pytest.approx(before, rel=1e-5)
  assert after < before and int(state.step) == 1


def test_overfits_64_examples():
  batch = _batch(1)
  state = create_state(jax.random.key(2), SMALL, make_optimizer(OptimizerConfig(learning_rate=0.05), 100))
  for i in range(150):
    state, _ = _step(state, batch, jax.random.key(i))
  accuracy = float(jnp.mean(jnp.argmax(_logits(state, batch), -1) == batch['labels']))
  assert accuracy >= 0.95


def _brute_force_ap(scores, labels):
  """AP as the mean over positives of the precision at the positive's score threshold (ties included)."""
  precisions = []
  for s in scores[labels == 1]:
    chosen = scores >= s
    precisions.append(labels[chosen].mean())
  return float(np.mean(precisions))


def test_metrics_match_brute_force_definitions():
  rng = np.random.default_rng(5)
  for _ in range(20):
    n = int(rng.integers(5, 40))
    scores = np.round(rng.uniform(size=n), 1)  # many ties
    labels = rng.integers(0, 2, n)
    if labels.sum() == 0:
      labels[0] = 1
    assert average_precision(scores, labels) == pytest.approx(_brute_force_ap(scores, labels))
    m = classification_metrics(scores, labels)
    pred = scores > 0.5
    assert m['accuracy'] == pytest.approx(np.mean(pred == labels))
    tpr = np.mean(pred[labels == 1])
    tnr = np.mean(~pred[labels == 0]) if np.any(labels == 0) else None
    assert m['recall'] == pytest.approx(tpr)
    assert m['balanced_accuracy'] == pytest.approx(np.mean([r for r in (tpr, tnr) if r is not None]))
  perfect = classification_metrics(np.array([0.9, 0.8, 0.1]), np.array([1, 1, 0]))
  assert perfect['average_precision'] == 1.0 and perfect['balanced_accuracy'] == 1.0
  empty = classification_metrics(np.array([0.2, 0.3]), np.array([0, 0]))
  assert empty['average_precision'] is None and empty['precision'] is None and empty['recall'] is None


def test_resampled_metrics_equal_scikit_learn_on_the_replicated_rows():
  from sklearn.metrics import average_precision_score, balanced_accuracy_score  # pylint: disable=g-import-not-at-top
  rng = np.random.default_rng(2)
  n, num_groups = 400, 23
  groups = rng.integers(0, num_groups, n)
  labels = rng.random(n) < 0.3
  scores = np.round(np.clip(0.3 * labels + 0.7 * rng.random(n), 0, 1), 2)  # ties across and within groups
  counts = rng.integers(0, 3, (7, num_groups))
  balanced, ap = _resampled_metrics(scores, labels, groups, counts)
  for r in range(len(counts)):
    rows = np.repeat(np.arange(n), counts[r][groups])  # each group's rows as often as it was drawn
    assert balanced[r] == pytest.approx(balanced_accuracy_score(labels[rows], scores[rows] > 0.5), abs=1e-12)
    assert ap[r] == pytest.approx(average_precision_score(labels[rows], scores[rows]), abs=1e-12)


def test_bootstrap_interval_of_independent_rows_is_the_binomial_one():
  rng = np.random.default_rng(3)
  n, p = 4000, 0.8
  labels = np.arange(n) % 2 == 0
  right = rng.random(n) < p
  scores = np.where(right == labels, 0.9, 0.1)
  result = bootstrap_intervals(scores, labels, np.arange(n), num_resamples=2000)
  lo, hi = result['balanced_accuracy']
  centre = classification_metrics(scores, labels)['balanced_accuracy']
  half = 1.96 * np.sqrt(centre * (1 - centre) / n)  # Var of (TPR + TNR) / 2 with n / 2 rows per class
  assert lo < centre < hi
  assert (hi - lo) / 2 == pytest.approx(half, rel=0.15)
  assert result['groups'] == n and result['resamples'] == 2000 and result['level'] == 0.95
  assert bootstrap_intervals(scores, labels, np.arange(n), num_resamples=2000) == result  # seeded


def test_bootstrap_resamples_whole_groups():
  rng = np.random.default_rng(4)
  n, copies = 300, 10
  labels = rng.random(n) < 0.4
  scores = np.clip(0.4 * labels + 0.6 * rng.random(n), 0, 1)
  single = bootstrap_intervals(scores, labels, np.arange(n))
  # Every row ten times, the copies in one group: the same data as far as the bootstrap is concerned.
  grouped = bootstrap_intervals(np.repeat(scores, copies), np.repeat(labels, copies), np.repeat(np.arange(n), copies))
  for key in ('balanced_accuracy', 'average_precision'):
    np.testing.assert_allclose(grouped[key], single[key], atol=1e-12)
  # Treated as independent, the copies would claim an interval about sqrt(10) times too narrow.
  naive = bootstrap_intervals(np.repeat(scores, copies), np.repeat(labels, copies), np.arange(n * copies))
  ratio = np.diff(single['balanced_accuracy'])[0] / np.diff(naive['balanced_accuracy'])[0]
  assert 2.5 < ratio < 4.0
  assert bootstrap_intervals(scores, np.zeros(n), np.arange(n))['average_precision'] is None  # no positives
  assert bootstrap_intervals(scores, labels, np.zeros(n))['balanced_accuracy'] is None  # one group
  empty = bootstrap_intervals(np.zeros(0), np.zeros(0), np.zeros(0))
  assert empty['groups'] == 0 and empty['balanced_accuracy'] is None and empty['average_precision'] is None
  with pytest.raises(ValueError, match='0 < level < 1'):
    bootstrap_intervals(scores, labels, np.arange(n), level=95)
  with pytest.raises(ValueError, match='one shape'):
    bootstrap_intervals(scores, labels, np.arange(n - 1))


def test_symmetrize_matches_reflections_about_the_grasp_pixel_and_negates_suction_angles(numpy_symmetric_view):
  from dexjax.train.data import symmetrize
  s = 8
  crop = np.arange(1, s * s + 1, dtype=np.float32).reshape(s, s, 1)
  pose = jnp.array([0.7, 0.3], jnp.float32)
  sym = jax.jit(symmetrize, static_argnums=3)
  seen = set()
  for seed in range(100):
    key = jax.random.key(seed)
    out, out_pose = sym(key, jnp.asarray(crop), pose, True)
    flips = tuple(bool(x) for x in np.asarray(jax.random.bernoulli(key, 0.5, (3,))))
    seen.add(flips)
    np.testing.assert_array_equal(np.asarray(out), numpy_symmetric_view(crop, *flips))
    assert out[s // 2, s // 2, 0] == crop[s // 2, s // 2, 0]  # the grasp pixel stays put
    rotate, _, flip_ud = flips
    assert float(out_pose[1]) == pytest.approx(-0.3 if rotate != flip_ud else 0.3)
    assert float(out_pose[0]) == pytest.approx(0.7)
  assert len(seen) == 8
  _, jaw_pose = sym(jax.random.key(0), jnp.asarray(crop), pose[:1], False)
  assert float(jaw_pose[0]) == pytest.approx(0.7)


def test_gripper_examples_crop_at_the_grasp_with_pose_and_label():
  from dexjax.train.data import gripper_examples
  rng = np.random.default_rng(0)
  depth = rng.uniform(0.6, 0.8, (3, 40, 40)).astype(np.float32)
  depth[1, 5, 5] = np.nan
  batch = {'depth': depth, 'gripper': np.array([0, 1, 1], np.int8),
           'center': np.array([[20, 20], [12, 30], [25, 9]], np.float32), 'angle': np.array([0.3, 0.0, 1.2], np.float32),
           'grasp_depth': np.array([0.7, 0.71, 0.72], np.float32),
           'approach_angle': np.array([0.0, 0.2, 0.4], np.float32), 'reward': np.array([1, 0, 1], np.int8),
           'robust_probability': np.array([0.9, 0.8, 0.6], np.float32)}
  jaw = gripper_examples(batch, 'parallel_jaw', crop_size=16)
  cup = gripper_examples(batch, 'suction', crop_size=16)
  assert jaw['crops'].shape == (1, 16, 16, 1) and cup['crops'].shape == (2, 16, 16, 1)
  assert jaw['crops'][0, 8, 8, 0] == depth[0, 20, 20]
  assert cup['crops'][0, 8, 8, 0] == depth[1, 30, 12] and cup['crops'][1, 8, 8, 0] == depth[2, 9, 25]
  assert np.all(np.isfinite(cup['crops']))
  np.testing.assert_allclose(cup['poses'], [[0.71, 0.2], [0.72, 0.4]])
  assert jaw['poses'].shape == (1, 1) and list(cup['labels']) == [0, 1] and list(jaw['labels']) == [1]
  with pytest.raises(ValueError, match='gripper'):
    gripper_examples(batch, 'claw')


@pytest.mark.parametrize('window, size', [(24, 24), (24, 8)])
def test_crops_from_grasp_patches_equal_crops_of_the_whole_image(window, size):
  """Patches cut around the grasps (object arrays of shared images, grasps near and past the border) give the
  same crops as `grasp_crop` on the whole image, nearest (equal sizes) and bilinear (resampled)."""
  from dexjax.sampling import grasp_crop
  from dexjax.train.data import grasp_patches, gripper_examples
  rng = np.random.default_rng(3)
  images = [rng.uniform(0.5, 0.9, (30, 41)).astype(np.float32) for _ in range(2)]
  centers = np.array([[20.3, 14.7], [1.2, 2.0], [40.5, 29.9], [-3.0, 10.0], [10.0, 5.5]], np.float32)
  angles = rng.uniform(-np.pi, np.pi, 5).astype(np.float32)
  which = [0, 1, 0, 1, 1]
  depth = np.empty(5, object)
  for k, i in enumerate(which):
    depth[k] = images[i]
  batch = {'depth': depth, 'gripper': np.zeros(5, np.int8), 'center': centers, 'angle': angles,
           'grasp_depth': np.full(5, 0.7, np.float32), 'approach_angle': np.zeros(5, np.float32),
           'reward': np.zeros(5, np.int8), 'robust_probability': np.zeros(5, np.float32)}
  crops = gripper_examples(batch, 'parallel_jaw', crop_size=size, crop_window=window)['crops'][..., 0]
  scale, interpolation = (1.0, 'nearest') if window == size else (size / window, 'bilinear')
  for k, i in enumerate(which):
    expected = grasp_crop(jnp.asarray(images[i]), jnp.asarray(centers[k]), jnp.asarray(angles[k]), window, scale,
                          interpolation)
    np.testing.assert_allclose(crops[k], np.asarray(expected), atol=1e-5)  # float32 centre shift
  patches, local = grasp_patches(depth, centers, window)
  assert patches.shape[1] >= window * np.sqrt(2) and np.all(patches[3][:, :2] == 0)  # left of the image: 0
  np.testing.assert_allclose(local - centers, np.round(local - centers), atol=1e-5)  # integer shifts only


def test_soft_targets_are_the_robust_probability_where_robustness_decided():
  from dexjax.quality.heap_reward import REWARD_FAILURES
  from dexjax.train import soft_labels
  failures = np.array([REWARD_FAILURES.index(n) for n in
                       ('none', 'not_robust', 'collision_object', 'collision_bin', 'multiple_objects')], np.int8)
  rows = {'failure': failures, 'robust_probability': np.array([0.9, 0.3, 0.8, 0.7, 0.95], np.float32)}
  np.testing.assert_allclose(soft_labels(rows), [0.9, 0.3, 0.0, 0.0, 0.0])
  logits = jnp.array([[0.2, 1.0], [1.5, -0.5], [0.0, 0.0]])
  labels = jnp.array([1, 0, 1])
  # Hard soft-labels are the integer loss; a soft one is -(1 - s) log p0 - s log p1 (checked in NumPy).
  np.testing.assert_allclose(cross_entropy(logits, labels, soft_labels=labels.astype(jnp.float32)),
                             cross_entropy(logits, labels), rtol=1e-6)
  s = np.array([0.7, 0.2, 0.5])
  logp = np.log(np.exp(np.asarray(logits)) / np.exp(np.asarray(logits)).sum(1, keepdims=True))
  w = np.array([1.0, 2.0, 0.0])
  expected = (w * -((1 - s) * logp[:, 0] + s * logp[:, 1])).sum() / w.sum()
  np.testing.assert_allclose(cross_entropy(logits, labels, jnp.asarray(w), jnp.asarray(s)), expected, rtol=1e-5)
  from dexjax.train import train_config_from_dict
  from dexjax.config import ConfigError
  assert train_config_from_dict({'loop': {'target': 'robust_probability'}}, 'x.yaml').loop.target == 'robust_probability'
  with pytest.raises(ConfigError, match=r"x.yaml: loop.label_draws: expected an integer in \[1, 10,000\]"):
    train_config_from_dict({'loop': {'target': 'label_probability', 'label_draws': 0}}, 'x.yaml').validate('x.yaml')
  with pytest.raises(ConfigError, match="x.yaml: loop.target: expected one of"):
    train_config_from_dict({'loop': {'target': 'soft'}}, 'x.yaml').validate('x.yaml')


def test_label_probability_is_the_binomial_tail_and_soft_targets_are_balanced_in_expectation():
  """`label_probability`: P(a reward of M draws is positive) = P(Binomial(M, p) > threshold M), against SciPy.
  Soft targets are class-balanced as the expected class-balanced loss over their labels: weight w and target t
  with w CE(t, q) = s w+ (-log q) + (1 - s) w- (-log(1 - q)) for every prediction q."""
  from scipy.stats import binom
  from dexjax.train import LoopConfig, label_probability
  from dexjax.train.batches import _balanced_soft_targets
  p = np.linspace(0.0, 1.0, 41)
  for draws, threshold in ((10, 0.5), (7, 0.5), (20, 0.3)):
    np.testing.assert_allclose(label_probability(p, draws, threshold), binom.sf(np.floor(threshold * draws), draws, p),
                               atol=1e-6)
  assert label_probability(np.array([0.5]), 10)[0] == pytest.approx(386 / 1024)  # 6..10 of 10: (210+120+45+10+1)/2^10
  s = np.array([0.0, 0.3, 0.55, 1.0], np.float32)
  for loop in (LoopConfig(target='robust_probability'), LoopConfig(target='label_probability', label_draws=10)):
    target, weight = _balanced_soft_targets(s, loop, 4.0, 0.6)
    want = s if loop.target == 'robust_probability' else binom.sf(5, 10, s)
    for q in (0.1, 0.5, 0.9):
      got = weight * -(target * np.log(q) + (1 - target) * np.log(1 - q))
      np.testing.assert_allclose(got, -(want * 4.0 * np.log(q) + (1 - want) * 0.6 * np.log(1 - q)), rtol=1e-5)


def test_a_step_on_soft_targets_lowers_the_soft_loss():
  batch = _batch(0)
  batch['soft_labels'] = jnp.clip(batch['labels'] * 0.8 + 0.1, 0.0, 1.0)
  state = create_state(jax.random.key(0), SMALL, make_optimizer(OptimizerConfig(), steps_per_epoch=100))
  soft = lambda st: float(cross_entropy(_logits(st, batch), batch['labels'], soft_labels=batch['soft_labels']))
  before = soft(state)
  state, stats = _step(state, batch, jax.random.key(1))
  assert float(stats['loss']) == pytest.approx(before, rel=1e-5) and soft(state) < before
