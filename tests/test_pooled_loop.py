"""Tests for `dexjax.quality.pooled_loop`: a pool of lanes gives every item the final state of its fixed loop."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dexjax.quality.pooled_loop import pooled_loop

T = 20  # Fixed trip count of the loops below.


def _count_step(x, state):
  """Item x needs max(x, 1) iterations: k counts them, done once k >= x (then unchanged)."""
  k, done = state
  k_next = jnp.where(done, k, k + 1)
  return k_next, done | (k_next >= x)


def _newton_step(x, state):
  """Newton's iteration for sqrt(x) from 1, done when a step moves y by less than 1e-6 y (then unchanged)."""
  y, done = state
  y_next = 0.5 * (y + x / y)
  small = jnp.abs(y_next - y) < 1e-6 * y
  return jnp.where(done, y, y_next), done | small


def _fixed(step, init, inputs):
  """The reference: every item runs all T iterations (`vmap` of the fixed loop)."""
  return jax.vmap(lambda x: jax.lax.fori_loop(0, T, lambda _, s: step(x, s), init))(inputs)


@functools.partial(jax.jit, static_argnames=('step', 'pool_size'))
def _pooled(step, init, inputs, pool_size):
  return pooled_loop(step, init, inputs, T, lambda s: s[1], pool_size=pool_size)


@pytest.mark.parametrize('pool_size', [7, 64, 5000])
def test_counts_equal_the_fixed_loop(pool_size):
  # Items needing 0 .. 40 iterations in random order: some finish at once, some never within T.
  x = jnp.asarray(np.random.default_rng(0).integers(0, 41, size=1000), jnp.int32)
  init = (jnp.int32(0), jnp.bool_(False))
  k, done = _pooled(_count_step, init, x, pool_size)
  ref_k, ref_done = _fixed(_count_step, init, x)
  np.testing.assert_array_equal(k, ref_k)
  np.testing.assert_array_equal(done, ref_done)
  np.testing.assert_array_equal(k, np.clip(np.asarray(x), 1, T))  # The known answer.
  assert not np.all(np.asarray(done)) and np.any(np.asarray(done))


def test_floating_point_iterates_are_bitwise_the_fixed_loops():
  x = jnp.asarray(10.0 ** np.random.default_rng(1).uniform(-3, 12, size=3000), jnp.float32)
  init = (jnp.float32(1.0), jnp.bool_(False))
  y, done = _pooled(_newton_step, init, x, 64)
  ref_y, ref_done = _fixed(_newton_step, init, x)
  np.testing.assert_array_equal(y, ref_y)
  np.testing.assert_array_equal(done, ref_done)
  # Converged items hold sqrt(x); the large x (more than T iterations from 1) are unfinished, not wrong.
  conv = np.asarray(done)
  assert 0.2 < conv.mean() < 1.0
  np.testing.assert_allclose(np.asarray(y)[conv], np.sqrt(np.asarray(x, np.float64))[conv], rtol=1e-5)


def test_keep_empty_batch_and_no_iterations():
  init = (jnp.int32(0), jnp.bool_(False))
  step, done = _count_step, (lambda s: s[1])
  x = jnp.arange(10, dtype=jnp.int32)
  k = pooled_loop(step, init, x, T, done, keep=lambda s: s[0], pool_size=4)
  np.testing.assert_array_equal(k, np.maximum(np.arange(10), 1))
  empty = pooled_loop(step, init, jnp.zeros((0,), jnp.int32), T, done)
  assert empty[0].shape == (0,) and empty[1].shape == (0,)
  untouched = pooled_loop(step, init, x, 0, done)
  np.testing.assert_array_equal(untouched[0], np.zeros(10))
  np.testing.assert_array_equal(untouched[1], np.zeros(10, bool))
