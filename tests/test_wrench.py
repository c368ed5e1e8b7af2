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

# Jitted functions shared by all tests (one compilation per input shape; batch sizes are kept equal).
# (`wrench.nnls` itself runs compiled when called plainly.)
_nnls_batch = jax.jit(jax.vmap(wrench.nnls))
_residual_batch = jax.jit(jax.vmap(wrench.wrench_residual))
_residual_single = jax.jit(wrench.wrench_residual)
_BATCH = 2000  # Batch size of every `_nnls_batch` call.


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
  import cvxopt  # the test extra installs it: a missing reference must fail, not skip
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


def _random_nnls(rng: np.random.Generator, num: int, m: int, n: int):
  """Random NNLS problems a (num, m, n), b (num, m): columns N(mu, 1) with mu ~ U(0, 1.5) per problem, so the
  cone of the columns ranges from almost everything to a narrow cone (some residuals are 0, most not)."""
  a = rng.normal(size=(num, m, n)) + rng.uniform(0.0, 1.5, size=(num, 1, 1))
  b = 3.0 * rng.normal(size=(num, m))
  return a, b


# ----------------------------------------------------------------------------------------------------
# NNLS against scipy.
# ----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("m, n", [(8, 22), (6, 20)])
def test_nnls_matches_scipy(m, n):
  rng = np.random.default_rng(10 * m + n)
  a, b = _random_nnls(rng, _BATCH, m, n)
  ref = _scipy_residuals(a, b)
  out = _nnls_batch(a.astype(np.float32), b.astype(np.float32))
  x, res = np.asarray(out.x, np.float64), np.asarray(out.residual, np.float64)
  err = np.abs(res - ref)
  scale = np.maximum(1.0, ref)
  print(f"\n{m}x{n}: {np.mean(ref < 1e-9):.2f} with residual 0, converged {np.mean(out.converged):.4f}, "
        f"max |err| {err.max():.2e}, err > 1e-4 (rel/abs) in {np.sum(err > 1e-4 * scale)} of {len(ref)}")
  assert 0.1 < np.mean(ref < 1e-9) < 0.9  # The set mixes zero and positive residuals.
  assert np.all(x >= 0.0)
  assert np.all(np.asarray(out.converged))
  # The reported residual is that of the returned x (float32 problem, float64 arithmetic), up to float32
  # rounding of A x - b ...
  a32, b32 = a.astype(np.float32).astype(np.float64), b.astype(np.float32).astype(np.float64)
  rounding = 1e-6 * (np.linalg.norm(b, axis=1) + np.linalg.norm(a, axis=(1, 2)) * np.linalg.norm(x, axis=1))
  true_res = np.linalg.norm(np.einsum("bij,bj->bi", a32, x) - b32, axis=1)
  assert np.all(np.abs(res - true_res) <= rounding)
  # ... so it is never below the optimum beyond that rounding ...
  assert np.all(res >= ref - 2.0 * rounding)
  # ... and matches it to ~1e-4: all within 1e-3 and >= 99.8 % within 1e-4 (relative or absolute).
  assert np.all(err <= 1e-3 * scale)
  assert np.mean(err <= 1e-4 * scale) >= 0.998


def test_nnls_small_cases():
  a = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
  out = wrench.nnls(a, np.array([2.0, 1.0, 1.0]))
  np.testing.assert_allclose(out.x, [1.5, 1.0], rtol=1e-6)
  np.testing.assert_allclose(out.residual, np.sqrt(0.5), rtol=1e-6)
  out = wrench.nnls(a, np.array([-1.0, -1.0, -1.0]))
  np.testing.assert_array_equal(out.x, [0.0, 0.0])
  np.testing.assert_allclose(out.residual, np.sqrt(3.0), rtol=1e-6)
  assert bool(out.converged)
  out = wrench.nnls(a, np.zeros(3))
  np.testing.assert_array_equal(out.x, [0.0, 0.0])
  assert float(out.residual) == 0.0 and bool(out.converged)
  # Too few iterations for a target that needs three columns: feasible, not converged, an upper bound.
  a = np.random.default_rng(0).uniform(0.5, 1.5, size=(1, 3, 5))
  b = a[:, :, :3] @ np.array([1.0, 2.0, 3.0])
  short = wrench.nnls(a[0], b[0], num_iterations=2)
  assert not bool(short.converged) and np.all(np.asarray(short.x) >= 0)
  assert float(short.residual) >= _scipy_residuals(a, b)[0] - 1e-5
  full = wrench.nnls(a[0], b[0], num_iterations=12)
  assert bool(full.converged) and float(full.residual) < 1e-5
  with pytest.raises(ValueError):
    wrench.nnls(np.ones((2, 8, 22)), np.ones((2, 8)))


# ----------------------------------------------------------------------------------------------------
# Wrench resistance: known answers.
# ----------------------------------------------------------------------------------------------------


def test_exact_combination_within_limits_has_zero_residual():
  rng = np.random.default_rng(1)
  g, _, groups, limits = _parallel_jaw(rng, 10)
  for i in range(10):
    alpha = np.where(rng.uniform(size=20) < 0.4, rng.uniform(0.1, 1.0, size=20), 0.0)
    alpha *= 0.9 * limits[i].min() / (groups[i] @ alpha).max()  # Every group sum below its limit.
    t = g[i] @ alpha
    assert float(_residual_single(g[i], t, groups[i], limits[i])) < 1e-4
    # The same target scaled beyond the force limit (and beyond 1 mN of reach) does not resist.
    assert float(_residual_single(g[i], 3.0 * t, groups[i], limits[i])) > 10 * TOL


def _one_column_problem(rho: float, c: float):
  """Group 0: columns rho e1, e2, -e1, e4 with limit c; group 1: e5, e6 with limit 1."""
  e = np.eye(6)
  g = np.stack([rho * e[0], e[1], -e[0], e[3], e[4], e[5]], axis=1)
  groups = np.array([[1.0, 1.0, 1.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0, 1.0, 1.0]])
  return g, groups, np.array([c, 1.0])


@pytest.mark.parametrize("rho, s, c", [(1.0, 12.0, 10.0), (3.0, 25.0, 20.0), (0.5, 10.0, 9.99), (1.0, 10.001, 10.0)])
def test_exceeding_force_limit_along_one_column(rho, s, c):
  # Target s * rho * e1 with s > c: only the first column helps, and with weight w the squared residual is
  # rho^2 (s - w)^2 + (w - c)^2, minimal at w = (rho^2 s + c) / (rho^2 + 1): residual (s - c) rho / sqrt(rho^2 + 1).
  g, groups, limits = _one_column_problem(rho, c)
  t = s * rho * np.eye(6)[0]
  expected = (s - c) * rho / np.sqrt(rho**2 + 1.0)
  np.testing.assert_allclose(float(_residual_single(g, t, groups, limits)), expected, rtol=1e-5, atol=2e-6)
  # Within the limit: resists; a target no column can produce: the residual is its norm.
  assert float(_residual_single(g, 0.5 * c * rho * np.eye(6)[0], groups, limits)) < 1e-5
  np.testing.assert_allclose(float(_residual_single(g, -2.0 * np.eye(6)[2], groups, limits)), 2.0, rtol=1e-6)


def test_residual_gradient_is_the_envelope_gradient():
  # For the one-column problem residual = (s - c) rho / sqrt(rho^2 + 1) with t = s rho e1: the derivative is
  # 1 / sqrt(rho^2 + 1) in t[0] and -rho / sqrt(rho^2 + 1) in the limit c; 0 where the grasp resists.
  rho, c = 2.0, 10.0
  g, groups, limits = _one_column_problem(rho, c)
  grad = jax.jit(jax.grad(wrench.wrench_residual, argnums=(0, 1, 3)))
  d_g, d_t, d_limits = grad(g, 15.0 * rho * np.eye(6)[0], groups, limits)
  np.testing.assert_allclose(d_t, np.eye(6)[0] / np.sqrt(rho**2 + 1.0), rtol=1e-5, atol=1e-6)
  np.testing.assert_allclose(d_limits, [-rho / np.sqrt(rho**2 + 1.0), 0.0], rtol=1e-5, atol=1e-6)
  assert np.all(np.isfinite(d_g))
  for v in grad(g, 0.5 * c * rho * np.eye(6)[0], groups, limits):
    np.testing.assert_array_equal(v, 0.0)


def test_lift_bounded_groups_layout():
  rng = np.random.default_rng(2)
  g, t, groups, limits = rng.normal(size=(6, 5)), rng.normal(size=6), np.array([[1, 1, 0, 0, 0.0]]), [3.0]
  a, b = wrench.lift_bounded_groups(g, t, groups, limits)
  assert a.shape == (7, 6) and b.shape == (7,) and a.dtype == jnp.float32
  np.testing.assert_allclose(a[:6, :5], g, rtol=1e-6)
  np.testing.assert_array_equal(a[:6, 5], 0.0)
  np.testing.assert_array_equal(a[6], [1, 1, 0, 0, 0, 1])
  np.testing.assert_allclose(b, np.concatenate([t, limits]), rtol=1e-6)


# ----------------------------------------------------------------------------------------------------
# Wrench resistance: decisions against cvxopt on 10,000 grasps.
# ----------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def decision_sets():
  """Per family: 3,500 random grasps + 1,500 moved near the decision boundary, and cvxopt residuals."""
  rng = np.random.default_rng(2024)
  sets = {}
  for name, family in (("parallel_jaw", _parallel_jaw), ("suction", _suction)):
    g, t, groups, limits = family(rng, 7000)
    near_t, moved = _near_boundary(rng, g[3500:], t[3500:], groups[3500:], limits[3500:])
    t[3500:] = near_t
    keep = np.concatenate([np.arange(3500), 3500 + np.nonzero(moved)[0][:1500]])
    assert keep.size == 5000
    g, t, groups, limits = g[keep], t[keep], groups[keep], limits[keep]
    start = time.perf_counter()
    ref = _cvxopt_residuals(g, t, groups, limits)
    print(f"\n{name}: cvxopt reference for 5000 grasps in {time.perf_counter() - start:.1f} s")
    sets[name] = (g, t, groups, limits, ref)
  return sets


@pytest.mark.parametrize("name", ["parallel_jaw", "suction"])
def test_decisions_match_cvxopt(decision_sets, name):
  g, t, groups, limits, ref = decision_sets[name]
  res = np.asarray(_residual_batch(g, t, groups, limits), np.float64)
  ours, theirs = res <= TOL, ref <= TOL
  near = (ref > 0.3 * TOL) & (ref < 3.0 * TOL)
  disagree = ours != theirs
  # Tolerance semantics: a grasp resists when the residual of the solver's (feasible) alpha is <= TOL. That
  # residual never undercuts the optimum beyond float32 rounding (asserted below), so a grasp is accepted only
  # if its optimal residual is <= TOL + rounding: nothing the reference rejects by more than numerical noise
  # may be accepted. The other direction (optimum just under TOL, solver stopping just over it) can reject.
  noise = 1e-5 * (1.0 + np.linalg.norm(t, axis=1))
  false_resist = ours & (ref > TOL + noise)
  print(f"\n{name}: reference resists {theirs.sum()} / {len(ref)}, {near.sum()} within [0.3, 3] tol; "
        f"disagreements {disagree.sum()} (we say resists: {np.sum(disagree & ours)}, "
        f"we say not: {np.sum(disagree & ~ours)}); accepted with reference > tol + rounding: "
        f"{false_resist.sum()} (largest reference residual accepted {ref[ours].max():.6e} N); "
        f"max |ours - cvxopt| {np.abs(res - ref).max():.2e} N")
  for i in np.nonzero(disagree)[0][:10]:
    print(f"  grasp {i}: ours {res[i]:.4e} N, cvxopt {ref[i]:.4e} N")
  assert 0.35 < theirs.mean() < 0.65 and near.sum() > 1000
  assert disagree.mean() <= 0.005
  assert false_resist.sum() == 0
  # Our residual is that of a feasible alpha, so it does not undercut the optimum beyond rounding.
  assert np.all(res >= ref - noise)


# ----------------------------------------------------------------------------------------------------
# Plain, jit and vmap agree bitwise.
# ----------------------------------------------------------------------------------------------------


def test_plain_jit_vmap_identical(decision_sets):
  g, t, groups, limits, _ = (v.astype(np.float32) for v in decision_sets["parallel_jaw"])
  res_batched = np.asarray(_residual_batch(g, t, groups, limits))
  # 1,000 random and 1,000 near-boundary grasps (the latter exercise degenerate pivoting).
  sel = np.concatenate([np.arange(1000), np.arange(3500, 4500)])
  g, t, groups, limits, res_batched = g[sel], t[sel], groups[sel], limits[sel], res_batched[sel]
  a, b = (np.asarray(v) for v in jax.vmap(wrench.lift_bounded_groups)(g, t, groups, limits))
  batched = _nnls_batch(a, b)
  np.testing.assert_array_equal(res_batched, batched.residual)
  for i in list(range(0, 1000, 50)) + list(range(1000, 2000, 25)):
    out = wrench.nnls(a[i], b[i])  # Plain call.
    for field in ("x", "residual", "converged"):
      np.testing.assert_array_equal(getattr(out, field), getattr(batched, field)[i])
    np.testing.assert_array_equal(_residual_single(g[i], t[i], groups[i], limits[i]), res_batched[i])
  for i in (1000, 1999):  # Plain calls of the wrappers too (the lifting runs op by op).
    np.testing.assert_array_equal(wrench.wrench_residual(g[i], t[i], groups[i], limits[i]), res_batched[i])
    assert bool(wrench.resists(g[i], t[i], groups[i], limits[i])) == (res_batched[i] <= TOL)


def test_vmap_pools_the_problems_and_equals_the_fixed_loop(decision_sets):
  """Under `vmap` the solver runs the batch through `pooled_loop` (each problem stops when converged); run one
  problem after another with `lax.map` (no batching rule) it runs the fixed loop. Both give the same bits, for
  nested `vmap` and for an argument shared by the batch too."""
  g, t, groups, limits, _ = (v.astype(np.float32) for v in decision_sets["suction"])
  sel = np.concatenate([np.arange(1000), np.arange(3500, 4500)])  # Random and near-boundary problems.
  a, b = (np.asarray(v) for v in jax.vmap(wrench.lift_bounded_groups)(g[sel], t[sel], groups[sel], limits[sel]))
  pooled = _nnls_batch(a, b)
  fixed = jax.jit(lambda a, b: jax.lax.map(lambda ab: wrench.nnls(*ab), (a, b)))(a, b)
  for field in ("x", "residual", "converged"):
    np.testing.assert_array_equal(getattr(pooled, field), getattr(fixed, field))
  assert np.mean(fixed.converged) > 0.99
  nested = jax.jit(jax.vmap(jax.vmap(wrench.nnls)))(a.reshape(200, 10, *a.shape[1:]), b.reshape(200, 10, -1))
  np.testing.assert_array_equal(nested.residual.reshape(-1), pooled.residual)
  shared_b = jax.jit(jax.vmap(wrench.nnls, in_axes=(0, None)))(a[:50], b[7])
  np.testing.assert_array_equal(shared_b.residual, [wrench.nnls(a[i], b[7]).residual for i in range(50)])
