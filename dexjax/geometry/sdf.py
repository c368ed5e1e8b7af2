"""Queries on an `ObjectModel`'s signed distance grid: value, gradient, normal, line and ray marching.

All functions take one point / one line / one ray and are pure, so they `jit`, `vmap` and (where the grid is
smooth) `grad`. The crossings of `first_crossing` and `ray_cast` carry the implicit-function gradient of a crossing
on the surface's tangent plane, whatever search found them (`_implicit_root`); their values are the
search's, bit for bit. Coordinates are in the object frame, metres. Outside the grid the distance is continued as
``sdf(clamp(x)) + |x - clamp(x)|`` (an upper bound of the true distance by the triangle inequality, exact
straight out from a face); signs stay right, and `ray_cast` only steps inside the grid box.
"""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np

from dexjax.geometry.object_model import ObjectModel, StackedObjectModel
from dexjax.geometry.transforms import normalize

_CORNERS = np.array(list(itertools.product((0, 1), repeat=3)), np.int32)  # (8, 3)


def _cell(model: ObjectModel, x: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
  """Lower cell corner (3,) int, fractional offset (3,) and distance from ``x`` to the grid box, metres."""
  d = model.grid_size
  g = (x - model.origin) / model.voxel_size
  gc = jnp.clip(g, 0.0, d - 1.0)
  sq = jnp.sum((g - gc) ** 2)
  pos = sq > 0.0  # double `where`: the norm's gradient at 0 is NaN, and the point is usually inside the grid
  outside = jnp.where(pos, jnp.sqrt(jnp.where(pos, sq, 1.0)), 0.0) * model.voxel_size
  i0 = jnp.clip(jnp.floor(gc), 0, d - 2).astype(jnp.int32)
  return i0, gc - i0, outside


def _trilinear(model: ObjectModel, grid: jax.Array, i0: jax.Array, frac: jax.Array) -> jax.Array:
  """Trilinear interpolation of ``grid`` (``model.sdf`` or ``model.sdf_grad``: (D, D, D, ...), or (N, D, D, D, ...)
  for a `StackedObjectModel`, read at its ``index``) in the cell at ``i0`` with offsets ``frac``.

  One linear index for the cell plus eight constant corner offsets (twice the lookups per second of indexing
  each corner's three coordinates, measured at D = 100)."""
  d = model.grid_size
  stacked = isinstance(model, StackedObjectModel)
  flat = grid.reshape((-1,) + grid.shape[4 if stacked else 3:])
  lin = (i0[0] * d + i0[1]) * d + i0[2]
  if stacked:
    lin = lin + model.index * (d * d * d)
  w = jnp.prod(jnp.where(_CORNERS == 1, frac[None, :], 1.0 - frac[None, :]), axis=-1)  # (8,)
  return jnp.tensordot(w, flat[lin + _corner_offsets(d)], axes=1)


def _corner_offsets(d: int) -> np.ndarray:
  """(8,) linear-index offsets of a cell's corners in a flattened (D, D, D) grid, in `_CORNERS` order."""
  return ((_CORNERS[:, 0] * d + _CORNERS[:, 1]) * d + _CORNERS[:, 2]).astype(np.int32)


def sdf_value(model: ObjectModel, x: jax.Array) -> jax.Array:
  """Signed distance () in metres at point ``x`` (3,); negative inside the object."""
  i0, frac, outside = _cell(model, x)
  return _trilinear(model, model.sdf, i0, frac) + outside


def sdf_gradient(model: ObjectModel, x: jax.Array) -> jax.Array:
  """Gradient (3,) of the signed distance at ``x`` (3,), trilinearly interpolated from the gradient grid."""
  i0, frac, _ = _cell(model, x)
  return _trilinear(model, model.sdf_grad, i0, frac)


def surface_normal(model: ObjectModel, x: jax.Array) -> jax.Array:
  """Outward unit surface normal (3,) at (or near) surface point ``x`` (3,)."""
  return normalize(sdf_gradient(model, x))


def _false_position(ta, tb, fa, fb):
  """Root estimate of the secant through (ta, fa) and (tb, fb); the midpoint if it is degenerate."""
  denom = fa - fb
  ok = jnp.abs(denom) > 1e-12
  return jnp.where(ok, ta + fa * (tb - ta) / jnp.where(ok, denom, 1.0), 0.5 * (ta + tb))


def _regula_falsi(f, ta, tb, fa, fb, num_iterations: int):
  """Illinois false-position refinement of a root of ``f`` bracketed by fa > 0 >= fb."""

  def body(_, state):
    ta, tb, fa, fb = state
    t = _false_position(ta, tb, fa, fb)
    ft = f(t)
    pos = ft > 0
    return (jnp.where(pos, t, ta), jnp.where(pos, tb, t),
            jnp.where(pos, ft, 0.5 * fa), jnp.where(pos, 0.5 * fb, ft))

  return _false_position(*jax.lax.fori_loop(0, num_iterations, body, (ta, tb, fa, fb)))


@jax.custom_jvp
def _implicit_root(model: ObjectModel, start: jax.Array, direction: jax.Array, t: jax.Array) -> jax.Array:
  """``t``, where the line ``start + t direction`` crosses the surface (found by any search), with the gradient
  of the implicit function theorem on the surface's tangent plane there: the value is ``t`` exactly (the
  search is not differentiated) and dt = -g . d(start + t direction) / (g . direction), g the interpolated
  `sdf_gradient` at the crossing (continuous across cells, unlike the derivative of the trilinear distance).
  A grazing line (|g . direction| < 1e-6) gets no gradient instead of an infinite one.

  A custom JVP, so that a pass without derivatives (labelling) does not look up the gradient at all."""
  del model, start, direction
  return jax.lax.stop_gradient(t)


@_implicit_root.defjvp
def _implicit_root_jvp(primals, tangents):
  model, start, direction, t = primals
  _, d_start, d_direction, _ = tangents
  t = jax.lax.stop_gradient(t)
  g = jax.lax.stop_gradient(sdf_gradient(model, start + t * direction))
  slope = jax.lax.stop_gradient(jnp.dot(g, direction))
  safe = jnp.where(jnp.abs(slope) > 1e-6, slope, jnp.inf)
  return t, -jnp.dot(g, d_start + t * d_direction) / safe


def first_crossing(model: ObjectModel, start: jax.Array, direction: jax.Array, length: float | jax.Array,
                   num_samples: int, *, exiting: bool = False,
                   num_refine: int = 3) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
  """First surface crossing along the segment ``start + t * direction``, t in [0, length].

  The segment is sampled at ``num_samples`` evenly spaced points (static); the first sample on the far side
  of the surface brackets the crossing, which is refined by ``num_refine`` steps of false position.

  Args:
    model: the object.
    start: (3,) segment start, metres.
    direction: (3,) unit direction.
    length: segment length, metres.
    num_samples: static number of samples (spacing = length / (num_samples - 1)).
    exiting: if False find the first outside -> inside crossing (a jaw or ray hitting the surface);
      if True the first inside -> outside crossing (leaving the object).
    num_refine: false-position iterations.

  Returns:
    t: () distance along the segment of the crossing, metres (undefined when not ``hit``).
    hit: () bool, a crossing was found and the start is on the expected side.
    starts_wrong_side: () bool, the start is already inside (or outside when ``exiting``) the object.
    deepest: () the smallest sampled signed distance along the segment, metres (negated when ``exiting``): < 0
      where a sample lies beyond the surface; differentiable in ``start`` and ``direction`` (the samples move
      with the segment), e.g. a margin of "the segment meets the surface" (`dexjax.quality.smooth`).
  """
  sign = -1.0 if exiting else 1.0
  f = lambda t: sign * sdf_value(model, start + t * direction)
  ts = jnp.linspace(0.0, 1.0, num_samples) * length
  phi = jax.vmap(f)(ts)
  beyond = phi <= 0.0
  starts_wrong_side = beyond[0]
  k = jnp.maximum(jnp.argmax(beyond), 1)
  hit = jnp.any(beyond) & ~starts_wrong_side
  t = _regula_falsi(f, ts[k - 1], ts[k], phi[k - 1], phi[k], num_refine)
  return _implicit_root(model, start, direction, t), hit, starts_wrong_side, jnp.min(phi)


def ray_cast(model: ObjectModel, origin: jax.Array, direction: jax.Array, *, num_steps: int = 32,
             max_distance: float | jax.Array = jnp.inf) -> tuple[jax.Array, jax.Array, jax.Array]:
  """First hit of the ray ``origin + t * direction`` (t >= 0) with the object surface, by sphere tracing.

  Marching starts where the ray enters the grid box and steps by the signed distance (at least a tenth of a
  voxel), so it cannot skip a wall thicker than that; a final Newton step along the ray refines the hit.

  Args:
    model: the object.
    origin: (3,) ray origin, metres (may be far outside the grid).
    direction: (3,) unit direction.
    num_steps: static number of sphere-tracing steps.
    max_distance: hits beyond this distance along the ray are reported as misses.

  Returns:
    t: () distance to the hit along the ray, metres (undefined when not ``hit``).
    hit: () bool.
    closest: () the smallest signed distance at the marching points, metres: about the ray's closest approach to
      the surface for a miss (> 0; for a ray that passes outside the grid box, the distance at its point nearest
      the box's centre), below a tenth of a voxel for a hit; differentiable in ``origin`` and ``direction`` (the
      points move with the ray), e.g. a margin of "the ray meets the surface".
  """
  d = model.grid_size
  lo = model.origin - 0.5 * model.voxel_size
  hi = lo + d * model.voxel_size
  safe = jnp.where(jnp.abs(direction) > 1e-9, direction, 1e-9)
  ta, tb = (lo - origin) / safe, (hi - origin) / safe
  t_enter = jnp.maximum(jnp.max(jnp.minimum(ta, tb)), 0.0)
  t_exit = jnp.minimum(jnp.min(jnp.maximum(ta, tb)), max_distance)
  min_step = 0.1 * model.voxel_size
  hit_tol = 0.01 * model.voxel_size

  def body(_, state):
    t, done, closest_t, closest = state
    phi = jax.lax.stop_gradient(sdf_value(model, origin + t * direction))
    inside = t <= t_exit
    nearer = inside & (phi < closest)
    closest_t, closest = jnp.where(nearer, t, closest_t), jnp.where(nearer, phi, closest)
    done = done | (phi < hit_tol) | (t > t_exit)
    return jnp.where(done, t, t + jnp.maximum(phi, min_step)), done, closest_t, closest

  start = jax.lax.stop_gradient(t_enter)
  t, _, closest_t, _ = jax.lax.fori_loop(0, num_steps, body, (start, jnp.array(False), start, jnp.array(jnp.inf)))
  t, closest_t = jax.lax.stop_gradient(t), jax.lax.stop_gradient(closest_t)
  # A ray that misses the grid box marches nowhere: its closest point is taken nearest the box's centre (where
  # the distance outside the grid is finite and a lower bound of sorts, not the far-away slab crossing).
  nearest_centre = jnp.clip(jnp.dot(0.5 * (lo + hi) - origin, direction), 0.0, max_distance)
  closest_t = jnp.where(t_enter <= t_exit, closest_t, jax.lax.stop_gradient(nearest_centre))
  closest = sdf_value(model, origin + closest_t * direction)
  p = origin + t * direction
  phi = sdf_value(model, p)
  slope = jnp.dot(sdf_gradient(model, p), direction)
  step = jnp.clip(-phi / jnp.minimum(slope, -0.1), -model.voxel_size, model.voxel_size)
  t = _implicit_root(model, origin, direction, t + step)
  hit = (phi < min_step) & (t <= t_exit) & (t_enter <= t_exit)
  return t, hit, closest
