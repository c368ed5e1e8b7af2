"""Wrench resistance as a non-negative least-squares problem.

A contact model describes what a grasp can apply to the object as a *wrench matrix* ``G`` of shape (6, n):
each column is a wrench generator (3 force rows in N, then 3 torque rows in N m already multiplied by a
torque scale in 1/m, so that every row is in newtons), combined with non-negative weights ``alpha``. Some
weights share a budget, written as *bounded-sum groups*: a 0/1 matrix ``C`` (k, n) and limits ``c`` (k,)
meaning "the alphas in group i should sum to at most c_i" (per-finger force limits in N for a parallel-jaw
gripper; for suction, a box |elastic torque| <= T written as a +/- column pair in one group with limit 1).
``t`` (6,) is the wrench the grasp must produce, i.e. minus the external wrench on the object.

Semantics:

  residual(G, t, C, c) = sqrt( min_{alpha >= 0}  ||G alpha - t||^2 + ||max(0, C alpha - c)||^2 )

  i.e. the smallest combination of unresisted wrench (N; torques scaled to N) and force-limit excess (N).
  A grasp *resists* iff residual <= tol (default tol = 1e-3, i.e. 1 mN).

This is computed exactly as an NNLS by lifting with slack variables s >= 0:

  A = [[G, 0], [C, I_k]]  ((6+k) x (n+k)),  b = [t; c],   residual = min_{x>=0} ||A x - b||.

(If the group sum is below its limit, the slack takes up the rest at zero cost; if above, the excess is
paid in the residual.)

The solver, `nnls`, is a Lawson--Hanson active-set method for ONE small problem (m <= ~8 rows,
n <= ~24 columns) in float32, written as a single `jax.lax.fori_loop` with a fixed trip count and static
shapes, so it runs plain, under `jax.jit` and under `jax.vmap` (batch it with `jax.vmap`):

* Lawson--Hanson keeps the passive columns linearly independent, so at most m are passive. They live in
  m *slots*: the slot matrix ``A_S`` (m, m), its Gram matrix ``A_S^T A_S`` and ``A_S^T b`` are updated by
  one column when a variable enters; unused slots are masked to the identity.
* The least-squares subproblem on the passive set is solved with a hand-unrolled Cholesky factorisation of
  the masked Gram matrix plus one step of iterative refinement with the residual formed from ``A_S``
  (corrected semi-normal equations). Unrolled element-wise code vectorises over a `vmap` batch; a batched
  LAPACK call is slow there on a CPU.
* Each iteration solves the subproblem once. A strictly positive solution is accepted and then, if the
  largest dual ``w = A^T (b - A x)`` over the inactive, non-banned columns exceeds the dual tolerance and a
  slot is free, that column enters. Otherwise the iteration interpolates towards the solution until the
  first passive variable reaches zero and drops the variables that reached zero. A column that enters but
  comes out of the subproblem non-positive (possible only through rounding) is banned until the passive
  set next grows, like the column rejection of the original Lawson--Hanson code. A converged state is a
  fixed point, so spare iterations change nothing.
* After the loop the subproblem on the final passive set is solved once more by modified Gram--Schmidt
  QR with reorthogonalisation, which is backward stable where the normal equations lose accuracy in
  float32 (a passive matrix with condition number >~ 1e3, e.g. a square, nearly singular exact fit). That
  solution is taken if it is strictly positive and has the smaller residual.
* Under `jax.vmap` the fixed loop is not run problem by problem for its whole trip count: a custom batching
  rule (`jax.custom_batching.custom_vmap`) hands the whole batch, however deeply nested the `vmap`, to
  `dexjax.quality.pooled_loop`, which stops each problem once it has converged and gives its lane to the next
  one (problems need 10 of the 32 iterations on average). A converged state is a fixed point of the
  iteration, so the results are the fixed loop's; the solver alone runs about 1.3x faster.
* Plain, `jit` and `vmap` calls give bitwise identical results: every sum is added in a fixed order and
  no product is contracted into a fused multiply-add (see `_mul`), so the rounding does not depend on how
  XLA vectorises the code.

Because x is always feasible, the reported residual is an upper bound of the true optimum up to float32
rounding of ||A x - b|| (~1e-7 ||b||): a rounding or convergence error can make a grasp look
*non*-resisting, not the other way round.

Gradients: the solver runs on `jax.lax.stop_gradient` copies of A and b and the residual is recomputed as
||A x - b|| at the (constant) minimiser x. Since x >= 0 does not depend on A or b, this is the exact
gradient of the optimal residual (envelope theorem), it costs one matrix-vector product instead of a
backward pass through the loop, and it is 0 (not NaN) where the residual is 0 or at the float32 noise floor
(below 1e-5 ||b||, where the residual vector is rounding with a meaningless direction and the true optimum is 0
nearby). ``x`` itself carries no gradient.
"""

from __future__ import annotations

import functools
from typing import Any, Callable

import jax
import jax.numpy as jnp
from flax import struct
from jax.custom_batching import custom_vmap

from dexjax.quality.pooled_loop import pooled_loop

# Loop iterations per row of A (static trip count = ITERATIONS_PER_ROW * m, 32 for the 8-row lifted
# parallel-jaw problem). Every iteration adds one column or drops at least one; on 10,000 lifted 8 x 22
# parallel-jaw problems 20 / 24 / 28 / 32 iterations converge 96.8 / 99.7 / 99.95 / 100 % of them.
ITERATIONS_PER_ROW = 4
# Dual tolerance relative to max_j ||A[:, j]|| * ||b||. It sits at the float32 noise floor of the dual on
# purpose: in degenerate problems a dual this small can still hide a residual reduction of ~1e-3 ||b||,
# and columns that enter on noise are harmless (rejected, or accepted at no cost).
DEFAULT_DUAL_TOL = 3e-8
# Default decision tolerance on the residual, newtons (1 mN).
DEFAULT_RESIDUAL_TOL = 1e-3
# Cholesky pivots are floored at this fraction of their Gram diagonal entry, and QR diagonal entries at
# this fraction of the column norm, so that a numerically dependent column cannot produce inf or NaN.
_PIVOT_FLOOR = 1e-6
_QR_FLOOR = 1e-6
# Residuals below this fraction of ||b|| (a few hundred times float32 rounding) carry no gradient.
_GRADIENT_FLOOR = 1e-5


@struct.dataclass
class NNLSResult:
  """Solution of one NNLS problem min_{x >= 0} ||A x - b||.

  Attributes:
    x: (n,) float32 non-negative minimiser (exact zeros off the passive set); not differentiated.
    residual: () float32 ||A x - b||, in the units of ``b``; differentiable in A and b.
    converged: () bool, True if the Lawson--Hanson optimality test passed within the iteration budget;
      if False, ``x`` is still feasible and ``residual`` an upper bound of the optimum.
  """

  x: jax.Array
  residual: jax.Array
  converged: jax.Array


@struct.dataclass
class _State:
  """Loop state of the slot-based Lawson--Hanson iteration (m slots, n columns).

  Attributes:
    slot_x: (m,) values of the passive variables in their slots; 0 in unused slots and for a column that
      entered in the previous iteration.
    slot_col: (m,) int32 column index held by each slot (meaningless where unused).
    used: (m,) bool, slot holds a passive column.
    a_slots: (m, m) columns of A held by the slots, A[:, slot_col] (stale where unused).
    gram: (m, m) A_S^T A_S over the slots (stale rows/columns where unused).
    atb: (m,) A_S^T b over the slots (stale where unused).
    banned: (n,) bool, column may not enter until the passive set next grows.
    done: () bool, the optimality test passed.
  """

  slot_x: jax.Array
  slot_col: jax.Array
  used: jax.Array
  a_slots: jax.Array
  gram: jax.Array
  atb: jax.Array
  banned: jax.Array
  done: jax.Array


def _opaque(v: jax.Array) -> jax.Array:
  """Returns v through a select the compiler cannot prove trivial (NaN stays NaN).

  XLA's CPU backend compiles the same expression differently depending on the surrounding program: a
  multiply feeding an add becomes a fused multiply-add in some fusions and not in others, and 1 / sqrt(x)
  becomes an approximate reciprocal square root. Either makes plain, `jit` and `vmap` results differ in
  the last bit. Hiding the intermediate value from the pattern matchers keeps every operation a single
  correctly rounded IEEE operation.
  """
  return jnp.where(v == v, v, jnp.nan)


def _mul(x: Any, y: Any) -> jax.Array:
  """Element-wise product that is never contracted into a fused multiply-add (see `_opaque`)."""
  return _opaque(x * y)


def _sqrt(x: jax.Array) -> jax.Array:
  """Square root that is never rewritten into a reciprocal square root (see `_opaque`)."""
  return _opaque(jnp.sqrt(x))


def _sum(v: jax.Array, axis: int) -> jax.Array:
  """Sum over a small axis, added strictly in index order (independent of XLA's reduction layout)."""
  v = jnp.moveaxis(v, axis, 0)
  total = v[0]
  for i in range(1, v.shape[0]):
    total = total + v[i]
  return total


def _matvec(a: jax.Array, v: jax.Array) -> jax.Array:
  """(p, q) @ (q,) -> (p,) as a broadcast product and an ordered sum (fuses under `vmap`)."""
  return _sum(_mul(a, v[None, :]), axis=1)


def _rmatvec(a: jax.Array, v: jax.Array) -> jax.Array:
  """(p, q)^T @ (p,) -> (q,) as a broadcast product and an ordered sum."""
  return _sum(_mul(a, v[:, None]), axis=0)


def _dot(u: list[Any], v: list[Any]) -> jax.Array:
  """Ordered dot product of two equal-length lists of scalars."""
  total = _mul(u[0], v[0])
  for i in range(1, len(u)):
    total = total + _mul(u[i], v[i])
  return total


def _cholesky(h: jax.Array) -> tuple[list[list[Any]], list[Any]]:
  """Unrolled Cholesky factorisation h = L L^T of a small symmetric positive definite matrix.

  Args:
    h: (m, m) symmetric matrix; only the lower triangle is read.

  Returns:
    (lower, diag): the strictly lower part of L as nested lists of scalars (lower[i][j], j < i) and the
    diagonal of L. Pivots are floored at `_PIVOT_FLOOR` times the diagonal of ``h``.
  """
  m = h.shape[0]
  lower = [[None] * m for _ in range(m)]
  diag = [None] * m
  for j in range(m):
    d = h[j, j]
    for k in range(j):
      d = d - _mul(lower[j][k], lower[j][k])
    floor = _mul(_PIVOT_FLOOR, h[j, j]) + jnp.finfo(h.dtype).tiny
    diag[j] = _sqrt(jnp.maximum(d, floor))
    for i in range(j + 1, m):
      s = h[i, j]
      for k in range(j):
        s = s - _mul(lower[i][k], lower[j][k])
      lower[i][j] = s / diag[j]
  return lower, diag


def _cholesky_solve(lower: list[list[Any]], diag: list[Any], rhs: jax.Array) -> jax.Array:
  """Solves L L^T z = rhs with a factor from `_cholesky`; rhs and the result are (m,)."""
  m = rhs.shape[0]
  y = [None] * m
  for i in range(m):
    s = rhs[i]
    for k in range(i):
      s = s - _mul(lower[i][k], y[k])
    y[i] = s / diag[i]
  z = [None] * m
  for i in reversed(range(m)):
    s = y[i]
    for k in range(i + 1, m):
      s = s - _mul(lower[k][i], z[k])
    z[i] = s / diag[i]
  return jnp.stack(z)


def _passive_least_squares(state: _State, b: jax.Array) -> jax.Array:
  """Least-squares solution on the used slots by Cholesky, (m,), zero in unused slots.

  Solves min ||A_S z - b|| with the Gram matrix masked to the identity on unused slots and one step of
  iterative refinement whose residual is formed with A_S.
  """
  used = state.used
  gram = jnp.where(used[:, None] & used[None, :], state.gram, jnp.eye(used.shape[0], dtype=b.dtype))
  a_s = jnp.where(used[None, :], state.a_slots, 0.0)
  lower, diag = _cholesky(gram)
  z = _cholesky_solve(lower, diag, jnp.where(used, state.atb, 0.0))
  r = b - _matvec(a_s, z)
  z = z + _cholesky_solve(lower, diag, _rmatvec(a_s, r))
  return jnp.where(used, z, 0.0)


def _qr_least_squares(a_slots: jax.Array, used: jax.Array, b: jax.Array) -> jax.Array:
  """Least-squares solution on the used slots by Gram--Schmidt QR, (m,), zero in unused slots.

  Classical Gram--Schmidt with one reorthogonalisation pass ("twice is enough"), then back-substitution
  and one step of iterative refinement. Both are short loops over the m slots so that the compiled program
  stays small. An unused slot gets a zero basis vector and a unit diagonal, so its value is 0.

  Args:
    a_slots: (m, m) slot columns (ignored where unused).
    used: (m,) bool slot mask.
    b: (m,) right-hand side.
  """
  m = used.shape[0]
  a_s = jnp.where(used[None, :], a_slots, 0.0)
  ids = jnp.arange(m)

  def orthogonalise(j, carry):
    q, r = carry  # Columns >= j of q are still zero.
    v = a_s[:, j]
    col_norm = _norm(v)
    c1 = _rmatvec(q, v)
    v = v - _matvec(q, c1)
    c2 = _rmatvec(q, v)
    v = v - _matvec(q, c2)
    use = used[j]
    d = jnp.where(use, jnp.maximum(_norm(v), _mul(_QR_FLOOR, col_norm)), 1.0)
    this = ids == j
    # Multiply by an explicit reciprocal: XLA rewrites a division by a broadcast scalar into exactly this
    # in some programs and not in others, which would change the rounding between plain and vmap calls.
    inv = jnp.where(use, _opaque(1.0 / d), 0.0)
    q = jnp.where(this[None, :], _mul(v, inv)[:, None], q)
    r = jnp.where(this[None, :], jnp.where(this, d, c1 + c2)[:, None], r)
    return q, r

  zeros = jnp.zeros((m, m), b.dtype)
  q, r = jax.lax.fori_loop(0, m, orthogonalise, (zeros, zeros))

  def solve(rhs: jax.Array) -> jax.Array:
    qtb = _rmatvec(q, rhs)

    def back_substitute(k, z):
      j = m - 1 - k  # Entries of z at and below j are still zero.
      return jnp.where(ids == j, (qtb[j] - _sum(_mul(r[j], z), axis=0)) / r[j, j], z)

    return jax.lax.fori_loop(0, m, back_substitute, jnp.zeros((m,), b.dtype))

  z = solve(b)
  z = z + solve(b - _matvec(a_s, z))
  return jnp.where(used, z, 0.0)


def _step(a: jax.Array, a_t: jax.Array, b: jax.Array, dual_tol: jax.Array, state: _State) -> _State:
  """One Lawson--Hanson iteration: accept-and-add or interpolate-and-drop.

  Args:
    a: (m, n) matrix.
    a_t: (n, m) its transpose (a row is gathered when a column enters).
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
  # entering column whose own value comes out non-positive (rounding) is banned.
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


def _scatter(slot_col: jax.Array, used: jax.Array, values: jax.Array, n: int) -> jax.Array:
  """Slot values (m,) -> column vector (n,), zero off the used slots (exact: one term per column)."""
  onehot = (slot_col[:, None] == jnp.arange(n)[None, :]) & used[:, None]
  return _sum(jnp.where(onehot, values[:, None], 0.0), axis=0)


def _norm(v: jax.Array) -> jax.Array:
  """Euclidean norm of a vector (), ordered sum."""
  return _sqrt(_sum(_mul(v, v), axis=0))


def _safe_norm(v: jax.Array) -> jax.Array:
  """`_norm` with a zero (not NaN) gradient at v = 0."""
  squared = _sum(_mul(v, v), axis=0)
  positive = squared > 0
  return jnp.where(positive, _sqrt(jnp.where(positive, squared, 1.0)), 0.0)


def nnls(
    a: jax.Array,
    b: jax.Array,
    *,
    num_iterations: int | None = None,
    tol: float = DEFAULT_DUAL_TOL,
) -> NNLSResult:
  """Solves min_{x >= 0} ||a x - b|| for ONE small problem (batch it with `jax.vmap`).

  Fixed-iteration Lawson--Hanson active set in float32 (see the module docstring), meant for m <= ~8 rows
  and n <= ~24 columns; one iteration costs O(m^3 + m n).

  Args:
    a: (m, n) matrix (cast to float32).
    b: (m,) right-hand side (cast to float32).
    num_iterations: static loop trip count; default ``ITERATIONS_PER_ROW * m`` (32 for m = 8). Every
      iteration adds one column or drops at least one, and the optimum needs at least
      (number of positive x) + 1 iterations.
    tol: dual tolerance relative to max_j ||a[:, j]|| * ||b||: the loop stops when no inactive column has
      a dual a[:, j]^T (b - a x) above tol * max_j ||a[:, j]|| * ||b||.

  Returns:
    `NNLSResult` with x (n,), residual () in the units of b and converged ().
  """
  a = jnp.asarray(a, dtype=jnp.float32)
  b = jnp.asarray(b, dtype=jnp.float32)
  if a.ndim != 2 or b.shape != a.shape[:1]:
    raise ValueError(f"expected a (m, n) and b (m,), got {a.shape} and {b.shape}; batch with jax.vmap")
  if num_iterations is None:
    num_iterations = ITERATIONS_PER_ROW * a.shape[0]
  # A plain call runs compiled too (inside `jit`/`vmap` the inner `jit` is inlined).
  return _nnls_compiled(a, b, jnp.float32(tol), num_iterations)


def _initial_state(m: int, n: int) -> _State:
  """The empty passive set of an (m, n) problem."""
  return _State(
      slot_x=jnp.zeros((m,), jnp.float32),
      slot_col=jnp.zeros((m,), jnp.int32),
      used=jnp.zeros((m,), bool),
      a_slots=jnp.zeros((m, m), jnp.float32),
      gram=jnp.zeros((m, m), jnp.float32),
      atb=jnp.zeros((m,), jnp.float32),
      banned=jnp.zeros((n,), bool),
      done=jnp.zeros((), bool),
  )


def _final_fields(state: _State) -> tuple[jax.Array, ...]:
  """What the solution needs of a final `_State`: (slot_x, slot_col, used, a_slots, done)."""
  return state.slot_x, state.slot_col, state.used, state.a_slots, state.done


def _broadcast_batched(axis_size: int, in_batched: list[bool], args: tuple) -> tuple:
  """The arguments of a `custom_vmap` rule, each with the batch axis in front (unbatched ones broadcast)."""
  return tuple(x if batched else jnp.broadcast_to(x, (axis_size,) + x.shape) for x, batched in zip(args, in_batched))


@functools.lru_cache(maxsize=None)
def _lawson_hanson(num_iterations: int) -> Callable[[jax.Array, jax.Array, jax.Array], tuple[jax.Array, ...]]:
  """The Lawson--Hanson iteration of one problem, ``(a (m, n), b (m,), dual_tol ()) -> `_final_fields```, for a
  static trip count.

  Called plainly it is the fixed loop of ``num_iterations`` `_step` calls. Under `jax.vmap` (at any depth of
  nesting) the problems of the whole batch go through `pooled_loop` instead: each stops when it has converged
  (a converged state is a fixed point of `_step`, so the spare iterations of the fixed loop change nothing)
  and its lane takes the next problem. The results are the fixed loop's, bit for bit.
  """

  def one(a, b, dual_tol):
    m, n = a.shape
    a_t = a.T
    state = jax.lax.fori_loop(0, num_iterations, lambda _, s: _step(a, a_t, b, dual_tol, s), _initial_state(m, n))
    return _final_fields(state)

  def many(a, b, dual_tol):  # a (B, m, n), b (B, m), dual_tol (B,)
    m, n = a.shape[1:]
    # The transpose travels with each problem (as `one` computes it once): transposing in every step measured
    # 0.9x (103-108k vs 115-117k problems/s).
    step = lambda item, s: _step(item[0], item[1], item[2], item[3], s)
    return pooled_loop(step, _initial_state(m, n), (a, jnp.swapaxes(a, 1, 2), b, dual_tol), num_iterations,
                       lambda s: s.done, keep=_final_fields)

  many = custom_vmap(many)
  one = custom_vmap(one)

  @many.def_vmap
  def _many_batched(axis_size, in_batched, a, b, dual_tol):  # one more batch axis in front: flatten it
    a, b, dual_tol = _broadcast_batched(axis_size, in_batched, (a, b, dual_tol))
    out = many(*(x.reshape((-1,) + x.shape[2:]) for x in (a, b, dual_tol)))
    return jax.tree.map(lambda x: x.reshape((axis_size, -1) + x.shape[1:]), out), jax.tree.map(lambda _: True, out)

  @one.def_vmap
  def _one_batched(axis_size, in_batched, a, b, dual_tol):
    out = many(*_broadcast_batched(axis_size, in_batched, (a, b, dual_tol)))
    return out, jax.tree.map(lambda _: True, out)

  return one


@functools.partial(jax.jit, static_argnums=3)
def _nnls_compiled(a: jax.Array, b: jax.Array, tol: jax.Array, num_iterations: int) -> NNLSResult:
  """`nnls` on float32 arrays of checked shapes."""
  m, n = a.shape
  # The minimiser is not differentiated; the residual is (see the module docstring).
  a_const, b_const = jax.lax.stop_gradient(a), jax.lax.stop_gradient(b)
  dual_tol = tol * _sqrt(jnp.max(_sum(_mul(a_const, a_const), axis=0))) * _norm(b_const)
  slot_x, slot_col, used, a_slots, done = _lawson_hanson(num_iterations)(a_const, b_const, dual_tol)

  x = _scatter(slot_col, used, slot_x, n)
  # Polish: re-solve on the final passive set with QR; keep it if strictly positive and better.
  z_qr = _qr_least_squares(a_slots, used, b_const)
  x_qr = _scatter(slot_col, used, z_qr, n)
  better = (jnp.all(jnp.where(used, z_qr > 0, True))
            & (_norm(b_const - _matvec(a_const, x_qr)) < _norm(b_const - _matvec(a_const, x))))
  x = jnp.where(better, x_qr, x)
  residual = _safe_norm(b - _matvec(a, x))
  # At the float32 noise floor the residual vector is rounding and its direction is meaningless, while the true
  # optimum is 0 in a neighbourhood: no gradient there (the value is unchanged).
  floor = _GRADIENT_FLOOR * _norm(b_const)
  residual = jnp.where(residual > floor, residual, jax.lax.stop_gradient(residual))
  return NNLSResult(x=x, residual=residual, converged=done)


def lift_bounded_groups(
    g: jax.Array, t: jax.Array, groups: jax.Array, limits: jax.Array
) -> tuple[jax.Array, jax.Array]:
  """Builds the lifted NNLS system of one wrench-resistance problem.

  Args:
    g: (6, n) wrench matrix, N (torque rows already multiplied by the torque scale).
    t: (6,) wrench to produce (minus the external wrench), N.
    groups: (k, n) 0/1 group membership of the columns.
    limits: (k,) upper bounds of the group sums (N for force limits).

  Returns:
    (a, b): a = [[g, 0], [groups, I_k]] of shape (6 + k, n + k) and b = [t; limits] of shape (6 + k,),
    float32, with min_{x >= 0} ||a x - b|| equal to the residual of the module docstring.
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
  """Wrench-resistance residual of ONE grasp (batch it with `jax.vmap`).

  Args:
    g: (6, n) wrench matrix, N (torque rows already multiplied by the torque scale).
    t: (6,) wrench to produce (minus the external wrench), N.
    groups: (k, n) 0/1 group membership of the columns.
    limits: (k,) upper bounds of the group sums.
    **solver_kwargs: forwarded to `nnls` (``num_iterations``, ``tol``).

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
    *,
    num_iterations: int | None = None,
    dual_tol: float = DEFAULT_DUAL_TOL,
) -> jax.Array:
  """Whether ONE grasp resists its target wrench (batch it with `jax.vmap`).

  Args:
    g, t, groups, limits: as in `wrench_residual`.
    tol: residual tolerance, N (default 1 mN).
    num_iterations: forwarded to `nnls`.
    dual_tol: the solver's relative dual tolerance, forwarded to `nnls` as ``tol``.

  Returns:
    () bool, `wrench_residual` <= tol.
  """
  return wrench_residual(g, t, groups, limits, num_iterations=num_iterations, tol=dual_tol) <= tol
