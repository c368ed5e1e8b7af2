"""Inference in chunks (`dexjax.models.chunked`) and the reshape max-pool (`dexjax.models.gqcnn.max_pool_2x2`):
the same logits and gradients as the whole batch at once, and the same pool as flax's."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import linen as nn

from dexjax.models import GQCNN, GQCNNConfig, GraspQualityModel, Normalization, SUCTION_POSE_DIM, init_gqcnn
from dexjax.models.chunked import network_logits
from dexjax.models.gqcnn import max_pool_2x2

CONFIG = GQCNNConfig.small(pose_dim=SUCTION_POSE_DIM)
CHUNK = 4


@pytest.fixture(scope='module')
def params():
  return init_gqcnn(jax.random.key(0), CONFIG)


def _inputs(batch: int, seed: int = 1):
  crops = jax.random.normal(jax.random.key(seed), (batch, CONFIG.crop_size, CONFIG.crop_size, 1))
  return crops, jax.random.normal(jax.random.key(seed + 1), (batch, CONFIG.pose_dim))


@pytest.mark.parametrize('batch', [1, CHUNK, CHUNK + 1, 3 * CHUNK + 2])
def test_chunked_logits_equal_the_whole_batch(params, batch):
  """Batches below, at and above the chunk, and ones the chunks do not divide (padded, padding dropped)."""
  crops, poses = _inputs(batch)
  whole = GQCNN(CONFIG).apply({'params': params}, crops, poses)
  chunked = jax.jit(network_logits, static_argnums=(1, 4))(params, CONFIG, crops, poses, CHUNK)
  assert chunked.shape == (batch, 2)
  np.testing.assert_allclose(np.asarray(chunked), np.asarray(whole), rtol=1e-5, atol=1e-5)


def test_chunked_logits_run_the_chunks_in_a_loop(params):
  """ceil(B / chunk) passes of the network, one after another (a loop in the program), not B at once."""
  crops, poses = _inputs(3 * CHUNK + 2)
  jaxpr = str(jax.make_jaxpr(lambda c, q: network_logits(params, CONFIG, c, q, CHUNK))(crops, poses))
  assert 'scan' in jaxpr and 'length=4' in jaxpr
  assert 'scan' not in str(jax.make_jaxpr(lambda c, q: network_logits(params, CONFIG, c, q, 0))(crops, poses))


def test_chunked_gradients_equal_the_whole_batch(params):
  """Gradients in the parameters, crops and poses (e.g. gradient-polished grasps) are the whole batch's."""
  crops, poses = _inputs(2 * CHUNK + 1, seed=5)

  def objective(logits_fn):
    return lambda p, c, q: jnp.sum(jax.nn.log_softmax(logits_fn(p, c, q))[:, 1])

  whole = jax.grad(objective(lambda p, c, q: GQCNN(CONFIG).apply({'params': p}, c, q)), argnums=(0, 1, 2))
  chunked = jax.grad(objective(lambda p, c, q: network_logits(p, CONFIG, c, q, CHUNK)), argnums=(0, 1, 2))
  for a, b in zip(jax.tree.leaves(whole(params, crops, poses)), jax.tree.leaves(chunked(params, crops, poses))):
    np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-4, atol=1e-6)


def test_a_saved_model_predicts_in_chunks_what_the_network_computes(params):
  """`GraspQualityModel` (what `predict`, the policies and `plan` call) normalises and runs `network_logits`."""
  norm = Normalization(jnp.float32(0.5), jnp.float32(0.1), jnp.float32([0.5, 0.0]), jnp.float32([0.1, 1.0]))
  model = GraspQualityModel(params=params, normalization=norm, config=CONFIG, gripper='suction',
                            crop_window=CONFIG.crop_size)
  crops, poses = _inputs(40, seed=7)
  expected = GQCNN(CONFIG).apply({'params': params}, *norm.apply(crops, poses, False))
  np.testing.assert_allclose(np.asarray(model.logits(crops, poses)), np.asarray(expected), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize('shape', [(2, 8, 6, 3), (1, 7, 9, 2), (3, 5, 5, 1)])
def test_max_pool_is_flaxs_with_its_gradient(shape):
  """Values of nn.max_pool (2 x 2, stride 2, SAME; odd sides padded), and its gradient where no window ties."""
  x = jax.random.normal(jax.random.key(sum(shape)), shape)
  flax_pool = lambda x: nn.max_pool(x, (2, 2), strides=(2, 2), padding='SAME')
  np.testing.assert_array_equal(np.asarray(max_pool_2x2(x)), np.asarray(flax_pool(x)))
  weights = jax.random.normal(jax.random.key(9), flax_pool(x).shape)
  grad = lambda pool: jax.grad(lambda x: jnp.sum(pool(x) * weights))(x)
  np.testing.assert_array_equal(np.asarray(grad(max_pool_2x2)), np.asarray(grad(flax_pool)))
