"""The installed XLA:CPU computes what dexjax's kernels are made of.

jaxlib 0.10.2 miscompiles a vmapped matrix-vector product followed by a reduction on the CPU (jax-ml/jax#39103):
the jitted result differs from the eager one and from NumPy. Grasp-quality, contact and camera kernels are built
of exactly such ops, so pyproject.toml excludes that release; this test fails if a broken jaxlib is installed
anyway (it did fail with 0.10.2 on this machine: 1065369600 instead of 1073741824).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def _sum_of_squares_after_rotation(points, rotation):
  """(N,) |R p|^2 per point: a vmapped matrix-vector product followed by a reduction."""
  return jax.vmap(lambda p: jnp.sum((rotation @ p) ** 2))(points)


def test_vmapped_matvec_reduction_matches_numpy():
  n = 32_769  # the size at which jaxlib 0.10.2 goes wrong in float32
  i = np.arange(n, dtype=np.float32)
  points = np.stack([i, np.zeros_like(i), np.zeros_like(i)], axis=1)
  rotation = np.eye(3, dtype=np.float32)
  expected = np.sum((points @ rotation.T).astype(np.float64) ** 2, axis=1)
  jitted = np.asarray(jax.jit(_sum_of_squares_after_rotation)(points, rotation))
  np.testing.assert_allclose(jitted, expected, rtol=1e-6)

