"""One jitted GQ-CNN training step (spec section 3): cross-entropy on label = robust probability > 0.5, momentum SGD
with a staircase exponential learning-rate decay and L2 weight decay on every parameter (biases included).

`make_optimizer` is the spec's optax chain; `train_step` and `eval_logits` work on one batch and are pure, so
they `jit` once per batch shape. Batches are dicts of normalised ``crops`` (B, S, S, 1), ``poses`` (B, pose_dim)
and integer ``labels`` (B,).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import optax
from flax.training import train_state

from dexjax.models.gqcnn import GQCNN, GQCNNConfig, init_gqcnn


@dataclasses.dataclass(frozen=True)
class OptimizerConfig:
  """Dex-Net 4.0's optimiser (spec section 3.2).

  Attributes:
    learning_rate: base learning rate.
    momentum: classical (non-Nesterov) momentum.
    decay_rate: the learning rate is multiplied by this every ``decay_epochs`` (staircase).
    decay_epochs: epochs between decays (0.5: every half epoch).
    weight_decay: L2 coefficient: the loss gains weight_decay * sum ||w||^2 / 2 over all parameters.
  """

  learning_rate: float = 0.01
  momentum: float = 0.9
  decay_rate: float = 0.95
  decay_epochs: float = 0.5
  weight_decay: float = 5e-4


def learning_rate_schedule(config: OptimizerConfig, steps_per_epoch: int) -> optax.Schedule:
  """Step -> learning rate: ``learning_rate * decay_rate ** floor(step / (decay_epochs * steps_per_epoch))``."""
  transition = max(1, round(config.decay_epochs * steps_per_epoch))
  return optax.exponential_decay(config.learning_rate, transition_steps=transition, decay_rate=config.decay_rate,
                                 staircase=True)


def make_optimizer(config: OptimizerConfig, steps_per_epoch: int) -> optax.GradientTransformation:
  """``chain(add_decayed_weights, sgd(staircase exponential decay, momentum))`` (spec section 3.2)."""
  return optax.chain(optax.add_decayed_weights(config.weight_decay),
                     optax.sgd(learning_rate_schedule(config, steps_per_epoch), momentum=config.momentum,
                               nesterov=False))


class TrainState(train_state.TrainState):
  """Flax `TrainState` (step, params, optimiser state, apply_fn) of one GQ-CNN."""


def create_state(key: jax.Array, model_config: GQCNNConfig, optimizer: optax.GradientTransformation) -> TrainState:
  """A fresh `TrainState` with `init_gqcnn` parameters."""
  return TrainState.create(apply_fn=GQCNN(model_config).apply, params=init_gqcnn(key, model_config), tx=optimizer)


def cross_entropy(logits: jax.Array, labels: jax.Array, weights: jax.Array | None = None,
                  soft_labels: jax.Array | None = None) -> jax.Array:
  """() softmax cross-entropy of logits (B, 2) and integer labels (B,): the mean, or the ``weights`` (B,)
  weighted mean sum(w l) / sum(w) (class balancing; zero weights mask padding). With ``soft_labels`` (B,) in
  [0, 1], the targets are the distributions (1 - s, s) instead of the integer labels."""
  if soft_labels is None:
    losses = optax.softmax_cross_entropy_with_integer_labels(logits, labels)
  else:
    losses = optax.softmax_cross_entropy(logits, jnp.stack([1.0 - soft_labels, soft_labels], axis=-1))
  if weights is None:
    return losses.mean()
  return jnp.sum(weights * losses) / jnp.maximum(jnp.sum(weights), 1e-12)


def train_step(state: TrainState, batch: dict[str, jax.Array], key: jax.Array) -> tuple[TrainState, dict]:
  """One SGD step on ``batch`` (optional ``weights`` (B,): a weighted loss; optional ``soft_labels`` (B,): soft
  targets, see `cross_entropy`); returns the new state, ``loss`` (cross-entropy before the step) and
  ``accuracy`` on the batch (against the integer labels)."""

  def loss_fn(params):
    logits = state.apply_fn({'params': params}, batch['crops'], batch['poses'], train=True, rngs={'dropout': key})
    return cross_entropy(logits, batch['labels'], batch.get('weights'), batch.get('soft_labels')), logits

  (loss, logits), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params)
  accuracy = jnp.mean(jnp.argmax(logits, -1) == batch['labels'])
  return state.apply_gradients(grads=grads), {'loss': loss, 'accuracy': accuracy}


def eval_logits(state: TrainState, batch: dict[str, jax.Array]) -> jax.Array:
  """Logits (B, 2) of a batch in inference mode (no dropout)."""
  return state.apply_fn({'params': state.params}, batch['crops'], batch['poses'], train=False)


__all__ = ['OptimizerConfig', 'TrainState', 'create_state', 'cross_entropy', 'eval_logits', 'learning_rate_schedule',
           'make_optimizer', 'train_step']
