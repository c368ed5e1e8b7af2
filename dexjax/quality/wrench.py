"""Wrench resistance as a non-negative least-squares problem.

A contact model describes what a grasp can push on the object with as a *wrench matrix* ``G`` of shape
(6, n): each column is a wrench generator (3 force rows in N, then 3 torque rows in N m already multiplied
by a torque scale in 1/m, so that every row is in newtons), combined with non-negative weights ``alpha``.
Some weights share a budget, written as *bounded-sum groups*: a 0/1 matrix ``C`` (k, n) and limits ``c``
(k,) in newtons meaning "the alphas in group i should sum to at most c_i" (a per-finger force limit for a
parallel-jaw gripper; for suction, a box |elastic torque| <= T written as a +/- column pair in one group
with limit 1).

Semantics:

  residual(G, t, C, c) = sqrt( min_{alpha >= 0}  ||G alpha - t||^2 + ||max(0, C alpha - c)||^2 )

  i.e. the smallest combination of unresisted wrench (N; torques scaled to N) and force-limit excess (N).
  A grasp *resists* iff residual <= tol (default tol = 1e-3, i.e. 1 mN).

Here ``t`` is the wrench the grasp must produce, i.e. minus the external wrench on the object.

The residual is computed exactly as an NNLS by lifting with slack variables ``s >= 0``:

  A = [[G, 0], [C, I_k]]  ((6 + k) x (n + k)),  b = [t; c],   residual = min_{x >= 0} ||A x - b||.

If a group sum is below its limit, the slack takes up the rest at zero cost; if above, the excess is paid
in the residual.

The NNLS solver `nnls` is a Lawson--Hanson active-set method written as one loop with a fixed trip count
and static shapes, so it runs unchanged plain, under `jax.jit` and under `jax.vmap` (one problem per call;
batch with `jax.vmap`). It is built for many *small* problems (m <= ~8 rows, n <= ~24 columns):

* Lawson--Hanson keeps the passive columns linearly independent, so at most m are passive. They live in
  m *slots*: the slot matrix ``A_S`` (m, m) and its Gram matrix ``A_S^T A_S`` are updated by one column
  when a variable enters, and unused slots are masked to the identity.
* The least-squares subproblem on the passive set is solved with a hand-unrolled Cholesky factorisation of
  the masked Gram matrix plus one step of iterative refinement whose residual is formed with ``A_S`` itself
  (corrected semi-normal equations). Unrolled element-wise code vectorises over a `vmap` batch, where a
  batched LAPACK call is slow on a CPU.
* Each iteration solves the subproblem once. A strictly positive solution is accepted and, if the largest
  dual ``w = A^T (b - A x)`` over the inactive, non-banned columns exceeds the dual tolerance and a slot is
  free, that column enters. Otherwise the step interpolates towards the solution until the first passive
  variable reaches zero and drops the variables that reached zero. A column that enters but comes out of the
  subproblem non-positive (possible only through rounding) is banned until the passive set next grows, as
  in the original Lawson--Hanson code. Once the dual test fails the state is a fixed point, so extra
  iterations change nothing.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

# Iterations of the fixed-length Lawson--Hanson loop. Each iteration either adds one column or drops at
# least one, plus one final iteration to confirm optimality; see the module tests and the benchmark notes.
DEFAULT_NUM_ITERATIONS = 32
# Dual tolerance, relative to max_j ||A_j|| * ||b||: a column enters only if its dual exceeds this.
DEFAULT_DUAL_TOL = 1e-6
# A Cholesky pivot is floored at this fraction of its Gram diagonal entry (guards near-dependent columns).
_PIVOT_FLOOR = 1e-6
# Steps of iterative refinement of the passive least-squares solution.
_REFINEMENT_STEPS = 1
# Default decision tolerance on the residual, newtons.
DEFAULT_RESIDUAL_TOL = 1e-3


@struct.dataclass
class NNLSResult:
  """Solution of one NNLS problem min_{x >= 0} ||A x - b||.

  Attributes:
    x: (n,) float32 non-negative minimiser.
    residual: () float32 ||A x - b||, in the units of ``b``.
    converged: () bool, True if the Lawson--Hanson optimality test passed within the iteration budget
      (if False, ``x`` is feasible and ``residual`` an upper bound on the optimum).
  """

  x: jax.Array
  residual: jax.Array
  converged: jax.Array


@struct.dataclass
class _State:
  """Loop state of the slot-based Lawson--Hanson iteration (m slots, n columns).

  Attributes:
    slot_x: (m,) values of the passive variables in their slots; 0 in unused slots and for a column that
      has just entered.
    slot_col: (m,) int32 column index held by each slot (meaningless where unused).
    used: (m,) bool, slot holds a passive column.
    a_slots: (m, m) columns of A held by the slots, A[:, slot_col] (stale where unused).
    gram: (m, m) A_S^T A_S over the slots (stale rows/columns where unused).
    atb: (m,) A_S^T b over the slots (stale where unused).
    banned: (n,) bool, column may not enter until the passive set next grows.
    done: () bool, optimality test passed.
  """

  slot_x: jax.Array
  slot_col: jax.Array
  used: jax.Array
  a_slots: jax.Array
  gram: jax.Array
  atb: jax.Array
  banned: jax.Array
  done: jax.Array


def _sum(v: jax.Array, axis: int) -> jax.Array:
  """Sum over a small axis, added strictly left to right.

  A fixed order of additions makes the result independent of how XLA lays out or vectorises a reduction,
  so plain, `jit` and `vmap` calls round identically.
  """
  v = jnp.moveaxis(v, axis, 0)
  total = v[0]
  for i in range(1, v.shape[0]):
    total = total + v[i]
  return total


def _mul(x: jax.Array, y: jax.Array) -> jax.Array:
  """Element-wise product that the compiler cannot fuse into a following add (no FMA contraction).

  XLA's CPU backend contracts a multiply feeding an add into an FMA in scalar code but not always in
  vectorised code, so the same expression can round differently plain and under `vmap`. Passing the
  product through a select it cannot prove trivial (NaN stays NaN) keeps every product rounded on its own.
  """
  p = x * y
  return jnp.where(p == p, p, jnp.nan)


def _matvec(a: jax.Array, v: jax.Array) -> jax.Array:
  """(p, q) @ (q,) -> (p,) as a broadcast multiply and an ordered sum (fuses under `vmap`)."""
  return _sum(_mul(a, v[None, :]), axis=1)


def _rmatvec(a: jax.Array, v: jax.Array) -> jax.Array:
  """(p, q)^T @ (p,) -> (q,) as a broadcast multiply and an ordered sum."""
  return _sum(_mul(a, v[:, None]), axis=0)


def _cholesky(h: jax.Array) -> tuple[list[list[Any]], list[Any]]:
  """Unrolled Cholesky factorisation h = L L^T of a small symmetric positive definite matrix.

  Args:
    h: (m, m) symmetric matrix; only the lower triangle is read.

  Returns:
    (L, inv_diag): L as a list of rows of scalars (L[i][j] for j < i; the diagonal is not stored) and the
    reciprocals of the diagonal of L. Pivots are floored at `_PIVOT_FLOOR` times the diagonal of ``h``.
  """
  m = h.shape[0]
  lower = [[None] * m for _ in range(m)]
  inv_diag = [None] * m
  for j in range(m):
    d = h[j, j]
    for k in range(j):
      d = d - _mul(lower[j][k], lower[j][k])
    floor = _mul(_PIVOT_FLOOR, h[j, j]) + jnp.finfo(h.dtype).tiny
    inv = 1.0 / jnp.sqrt(jnp.maximum(d, floor))
    inv_diag[j] = inv
    for i in range(j + 1, m):
      s = h[i, j]
      for k in range(j):
        s = s - _mul(lower[i][k], lower[j][k])
      lower[i][j] = s * inv
  return lower, inv_diag


def _cholesky_solve(lower: list[list[Any]], inv_diag: list[Any], rhs: jax.Array) -> jax.Array:
  """Solves L L^T z = rhs with the factor from `_cholesky`; rhs and the result are (m,)."""
  m = rhs.shape[0]
  y = [None] * m
  for i in range(m):
    s = rhs[i]
    for k in range(i):
      s = s - _mul(lower[i][k], y[k])
    y[i] = s * inv_diag[i]
  z = [None] * m
  for i in reversed(range(m)):
    s = y[i]
    for k in range(i + 1, m):
      s = s - _mul(lower[k][i], z[k])
    z[i] = s * inv_diag[i]
  return jnp.stack(z)


def _passive_least_squares(state: _State, b: jax.Array) -> jax.Array:
  """Least-squares solution on the passive slots, (m,), zero in unused slots.

  Solves min ||A_S z - b|| over the used slots with the masked Gram matrix (identity on unused slots) and
  one step of iterative refinement.
  """
  used = state.used
  both = used[:, None] & used[None, :]
  eye = jnp.eye(used.shape[0], dtype=b.dtype)
  gram = jnp.where(both, state.gram, eye)
  a_s = jnp.where(used[None, :], state.a_slots, 0.0)
  lower, inv_diag = _cholesky(gram)
  z = _cholesky_solve(lower, inv_diag, jnp.where(used, state.atb, 0.0))
  for _ in range(_REFINEMENT_STEPS):
    r = b - _matvec(a_s, z)
    z = z + _cholesky_solve(lower, inv_diag, _rmatvec(a_s, r))
  return jnp.where(used, z, 0.0)


def _step(a: jax.Array, a_t: jax.Array, b: jax.Array, dual_tol: jax.Array, state: _State) -> _State:
  """One Lawson--Hanson iteration: an accept-and-add step or an interpolate-and-drop step.

  Args:
    a: (m, n) matrix.
    a_t: (n, m) its transpose (rows are gathered when a column enters).
    b: (m,) right-hand side.
    dual_tol: () absolute dual tolerance.
    state: current `_State`.

  Returns:
    The next `_State`; a state with ``done`` set is returned unchanged.
  """
  m, n = a.shape
  used, slot_x, slot_col, done = state.used, state.slot_x, state.slot_col, state.done
  slot_ids = jnp.arange(m)
  z = _passive_least_squares(state, b)
  positive = jnp.all(jnp.where(used, z > 0, True))
  entered = used & (slot_x == 0)  # The column that entered in the previous iteration, if any.

  # (1) Accept z; add the inactive column with the largest dual if it passes the test and a slot is free.
  a_s = jnp.where(used[None, :], state.a_slots, 0.0)
  w = _rmatvec(a, b - _matvec(a_s, z))
  passive = jnp.any(used[:, None] & (slot_col[:, None] == jnp.arange(n)[None, :]), axis=0)
  banned_accept = state.banned & ~jnp.any(entered)  # The passive set grew: lift all bans.
  w_cand = jnp.where(passive | banned_accept, -jnp.inf, w)
  col = jnp.argmax(w_cand).astype(jnp.int32)
  free = jnp.argmin(used)  # First free slot (argmin of a bool array picks the first False).
  add = positive & ~done & (jnp.max(w_cand) > dual_tol) & ~jnp.all(used)
  new_slot = (slot_ids == free) & add
  new_col = a_t[col]  # (m,) = A[:, col]
  a_slots = jnp.where(new_slot[None, :], new_col[:, None], state.a_slots)
  g_new = _rmatvec(a_slots, new_col)  # (m,) = A_S^T A[:, col]
  gram = jnp.where(new_slot[None, :], g_new[:, None], state.gram)
  gram = jnp.where(new_slot[:, None], g_new[None, :], gram)
  atb = jnp.where(new_slot, _sum(_mul(new_col, b), axis=0), state.atb)

  # (2) Interpolate towards z until the first passive variable reaches zero; drop the ones at zero. An
  # entering column whose own value is not positive (rounding) is banned.
  blocking = used & (z <= 0)
  ratio = jnp.where(blocking, slot_x / jnp.where(blocking, slot_x - z, 1.0), jnp.inf)
  first = jnp.argmin(ratio)
  x_interp = slot_x + _mul(ratio[first], z - slot_x)
  drop = used & ((x_interp <= 0) | (slot_ids == first))
  ban = jnp.any(drop & entered & (z <= 0))
  ban_col = _sum(jnp.where(entered, slot_col, 0), axis=0)  # At most one slot has entered.
  banned_interp = state.banned | ((jnp.arange(n) == ban_col) & ban)

  interpolate = ~positive & ~done
  return _State(
      slot_x=jnp.where(done, slot_x, jnp.where(positive, z, jnp.where(drop, 0.0, x_interp))),
      slot_col=jnp.where(new_slot, col, slot_col),
      used=jnp.where(interpolate, used & ~drop, used | new_slot),
      a_slots=a_slots,
      gram=gram,
      atb=atb,
      banned=jnp.where(done, state.banned, jnp.where(positive, banned_accept, banned_interp)),
      done=done | (positive & ~add),
  )


def nnls(
    a: jax.Array,
    b: jax.Array,
    *,
    num_iterations: int | None = None,
    tol: float = DEFAULT_DUAL_TOL,
) -> NNLSResult:
  """Solves min_{x >= 0} ||a x - b|| for ONE small problem (batch with `jax.vmap`).

  Lawson--Hanson active set with a fixed trip count (see the module docstring). Works in float32 and is
  meant for m <= ~8 rows, n <= ~24 columns; the cost per iteration grows like m^3 + m n.

  Args:
    a: (m, n) matrix.
    b: (m,) right-hand side.
    num_iterations: loop trip count (static); default `DEFAULT_NUM_ITERATIONS`. Each iteration adds one
      column or drops at least one; the optimum needs at least (number of positive x) + 1.
    tol: dual tolerance relative to max_j ||a[:, j]|| * ||b||: the loop stops when no inactive column has
      a dual a[:, j]^T (b - a x) above tol * max_j ||a[:, j]|| * ||b||.

  Returns:
    `NNLSResult` with x (n,), residual () in the units of b, converged ().
  """
  a = jnp.asarray(a, dtype=jnp.float32)
  b = jnp.asarray(b, dtype=jnp.float32)
  m, n = a.shape
  if b.shape != (m,):
    raise ValueError(f"b must have shape ({m},), got {b.shape}")
  if num_iterations is None:
    num_iterations = DEFAULT_NUM_ITERATIONS
  col_norm = jnp.sqrt(jnp.max(_sum(_mul(a, a), axis=0)))
  dual_tol = tol * col_norm * jnp.sqrt(_sum(_mul(b, b), axis=0))
  state = _State(
      slot_x=jnp.zeros((m,), b.dtype),
      slot_col=jnp.zeros((m,), jnp.int32),
      used=jnp.zeros((m,), bool),
      a_slots=jnp.zeros((m, m), b.dtype),
      gram=jnp.zeros((m, m), b.dtype),
      atb=jnp.zeros((m,), b.dtype),
      banned=jnp.zeros((n,), bool),
      done=jnp.zeros((), bool),
  )
  a_t = a.T
  state = jax.lax.fori_loop(0, num_iterations, lambda _, s: _step(a, a_t, b, dual_tol, s), state)
  onehot = (state.slot_col[:, None] == jnp.arange(n)[None, :]) & state.used[:, None]
  x = _sum(jnp.where(onehot, state.slot_x[:, None], 0.0), axis=0)
  r = b - _matvec(a, x)
  return NNLSResult(x=x, residual=jnp.sqrt(_sum(_mul(r, r), axis=0)), converged=state.done)


def lift_bounded_groups(
    g: jax.Array, t: jax.Array, groups: jax.Array, limits: jax.Array
) -> tuple[jax.Array, jax.Array]:
  """Builds the lifted NNLS system of one wrench-resistance problem.

  Args:
    g: (6, n) wrench matrix, N (torque rows already scaled to N).
    t: (6,) wrench to produce (minus the external wrench), N.
    groups: (k, n) 0/1 group membership of the columns.
    limits: (k,) upper bounds of the group sums, N.

  Returns:
    (a, b): a = [[g, 0], [groups, I_k]] of shape (6 + k, n + k) and b = [t; limits] of shape (6 + k,),
    float32, such that min_{x >= 0} ||a x - b|| is the residual of the module docstring.
  """
  g = jnp.asarray(g, jnp.float32)
  t = jnp.asarray(t, jnp.float32)
  groups = jnp.asarray(groups, jnp.float32)
  limits = jnp.asarray(limits, jnp.float32)
  k = groups.shape[0]
  top = jnp.concatenate([g, jnp.zeros((g.shape[0], k), jnp.float32)], axis=1)
  bottom = jnp.concatenate([groups, jnp.eye(k, dtype=jnp.float32)], axis=1)
  return jnp.concatenate([top, bottom], axis=0), jnp.concatenate([t, limits])


def wrench_residual(
    g: jax.Array, t: jax.Array, groups: jax.Array, limits: jax.Array, **solver_kwargs: Any
) -> jax.Array:
  """Wrench-resistance residual of ONE grasp (batch with `jax.vmap`).

  Args:
    g: (6, n) wrench matrix, N (torque rows already scaled to N).
    t: (6,) wrench to produce (minus the external wrench), N.
    groups: (k, n) 0/1 group membership of the columns.
    limits: (k,) upper bounds of the group sums, N.
    **solver_kwargs: forwarded to `nnls` (num_iterations, tol).

  Returns:
    () float32 residual in N: sqrt(min_{alpha >= 0} ||g alpha - t||^2 + ||max(0, groups alpha - limits)||^2).
  """
  a, b = lift_bounded_groups(g, t, groups, limits)
  return nnls(a, b, **solver_kwargs).residual


def resists(
    g: jax.Array,
    t: jax.Array,
    groups: jax.Array,
    limits: jax.Array,
    tol: float = DEFAULT_RESIDUAL_TOL,
    **solver_kwargs: Any,
) -> jax.Array:
  """Whether ONE grasp resists: `wrench_residual` <= tol (tol in N, default 1 mN). Returns a () bool."""
  return wrench_residual(g, t, groups, limits, **solver_kwargs) <= tol
