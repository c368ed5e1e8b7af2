"""The Monte-Carlo model draws what the seed specifies (moments, supports, cones)."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from dexjax.grasps import ParallelJawGrasp
from dexjax.quality import parallel_jaw_perturbations, perturb_parallel_jaw_grasp, sample_conditions, suction_perturbations

N = 20000
APPROACH = jnp.array([0.0, 0.0, -1.0])


def _draw(perturbations):
  keys = jax.random.split(jax.random.key(0), N)
  return jax.jit(jax.vmap(lambda k: sample_conditions(k, perturbations, APPROACH)))(keys)


def test_mass_is_gamma_with_seed_mean_and_variance():
  c = _draw(parallel_jaw_perturbations())
  m = np.asarray(c.mass)
  assert np.all(m > 0)
  assert abs(m.mean() - 0.25) < 0.01 and abs(m.var() - 0.05) < 0.005


def test_friction_is_truncated_normal_on_unit_interval():
  c = _draw(parallel_jaw_perturbations())
  mu = np.asarray(c.friction)
  assert mu.min() >= 0.0 and mu.max() <= 1.0
  # Mean of N(0.8, 0.1^2) truncated to [0, 1]: 0.8 - 0.1 * phi(2) / (Phi(2) - Phi(-8)).
  phi2 = math.exp(-2.0) / math.sqrt(2 * math.pi)
  expected = 0.8 - 0.1 * phi2 / (0.5 * (1 + math.erf(2 / math.sqrt(2))))
  assert abs(mu.mean() - expected) < 0.003


def test_gravity_uniform_on_sphere_for_parallel_jaw_and_in_cone_for_suction():
  g = np.asarray(_draw(parallel_jaw_perturbations()).gravity)
  np.testing.assert_allclose(np.linalg.norm(g, axis=1), 1.0, atol=1e-5)
  assert np.all(np.abs(g.mean(0)) < 0.02)
  np.testing.assert_allclose(np.cov(g.T), np.eye(3) / 3, atol=0.01)
  g = np.asarray(_draw(suction_perturbations()).gravity)
  cos = g @ np.asarray(APPROACH)
  assert cos.min() >= math.cos(math.pi / 6) - 1e-6
  # Uniform on the cap: cos is uniform on [cos(pi/6), 1].
  assert abs(cos.mean() - (1 + math.cos(math.pi / 6)) / 2) < 0.002


def test_disturbance_and_pose_noise_have_seed_sigmas():
  c = _draw(parallel_jaw_perturbations())
  np.testing.assert_allclose(np.asarray(c.disturbance).std(0), 0.01, rtol=0.05)
  grasp = ParallelJawGrasp(center=jnp.zeros(3), axis=jnp.array([1.0, 0, 0]), approach=APPROACH, width=jnp.float32(0.05))
  keys = jax.random.split(jax.random.key(1), N)
  for p, sigma in ((parallel_jaw_perturbations(), 0.0025), (suction_perturbations(), 0.0001)):
    g = jax.jit(jax.vmap(lambda k: perturb_parallel_jaw_grasp(k, grasp, p)))(keys)
    np.testing.assert_allclose(np.asarray(g.center).std(0), sigma, rtol=0.05)
    np.testing.assert_allclose(np.asarray(g.axis), np.tile([1.0, 0, 0], (N, 1)), atol=1e-6)  # no rotation noise
