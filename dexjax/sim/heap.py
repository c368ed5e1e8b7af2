"""The Dex-Net 4.0 heap state distribution xi(x0) (seed, "State Distribution", items 1, 2 and 4) and the bin.

One draw is a pure function of a `jax.random` key with static shapes (padded to ``dist.max_count`` objects
plus a mask), so it `jit`s and `vmap`s::

  keys = jax.random.split(key, 64)
  states = jax.vmap(lambda k: sample_heap_state(k, num_available, dist))(keys)   # leading axis 64

* object count m ~ Poisson(lambda = 5) *conditioned* on 3 <= m <= 10 (the distribution that rejection
  sampling gives; not clipping, which would pile the tails' mass on 3 and 10). Drawn exactly from the
  normalised truncated pmf with one categorical draw, so there is no loop. ``count_truncation='clip'`` gives
  the clipped law instead (what the public SD Mask R-CNN heap code, a relative of Dex-Net's, does). When
  fewer than ``max_count`` objects are available the upper bound becomes ``num_available`` (objects are drawn
  without replacement). ``count_law='uniform'`` draws m uniformly from the bounds instead: the counts a full
  bin passes through as it is emptied one object at a time, for training data like the benchmark's bins of 25
  (``configs/deployment.yaml``);
* object identities: the first m entries of a uniform random permutation of ``range(num_available)``
  (uniform without replacement);
* orientation uniform on SO(3) (a normalised 4-D Gaussian, i.e. a Haar-uniform unit quaternion, wxyz);
* drop position of the object's centre of mass uniform on [-0.125, 0.125]^2 m (about ``drop_center``) at
  z = 0.15 m above the bin floor (the floor is the plane z = 0 of the world frame);
* friction per object: the seed's truncated Gaussian, mean 0.8, variance 0.01, truncated to [0, 1], drawn by
  `dexjax.quality.sample_conditions` (the same sampler the reward model uses).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from dexjax.quality.robust import Perturbations, sample_conditions

#: Largest number of objects in a Dex-Net 4.0 heap (seed: at most 10), the default padded length.
MAX_OBJECTS = 10
#: The laws of a heap's object count (`HeapDistribution.count_law`).
COUNT_LAWS = ('poisson', 'uniform')


@struct.dataclass
class Bin:
  """An open box on the world's z = 0 plane: the floor's top face is z = 0, centred on the origin.

  Attributes:
    inner_size: (x, y) inner extent of the floor between the walls, metres. The default 0.4 x 0.4 m holds the
      0.25 x 0.25 m drop area with a 7.5 cm margin on every side.
    wall_height: height of the walls' top above the floor, metres.
    wall_thickness: thickness of the walls and of the floor slab, metres.
  """

  inner_size: tuple[float, float] = struct.field(pytree_node=False, default=(0.4, 0.4))
  wall_height: float = struct.field(pytree_node=False, default=0.1)
  wall_thickness: float = struct.field(pytree_node=False, default=0.01)

  def validate(self) -> None:
    """Raises ValueError naming the field when a dimension is not a positive finite number."""
    for field, value in (('inner_size[0]', self.inner_size[0]), ('inner_size[1]', self.inner_size[1]),
                         ('wall_height', self.wall_height), ('wall_thickness', self.wall_thickness)):
      if not (math.isfinite(value) and value > 0):
        raise ValueError(f'Bin.{field}: expected a finite number > 0 (metres), got {value!r}')


@struct.dataclass
class HeapDistribution:
  """Parameters of the heap state distribution (defaults: Dex-Net 4.0, seed "State Distribution").

  Attributes:
    count_mean: lambda of the Poisson object count (before truncation).
    min_count, max_count: static truncation bounds of the count; ``max_count`` is also the padded length of
      every `HeapState` array.
    count_truncation: static, ``'condition'`` (Poisson conditioned on the bounds: the law of rejection
      sampling, the seed's reading) or ``'clip'`` (Poisson clipped to the bounds).
    count_law: static, ``'poisson'`` (the seed's: ``count_mean`` and ``count_truncation``) or ``'uniform'``
      (every count in the bounds equally likely: the counts a bin of ``max_count`` objects passes through, one
      pick at a time, as the benchmark empties it; ``count_mean`` and ``count_truncation`` are then unused).
    drop_half_width: drop positions are uniform on ``drop_center`` +- this in x and y, metres.
    drop_center: (x, y) centre of the drop square, metres.
    drop_height: height of the dropped centre of mass above the bin floor, metres.
    friction_mean, friction_variance, friction_range: the per-object Coulomb friction, a normal with this mean
      and variance truncated to ``friction_range``.
  """

  count_mean: float = 5.0
  min_count: int = struct.field(pytree_node=False, default=3)
  max_count: int = struct.field(pytree_node=False, default=MAX_OBJECTS)
  count_truncation: str = struct.field(pytree_node=False, default='condition')
  count_law: str = struct.field(pytree_node=False, default='poisson')
  drop_half_width: float = 0.125
  drop_center: tuple[float, float] = (0.0, 0.0)
  drop_height: float = 0.15
  friction_mean: float = 0.8
  friction_variance: float = 0.01
  friction_range: tuple[float, float] = (0.0, 1.0)


@struct.dataclass
class HeapState:
  """One heap's initial state, padded to P = ``dist.max_count`` objects (a leading batch axis under `vmap`).

  Attributes:
    object_ids: (P,) int32 indices into the list of available objects; -1 in padded slots.
    mask: (P,) bool, True for the m objects of the heap (always the first m slots).
    positions: (P, 3) float32, world position of each object's centre of mass at the drop, metres (zeros in
      padded slots).
    quaternions: (P, 4) float32 unit quaternions (w, x, y, z) rotating the object frame into the world frame
      (identity in padded slots).
    friction: (P,) float32 Coulomb friction coefficient of each object (zero in padded slots).
  """

  object_ids: jax.Array
  mask: jax.Array
  positions: jax.Array
  quaternions: jax.Array
  friction: jax.Array

  @property
  def num_objects(self) -> jax.Array:
    """() (or (B,)) int32 number of objects m in the heap."""
    return jnp.sum(self.mask, axis=-1).astype(jnp.int32)


def select_heap(states: HeapState, b: int) -> HeapState:
  """Heap ``b`` of a batched `HeapState` (the leading axis dropped)."""
  return jax.tree.map(lambda x: x[b], states)


def _count_bounds(num_available: int, dist: HeapDistribution) -> tuple[int, int]:
  """(low, high) bounds of the object count given the number of available objects; checks them."""
  if not isinstance(num_available, (int, np.integer)) or num_available < 1:
    raise ValueError(f'num_available: expected a positive Python int (static), got {num_available!r}')
  if not 1 <= dist.min_count <= dist.max_count:
    raise ValueError(f'HeapDistribution.min_count/max_count: expected 1 <= min_count <= max_count, got '
                     f'{dist.min_count}, {dist.max_count}')
  if dist.count_truncation not in ('condition', 'clip'):
    raise ValueError(f"HeapDistribution.count_truncation: expected 'condition' or 'clip', got "
                     f'{dist.count_truncation!r}')
  if dist.count_law not in COUNT_LAWS:
    raise ValueError(f'HeapDistribution.count_law: expected one of {COUNT_LAWS}, got {dist.count_law!r}')
  if num_available < dist.min_count:
    raise ValueError(f'num_available: expected at least HeapDistribution.min_count = {dist.min_count} objects '
                     f'(they are drawn without replacement), got {num_available}')
  return dist.min_count, min(dist.max_count, int(num_available))


def truncated_poisson_pmf(mean: float, low: int, high: int) -> np.ndarray:
  """Probabilities (high - low + 1,) of k = low..high under Poisson(``mean``) conditioned on low <= k <= high."""
  k = np.arange(low, high + 1)
  log_p = k * math.log(mean) - np.array([math.lgamma(x + 1.0) for x in k])
  p = np.exp(log_p - log_p.max())
  return p / p.sum()


def sample_object_count(key: jax.Array, num_available: int, dist: HeapDistribution = HeapDistribution()) -> jax.Array:
  """Object count m, () int32: Poisson(``dist.count_mean``) conditioned on [min_count, min(max_count, N)].

  Exactly the law of rejection sampling (redraw until the count is in range), drawn with one categorical draw;
  with ``dist.count_truncation == 'clip'``, a Poisson draw clipped to the bounds; with ``dist.count_law ==
  'uniform'``, uniform on the bounds.
  """
  low, high = _count_bounds(num_available, dist)
  if dist.count_law == 'uniform':
    return jax.random.randint(key, (), low, high + 1, dtype=jnp.int32)
  if dist.count_truncation == 'clip':
    return jnp.clip(jax.random.poisson(key, dist.count_mean), low, high).astype(jnp.int32)
  k = jnp.arange(low, high + 1, dtype=jnp.float32)
  logits = k * jnp.log(jnp.asarray(dist.count_mean, jnp.float32)) - jax.lax.lgamma(k + 1.0)
  return (low + jax.random.categorical(key, logits)).astype(jnp.int32)


def sample_uniform_quaternion(key: jax.Array) -> jax.Array:
  """A unit quaternion (4,) float32 (w, x, y, z) uniform on SO(3) (Haar measure)."""
  q = jax.random.normal(key, (4,))
  return q / jnp.maximum(jnp.linalg.norm(q), 1e-12)


def sample_friction(key: jax.Array, dist: HeapDistribution = HeapDistribution()) -> jax.Array:
  """One Coulomb friction coefficient, () float32, from the seed's truncated Gaussian (the reward model's
  sampler, `dexjax.quality.sample_conditions`, with this distribution's friction parameters)."""
  perturbations = Perturbations(friction_mean=dist.friction_mean, friction_variance=dist.friction_variance,
                                friction_range=dist.friction_range)
  return sample_conditions(key, perturbations, jnp.array([0.0, 0.0, 1.0])).friction


def sample_heap_state(key: jax.Array, num_available: int,
                      dist: HeapDistribution = HeapDistribution()) -> HeapState:
  """Draws one heap's initial state x0 ~ xi (padded; batch with `jax.vmap` over keys).

  Args:
    key: a `jax.random` key.
    num_available: static number N of available objects; ids are drawn from range(N) without replacement.
    dist: the distribution's parameters.

  Returns:
    A `HeapState` with arrays padded to ``dist.max_count`` slots; the heap's objects are the first m slots.

  Raises:
    ValueError: ``num_available`` is not a positive int or is smaller than ``dist.min_count``.
  """
  _, high = _count_bounds(num_available, dist)
  pad = dist.max_count
  k_count, k_ids, k_rot, k_pos, k_mu = jax.random.split(key, 5)
  count = sample_object_count(k_count, num_available, dist)
  slots = jnp.arange(pad)
  mask = slots < count
  ids = jax.random.permutation(k_ids, num_available)[:high].astype(jnp.int32)
  ids = jnp.concatenate([ids, jnp.full((pad - high,), -1, jnp.int32)])
  ids = jnp.where(mask, ids, -1)
  quats = jax.vmap(sample_uniform_quaternion)(jax.random.split(k_rot, pad))
  quats = jnp.where(mask[:, None], quats, jnp.array([1.0, 0.0, 0.0, 0.0]))
  xy = jax.random.uniform(k_pos, (pad, 2), minval=-1.0, maxval=1.0) * dist.drop_half_width
  xy = xy + jnp.asarray(dist.drop_center, jnp.float32)
  positions = jnp.concatenate([xy, jnp.full((pad, 1), dist.drop_height, jnp.float32)], axis=1)
  positions = jnp.where(mask[:, None], positions, 0.0).astype(jnp.float32)
  friction = jax.vmap(lambda k: sample_friction(k, dist))(jax.random.split(k_mu, pad))
  friction = jnp.where(mask, friction, 0.0).astype(jnp.float32)
  return HeapState(object_ids=ids, mask=mask, positions=positions, quaternions=quats.astype(jnp.float32),
                   friction=friction)


@functools.partial(jax.jit, static_argnums=(1, 2))
def sample_heap_states(key: jax.Array, num_heaps: int, num_available: int,
                       dist: HeapDistribution = HeapDistribution()) -> HeapState:
  """``num_heaps`` independent heap states: `sample_heap_state` over ``jax.random.split(key, num_heaps)``.

  Args:
    key: a `jax.random` key.
    num_heaps: static batch size B.
    num_available: static number N of available objects.
    dist: the distribution's parameters.

  Returns:
    A `HeapState` whose arrays have a leading axis of B heaps.
  """
  keys = jax.random.split(key, num_heaps)
  return jax.vmap(lambda k: sample_heap_state(k, num_available, dist))(keys)
