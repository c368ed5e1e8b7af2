"""A batched fixed-trip-count loop that stops each item early, by refilling a pool of lanes with new items.

``jax.vmap`` of ``jax.lax.fori_loop(0, T, step, init)`` runs every item for all T iterations, and a batched
``while_loop`` runs every item until the slowest one stops. When most items converge long before T (the
wrench solver's Lawson--Hanson iteration needs 10 of its 32 iterations on average), both spend most of their
time on items that are already finished. `pooled_loop` instead iterates a fixed *pool* of lanes: a lane whose
item is done hands its final state back and takes the next waiting item, so the work is about the total number
of iterations the items need, divided by the pool size, plus one tail of at most T iterations.

It is exact, not an approximation: each item goes through the same ``step`` calls on the same inputs as in the
fixed loop, and stops either when ``is_done`` holds (which ``step`` must leave unchanged: a done state is a
fixed point) or after T iterations. So its result equals the fixed loop's bit for bit, as long as ``step``
itself computes the same bits batched and unbatched (the wrench solver's element-wise code does).
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp

# Lanes per pool when the batch is larger: enough items per element-wise operation to amortise the loop's
# per-iteration overhead on a CPU, few enough that the tail (the last items finishing while lanes idle) is
# short. Chosen on the wrench solver's problems (`benchmarks/quality_throughput.py`).
DEFAULT_POOL_SIZE = 1024


def _take(tree: Any, index: jax.Array) -> Any:
  """Rows ``index`` (P,) of every leaf (B, ...) of ``tree``."""
  return jax.tree.map(lambda x: x[index], tree)


def _select(mask: jax.Array, on_true: Any, on_false: Any) -> Any:
  """Per lane (P,) choice between two pytrees of leaves (P, ...)."""
  return jax.tree.map(lambda t, f: jnp.where(mask.reshape(mask.shape + (1,) * (t.ndim - 1)), t, f),
                      on_true, on_false)


def pooled_loop(step: Callable[[Any, Any], Any], init: Any, inputs: Any, num_iterations: int,
                is_done: Callable[[Any], jax.Array], keep: Callable[[Any], Any] = lambda state: state,
                pool_size: int = DEFAULT_POOL_SIZE) -> Any:
  """Final states of ``fori_loop(0, num_iterations, lambda _, s: step(x, s), init)`` for every item x of a batch.

  Args:
    step: ``step(item_inputs, state) -> state`` for ONE item (it is `vmap`-ed over the pool's lanes). A state
      for which ``is_done`` holds must come back unchanged.
    init: the initial state of one item (a pytree of arrays, the same for every item).
    inputs: pytree of arrays with a leading batch axis B: the items.
    num_iterations: static trip count T of the fixed loop.
    is_done: ``is_done(state) -> () bool`` for one item.
    keep: ``keep(state) -> part`` of one item's final state that is returned (default: all of it).
    pool_size: static number of lanes (at most B are used).

  Returns:
    ``keep`` of the final states, with a leading axis B.
  """
  batch = jax.tree.leaves(inputs)[0].shape[0]
  lanes = max(1, min(pool_size, batch))
  stack = lambda tree, k: jax.tree.map(lambda x: jnp.broadcast_to(x, (k,) + jnp.shape(x)), tree)
  results = stack(keep(init), batch)
  if batch == 0 or num_iterations <= 0:
    return results
  step_lanes = jax.vmap(step)
  done_lanes = jax.vmap(is_done)
  keep_lanes = jax.vmap(keep)
  fresh = stack(init, lanes)
  first = jnp.arange(lanes, dtype=jnp.int32)

  def cond(carry):
    return jnp.any(carry[3])

  def body(carry):
    state, item, count, active, waiting, results, lane_inputs = carry
    state = step_lanes(lane_inputs, state)
    count = count + 1
    finished = active & (done_lanes(state) | (count >= num_iterations))
    # Finished lanes write their item's result; the others write nowhere (index B is dropped).
    target = jnp.where(finished, item, batch)
    results = jax.tree.map(lambda r, s: r.at[target].set(s, mode='drop'), results, keep_lanes(state))
    # Each finished lane takes the next waiting item, in lane order, while items remain.
    next_item = waiting + jnp.cumsum(finished, dtype=jnp.int32) - 1
    refill = finished & (next_item < batch)
    item = jnp.where(refill, next_item, item)
    lane_inputs = _select(refill, _take(inputs, jnp.minimum(next_item, batch - 1)), lane_inputs)
    state = _select(refill, fresh, state)
    count = jnp.where(refill, 0, count)
    active = jnp.where(finished, refill, active)
    waiting = waiting + jnp.sum(finished, dtype=jnp.int32)
    return state, item, count, active, waiting, results, lane_inputs

  carry = (fresh, first, jnp.zeros(lanes, jnp.int32), jnp.ones(lanes, bool), jnp.int32(lanes), results,
           _take(inputs, first))
  return jax.lax.while_loop(cond, body, carry)[5]


__all__ = ['DEFAULT_POOL_SIZE', 'pooled_loop']
