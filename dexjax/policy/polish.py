"""Gradient polishing of image grasps: a few projected Adam steps on a GQ-CNN's predicted probability.

A GQ-CNN reads a grasp through its crop, which is a bilinear resampling of the depth image around the grasp
centre rotated by the grasp angle, and through its pose input (the gripper depth, and for suction the approach
angle). Both are differentiable in the grasp, so the network's probability has a gradient with respect to the
grasp's pixel, angle and depth. `polish_grasps` follows it from K starting grasps (a CEM's best):

* the variables are offsets from each start in units of (``pixel_unit`` px, ``pixel_unit`` px, ``angle_unit`` rad,
  ``depth_unit`` m) for the parallel jaw, (``pixel_unit``, ``pixel_unit``) for suction, whose depth and approach are
  read from the image at the centre (bilinear reads of the depth and of its `surface_normals`), as the suction
  sampler does at integer pixels;
* the objective is the logit of the network's probability (its gradient does not vanish near p = 1), summed
  over the K grasps (each term depends on its own offsets only, so Adam, elementwise, polishes each alone);
* every step is projected onto a trust region around its start (``max_shift`` px, ``max_rotation`` rad,
  ``max_depth_change`` m);
* each grasp keeps the iterate of highest smooth probability among those that decode to a valid grasp as the
  policy decodes its samples (`grasps_from_features`: suction centres on integer pixels, the parallel-jaw depth
  clipped to the sampler's range, the validity masks: border, segmentation mask, defined normals and approach
  cone); that decoded grasp is scored by the policy's own scorer and replaces the start only if it scores higher.
  Polishing never lowers a grasp's score, and costs ``steps + 1`` forward and backward passes of K grasps and one
  forward pass.

The ascent follows the scorer's ``smooth`` method (`GQCNNScorer.smooth`: the network through bilinear crops of
its window; the exact score for resampled windows, an interpolated one for gqcnn's nearest-pixel warp, which is
piecewise constant in the grasp); the scorer itself judges every iterate.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from dexjax.policy.candidates import ImageGrasp, Sampler, grasp_features, grasps_from_features
from dexjax.policy.observation import Observation
from dexjax.sampling.crops import sample_bilinear
from dexjax.sampling.image_grasps import ImageParallelJawGrasp, ImageSuctionGrasp, angles_from_approach
from dexjax.sampling.image_samplers import surface_normals

_LOGIT_EPS = 1e-6


@struct.dataclass
class PolishParams:
  """Settings of the gradient polish (the counts are static: they fix the shapes).

  Attributes:
    num_grasps: K, the policy's best grasps that are polished.
    steps: Adam steps per grasp.
    learning_rate: Adam's step size, in the units below (Adam's first steps move each variable by about this).
    pixel_unit: pixels per unit of a centre offset.
    angle_unit: radians per unit of the angle offset (parallel jaw).
    depth_unit: metres per unit of the depth offset (parallel jaw).
    max_shift: trust region of the centre, pixels from the start.
    max_rotation: trust region of the angle, radians (parallel jaw).
    max_depth_change: trust region of the depth, metres (parallel jaw; also clipped to the sampler's range).
  """

  num_grasps: int = struct.field(pytree_node=False, default=8)
  steps: int = struct.field(pytree_node=False, default=8)
  learning_rate: float = 0.5
  pixel_unit: float = 2.0
  angle_unit: float = 0.1
  depth_unit: float = 0.002
  max_shift: float = 8.0
  max_rotation: float = 0.35
  max_depth_change: float = 0.01

  def validate(self) -> PolishParams:
    """Checks the fields; raises ValueError naming the field and the expected value."""
    for name in ('num_grasps', 'steps'):
      value = getattr(self, name)
      if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f'PolishParams.{name}: expected an integer >= 1, got {value!r}')
    for name in ('learning_rate', 'pixel_unit', 'angle_unit', 'depth_unit', 'max_shift', 'max_rotation',
                 'max_depth_change'):
      value = getattr(self, name)
      if not (isinstance(value, (int, float)) and value > 0):
        raise ValueError(f'PolishParams.{name}: expected a positive number, got {value!r}')
    return self


def _num_variables(grasps: ImageGrasp) -> int:
  return 2 if isinstance(grasps, ImageSuctionGrasp) else 4


def _limits(grasps: ImageGrasp, params: PolishParams) -> jax.Array:
  """(V,) largest |offset| of each variable, in its units."""
  shift = params.max_shift / params.pixel_unit
  if isinstance(grasps, ImageSuctionGrasp):
    return jnp.array([shift, shift], jnp.float32)
  return jnp.array([shift, shift, params.max_rotation / params.angle_unit,
                    params.max_depth_change / params.depth_unit], jnp.float32)


def _project(x: jax.Array, grasps: ImageGrasp, params: PolishParams) -> jax.Array:
  """Offsets (K, V) moved into the trust region: the centre shift's norm and the other offsets clipped."""
  limits = _limits(grasps, params)
  shift = x[:, :2]
  norm = jnp.linalg.norm(shift, axis=-1, keepdims=True)
  shift = shift * jnp.minimum(1.0, limits[0] / jnp.maximum(norm, 1e-12))
  return jnp.concatenate([shift, jnp.clip(x[:, 2:], -limits[2:], limits[2:])], axis=-1)


def moved_grasps(observation: Observation, start: ImageGrasp, x: jax.Array, params: PolishParams,
                 normals: jax.Array | None = None) -> ImageGrasp:
  """The grasps (K,) at offsets ``x`` (K, V) from ``start``, continuous in ``x`` (see the module doc).

  Parallel jaw: centre + pixel_unit x[:2], angle + angle_unit x[2], depth + depth_unit x[3]. Suction: centre +
  pixel_unit x[:2], its depth and approach read bilinearly from the image and ``normals`` (H, W, 3) there.
  """
  center = start.center + params.pixel_unit * x[:, :2]
  if isinstance(start, ImageParallelJawGrasp):
    return start.replace(center=center, angle=start.angle + params.angle_unit * x[:, 2],
                         depth=start.depth + params.depth_unit * x[:, 3])
  normals = surface_normals(observation.camera, observation.depth) if normals is None else normals
  finite = jnp.nan_to_num(normals)
  read = jax.vmap(lambda c: jnp.stack([sample_bilinear(finite[..., i], c) for i in range(3)]))(center)
  approach = -read / jnp.maximum(jnp.linalg.norm(read, axis=-1, keepdims=True), 1e-9)
  angle, psi = jax.vmap(angles_from_approach)(approach)
  depth = jax.vmap(lambda c: sample_bilinear(observation.depth, c))(center)
  return ImageSuctionGrasp(center=center, angle=angle, depth=depth, approach_angle=psi)


def _logit(p: jax.Array) -> jax.Array:
  p = jnp.clip(p, _LOGIT_EPS, 1.0 - _LOGIT_EPS)
  return jnp.log(p) - jnp.log1p(-p)


def _decoded(observation: Observation, grasps: ImageGrasp, sampler: Sampler,
             normals: jax.Array | None) -> tuple[ImageGrasp, jax.Array]:
  """The policy's own decoding of continuous grasps: (grasps, valid) as its samples are made."""
  return grasps_from_features(observation, grasp_features(observation, grasps), sampler, normals)


def _choose(better: jax.Array, a, b):
  return jax.tree.map(lambda x, y: jnp.where(better.reshape(better.shape + (1,) * (x.ndim - 1)), x, y), a, b)


def polish_grasps(observation: Observation, grasps: ImageGrasp, quality: jax.Array, scorer: Any,
                  sampler: Sampler, params: PolishParams = PolishParams(),
                  normals: jax.Array | None = None) -> tuple[ImageGrasp, jax.Array]:
  """Polishes K image grasps of one gripper by projected gradient ascent on ``scorer``'s probability.

  Args:
    observation: the `Observation` the grasps were planned on.
    grasps: (K,) start grasps (`ImageParallelJawGrasp` or `ImageSuctionGrasp` with a leading axis K).
    quality: (K,) their scores by ``scorer`` (-inf where a start is invalid: it is left as is).
    scorer: the policy's scorer, with a differentiable ``smooth(observation, grasps) -> (K,)`` method of
      probabilities in [0, 1] (`GQCNNScorer.smooth`); the iterates are judged by calling it.
    sampler: the policy's sampler (its validity masks, depth range and jaw width decode the iterates).
    params: `PolishParams` (its ``num_grasps`` is the caller's K; here K is the leading axis of ``grasps``).
    normals: (H, W, 3) the observation's `surface_normals` (suction; computed here if not given).

  Returns:
    (grasps (K,), quality (K,)): each grasp's best valid iterate (decoded) and its score by ``scorer``, or the
    start and ``quality`` where it does not score higher; so the returned quality is >= ``quality`` elementwise.
  """
  if not callable(getattr(scorer, 'smooth', None)):
    raise TypeError(f'polish: the scorer needs a differentiable smooth(observation, grasps) method (as '
                    f'GQCNNScorer has); {type(scorer).__name__} has none')
  if isinstance(grasps, ImageSuctionGrasp) and normals is None:
    normals = surface_normals(observation.camera, observation.depth)
  start = jax.tree.map(jax.lax.stop_gradient, grasps)
  moved = lambda x: moved_grasps(observation, start, x, params, normals)

  def objective(x):
    grasps_x = moved(x)
    p = scorer.smooth(observation, grasps_x)
    return -jnp.sum(_logit(p)), (p, grasps_x)

  value_and_grad = jax.value_and_grad(objective, has_aux=True)
  optimizer = optax.adam(params.learning_rate)
  x0 = jnp.zeros((quality.shape[0], _num_variables(grasps)), jnp.float32)
  started = jnp.isfinite(quality)

  def step(carry, _):
    x, state, best_x, best_p = carry
    (_, (p, grasps_x)), g = value_and_grad(x)  # the iterate's grasps come back with its score: read once
    p = jnp.where(_decoded(observation, grasps_x, sampler, normals)[1] & started, p, -jnp.inf)
    better = p > best_p
    best_x, best_p = jnp.where(better[:, None], x, best_x), jnp.where(better, p, best_p)
    updates, state = optimizer.update(jnp.where(jnp.isfinite(g), g, 0.0), state, x)
    return (_project(optax.apply_updates(x, updates), grasps, params), state, best_x, best_p), None

  # steps + 1 evaluations: the start and every step's iterate (the last evaluation's update is not used).
  init = (x0, optimizer.init(x0), x0, jnp.full(quality.shape, -jnp.inf))
  (_, _, best_x, _), _ = jax.lax.scan(step, init, None, length=params.steps + 1, unroll=True)
  candidate, ok = _decoded(observation, moved(best_x), sampler, normals)
  q = jnp.where(ok & started, scorer(observation, candidate), -jnp.inf)
  better = q > quality
  return _choose(better, candidate, grasps), jnp.where(better, q, quality)


__all__ = ['PolishParams', 'moved_grasps', 'polish_grasps']
