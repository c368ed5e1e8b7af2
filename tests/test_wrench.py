"""Tests for `dexjax.quality.wrench`: the fixed-iteration NNLS and the wrench-resistance residual.

References are independent float64 solvers: `scipy.optimize.nnls` on the lifted NNLS, and a cvxopt QP on
the *un-lifted* formulation (variables alpha and the force-limit excess e).
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import nnls as scipy_nnls

from dexjax.quality import wrench

TOL = wrench.DEFAULT_RESIDUAL_TOL
TORQUE_SCALE = 100.0  # 1/m

# Jitted batch functions shared by all tests (one compilation per input shape).
_nnls_batch = jax.jit(jax.vmap(wrench.nnls))
_residual_batch = jax.jit(jax.vmap(wrench.wrench_residual))
_resists_batch = jax.jit(jax.vmap(wrench.resists))


# ----------------------------------------------------------------------------------------------------
# Instance families (float64 numpy, batched over the leading axis).
# ----------------------------------------------------------------------------------------------------


def _unit(v: np.ndarray) -> np.ndarray:
  return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _tangents(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
  """Two unit tangents (num, 3) orthogonal to unit normals n (num, 3)."""
  helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
  t1 = _unit(np.cross(n, helper))
  return t1, np.cross(n, t1)


def _gravity_target(rng: np.random.Generator, num: int) -> np.ndarray:
  """t = -(gravity wrench of a 0.05-1.5 kg object in a random direction) + N(0, 0.01^2), (num, 6), N."""
  mass = rng.uniform(0.05, 1.5, size=(num, 1))
  gravity = mass * 9.81 * _unit(rng.normal(size=(num, 3)))
  t = np.concatenate([-gravity, np.zeros((num, 3))], axis=1)
  return t + rng.normal(scale=0.01, size=t.shape)


def _parallel_jaw(rng: np.random.Generator, num: int):
  """Two-contact soft-finger grasps: G (num, 6, 20), t (num, 6), C (num, 2, 20), c (num, 2).

  Per contact: 8 friction-cone edges n + mu (cos phi t1 + sin phi t2) (mu in [0.3, 1], inward normals tilted
  from the jaw axis) and 2 torsion columns +-gamma n (gamma 1-3 mm); torques (p - com) x f times the torque
  scale, contacts within ~3 cm of the centre of mass; one group per finger with a 10-30 N limit.
  """
  axis = _unit(rng.normal(size=(num, 3)))
  half_width = rng.uniform(0.005, 0.03, size=(num, 1))
  offset = rng.normal(size=(num, 3)) * rng.uniform(0.0, 0.01, size=(num, 1))
  tilt = rng.uniform(0.0, 0.6, size=(num, 1))
  mu = rng.uniform(0.3, 1.0, size=(num, 1, 1))
  phi = np.arange(8) * 2 * np.pi / 8
  columns = []
  for sign in (1.0, -1.0):
    p = offset + sign * half_width * axis
    n = _unit(-sign * axis + tilt * rng.normal(size=(num, 3)))
    t1, t2 = _tangents(n)
    f = n[:, None] + mu * (np.cos(phi)[None, :, None] * t1[:, None] + np.sin(phi)[None, :, None] * t2[:, None])
    tau = TORQUE_SCALE * np.cross(p[:, None], f)
    gamma = TORQUE_SCALE * rng.uniform(1e-3, 3e-3, size=(num, 1, 1))
    torsion = gamma * np.stack([n, -n], axis=1)
    columns.append(np.concatenate([f, tau], axis=-1))
    columns.append(np.concatenate([np.zeros_like(torsion), torsion], axis=-1))
  g = np.concatenate(columns, axis=1).transpose(0, 2, 1)
  groups = np.zeros((num, 2, 20))
  groups[:, 0, :10] = 1.0
  groups[:, 1, 10:] = 1.0
  limits = np.repeat(rng.uniform(10.0, 30.0, size=(num, 1)), 2, axis=1)
  return g, _gravity_target(rng, num), groups, limits


def _suction(rng: np.random.Generator, num: int):
  """Suction-like contacts: G (num, 6, 12), t (num, 6), C (num, 2, 12), c (num, 2).

  8 generators of a pyramid cone (4 friction directions n +- mu t_i, each with +-gamma torsion) plus two
  +-T elastic torque pairs about the tangents, one group (limit 1) per pair. The normal is tilted away from
  the target force so that some targets leave the cone.
  """
  t = _gravity_target(rng, num)
  n = _unit(_unit(t[:, :3]) + rng.uniform(0.0, 0.6, size=(num, 1)) * rng.normal(size=(num, 3)))
  t1, t2 = _tangents(n)
  p = rng.normal(size=(num, 3)) * rng.uniform(0.0, 0.02, size=(num, 1))
  mu = rng.uniform(0.3, 1.0, size=(num, 1))
  gamma = TORQUE_SCALE * rng.uniform(1e-3, 5e-3, size=(num, 1))
  columns = []
  for d in (t1, -t1, t2, -t2):
    f = n + mu * d
    for s in (1.0, -1.0):
      columns.append(np.concatenate([f, TORQUE_SCALE * np.cross(p, f) + s * gamma * n], axis=-1))
  elastic = TORQUE_SCALE * rng.uniform(0.02, 0.2, size=(num, 1))
  for d in (t1, -t1, t2, -t2):
    columns.append(np.concatenate([np.zeros_like(d), elastic * d], axis=-1))
  g = np.stack(columns, axis=2)
  groups = np.zeros((num, 2, 12))
  groups[:, 0, 8:10] = 1.0
  groups[:, 1, 10:12] = 1.0
  return g, t, groups, np.ones((num, 2))


def _lift64(g, t, groups, limits):
  """Float64 numpy version of the lifting, batched: A (num, 6+k, n+k), b (num, 6+k)."""
  num, k = groups.shape[0], groups.shape[1]
  top = np.concatenate([g, np.zeros((num, g.shape[1], k))], axis=2)
  bottom = np.concatenate([groups, np.broadcast_to(np.eye(k), (num, k, k))], axis=2)
  return np.concatenate([top, bottom], axis=1), np.concatenate([t, limits], axis=1)


def _scipy_residuals(a: np.ndarray, b: np.ndarray) -> np.ndarray:
  return np.array([scipy_nnls(a[i], b[i])[1] for i in range(a.shape[0])])


def _near_boundary(rng: np.random.Generator, g, t, groups, limits):
  """Moves grasps near the decision boundary.

  Targets whose (scipy, lifted) residual exceeds 3 * TOL are scaled down by s in (0, 1) (a lighter object)
  so that the residual becomes log-uniform in [0.3, 3] * TOL; the residual is convex in s and 0 at s = 0,
  so bisection finds s. Other targets are kept. Returns (new targets (num, 6), mask of rescaled ones).
  """
  goal = TOL * np.exp(rng.uniform(np.log(0.3), np.log(3.0), size=t.shape[0]))
  a, b = _lift64(g, t, groups, limits)
  new_t, rescaled = t.copy(), _scipy_residuals(a, b) > 3.0 * TOL
  for i in np.nonzero(rescaled)[0]:
    lo, hi = 0.0, 1.0
    for _ in range(30):
      mid = 0.5 * (lo + hi)
      res = scipy_nnls(a[i], np.concatenate([mid * t[i], limits[i]]))[1]
      lo, hi = (mid, hi) if res < goal[i] else (lo, mid)
    new_t[i] = 0.5 * (lo + hi) * t[i]
  return new_t, rescaled


def _cvxopt_residuals(g, t, groups, limits) -> np.ndarray:
  """Reference residuals from a cvxopt QP on the un-lifted problem, (num,) float64.

  Variables (alpha, r, e): minimise ||r||^2 + ||e||^2 s.t. G alpha - r = t, alpha >= 0, e >= 0,
  C alpha - e <= c (the same as ||G alpha - t||^2 + ||e||^2, written with r so that the objective value is
  the squared residual itself and the absolute gap tolerance applies to it). The residual is evaluated at
  the returned alpha (clipped to >= 0, so it is an upper bound of the optimum).
  """
  cvxopt = pytest.importorskip("cvxopt")
  options = {"show_progress": False, "abstol": 1e-14, "reltol": 1e-10, "feastol": 1e-10, "maxiters": 100}
  out = np.empty(t.shape[0])
  for i in range(t.shape[0]):
    gi, ci = g[i], groups[i]
    m, n, k = gi.shape[0], gi.shape[1], ci.shape[0]
    nv = n + m + k
    p = np.zeros((nv, nv))
    p[n:, n:] = 2.0 * np.eye(m + k)
    eq = np.concatenate([gi, -np.eye(m), np.zeros((m, k))], axis=1)
    ineq = np.zeros((n + 2 * k, nv))
    ineq[:n, :n] = -np.eye(n)
    ineq[n:n + k, n + m:] = -np.eye(k)
    ineq[n + k:, :n] = ci
    ineq[n + k:, n + m:] = -np.eye(k)
    h = np.concatenate([np.zeros(n + k), limits[i]])
    sol = cvxopt.solvers.qp(
        cvxopt.matrix(p), cvxopt.matrix(np.zeros(nv)), cvxopt.matrix(ineq), cvxopt.matrix(h),
        cvxopt.matrix(eq), cvxopt.matrix(t[i]), options=options)
    alpha = np.maximum(np.asarray(sol["x"]).ravel()[:n], 0.0)
    excess = np.maximum(ci @ alpha - limits[i], 0.0)
    out[i] = np.sqrt(np.sum((gi @ alpha - t[i]) ** 2) + np.sum(excess**2))
  return out
