"""GQ-CNN training pieces: the optimiser schedule, a step that lowers the loss, overfitting 64 examples, and the
validation metrics against a brute-force reference."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dexjax.models import GQCNNConfig
from dexjax.train import (OptimizerConfig, average_precision, classification_metrics, create_state, cross_entropy,
                          eval_logits, make_optimizer, train_step)

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
