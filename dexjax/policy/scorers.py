"""Grasp scorers: the quality function Q(y, u) a policy maximises, for a batch of image grasps of one gripper.

A scorer is a pytree (a frozen `flax.struct` dataclass) with a static ``gripper`` (``'parallel_jaw'`` or
``'suction'``) that is called as ``scorer(observation, grasps) -> (N,) float32`` on one `Observation` and N image
grasps (`dexjax.sampling.ImageParallelJawGrasp` / `ImageSuctionGrasp` with a leading axis N). Higher is better;
the learned scorers return p(success) in [0, 1], so the scores of two grippers' learned scorers are comparable
(both networks are trained on the same reward, the key idea of the ambidextrous policy). Being pytrees, scorers
pass through `jax.jit` as arguments: one compilation serves every set of weights of one architecture.

Two methods are optional parts of the protocol; policies look for them, so a plain function-like scorer needs
neither:

* ``refine(observation, grasps) -> grasps``: the N candidates as the policy executes them, applied by the ranking
  policy before scoring (`refined_candidates`; e.g. `SuctionPlanarityCentroid.refine` turns each suction approach
  to its disc's best-fit normal). Without it the candidates are scored as sampled.
* ``smooth(observation, grasps) -> (N,)``: the score, differentiable in the grasps (`dexjax.policy.polish`).

The scorers:

* `GQCNNScorer`: a trained GQ-CNN (`dexjax.models.GraspQualityModel`): each grasp's crop (`model_crop`, the crop
  rule of training) and pose vector ([depth] for the parallel jaw, [depth, approach angle] for suction).
  Its ``smooth`` method is the same score through bilinear crops, differentiable in the grasp, so it can be
  polished by gradient ascent (`dexjax.policy.polish`).
* The heuristic scorers of the baselines live in `dexjax.policy.heuristics`.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.models.saved import GraspQualityModel
from dexjax.policy.observation import Observation
from dexjax.sampling.crops import grasp_crop, model_crop
from dexjax.sampling.image_grasps import ImageParallelJawGrasp, ImageSuctionGrasp

PARALLEL_JAW, SUCTION = 'parallel_jaw', 'suction'
GRIPPERS = (PARALLEL_JAW, SUCTION)


def pose_inputs(grasps: ImageParallelJawGrasp | ImageSuctionGrasp) -> jax.Array:
  """(N, pose_dim) network pose inputs of N image grasps: [depth] (parallel jaw) or [depth, approach angle]
  (suction), metres and radians (as `dexjax.train.pose_vectors` of dataset rows)."""
  if isinstance(grasps, ImageSuctionGrasp):
    return jnp.stack([grasps.depth, grasps.approach_angle], axis=-1)
  return grasps.depth[:, None]


@struct.dataclass
class GQCNNScorer:
  """p(success) of image grasps from a trained GQ-CNN.

  Attributes:
    model: the `GraspQualityModel` (weights, normalisation, architecture, crop window, gripper).
  """

  model: GraspQualityModel

  @property
  def gripper(self) -> str:
    return self.model.gripper

  def crops(self, observation: Observation, grasps: ImageParallelJawGrasp | ImageSuctionGrasp) -> jax.Array:
    """(N, S, S, 1) raw crops (metres) of N grasps, S = the network's crop size."""
    window, size = self.model.crop_window, self.model.config.crop_size
    crop = jax.vmap(model_crop, in_axes=(None, 0, 0, None, None))
    return crop(observation.depth, grasps.center, grasps.angle, window, size)[..., None]

  def __call__(self, observation: Observation, grasps: ImageParallelJawGrasp | ImageSuctionGrasp) -> jax.Array:
    """(N,) p(success) of N grasps; NaN-free (invalid grasps are the caller's to mask)."""
    return self.model(self.crops(observation, grasps), pose_inputs(grasps))

  def smooth(self, observation: Observation, grasps: ImageParallelJawGrasp | ImageSuctionGrasp) -> jax.Array:
    """(N,) p(success) of N grasps read through bilinear crops of the model's window, differentiable in the
    grasps' centre, angle and depth (`dexjax.policy.polish`). The same as calling the scorer for a model whose
    window is resampled (``crop_window != crop_size``); for gqcnn's nearest-pixel warp, its interpolated version."""
    window, size = self.model.crop_window, self.model.config.crop_size
    depth = jnp.nan_to_num(observation.depth, nan=0.0)
    crop = jax.vmap(lambda c, a: grasp_crop(depth, c, a, window, size / window, 'bilinear'))
    return self.model(crop(grasps.center, grasps.angle)[..., None], pose_inputs(grasps))


def refined_candidates(scorer: Any, observation: Observation, grasps: ImageParallelJawGrasp | ImageSuctionGrasp
                       ) -> ImageParallelJawGrasp | ImageSuctionGrasp:
  """N candidates as ``scorer`` would have them executed: ``scorer.refine(observation, grasps)`` when the scorer
  has the optional ``refine`` method (module doc), else ``grasps`` unchanged. Traceable (the choice is static)."""
  refine = getattr(scorer, 'refine', None)
  return grasps if refine is None else refine(observation, grasps)


__all__ = ['GRIPPERS', 'PARALLEL_JAW', 'SUCTION', 'GQCNNScorer', 'pose_inputs', 'refined_candidates']
