"""Input normalisation of a GQ-CNN (spec section 1.3, ``pose_stream`` mode), fitted on the training split.

crop <- (crop - image_mean) / image_std with one scalar mean and std over every pixel of the training crops;
pose <- (pose - pose_mean) / pose_std per pose dimension. With ``subtract_depth`` (a network of
``input_depth_mode = 'im_depth_sub'``) the crop is first taken relative to the grasp: crop - pose[0], as gqcnn's
mode of that name, and the image statistics are those of that difference. `fit_normalization` accumulates the statistics over a
stream of batches (never the whole dataset in memory) in float64; they are stored with a checkpoint.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

_MIN_STD = 1e-6


@struct.dataclass
class Normalization:
  """Statistics of the training inputs.

  Attributes:
    image_mean, image_std: () float32 mean and standard deviation of every crop pixel, metres.
    pose_mean, pose_std: (pose_dim,) float32 per pose dimension (metres, radians).
  """

  image_mean: jax.Array
  image_std: jax.Array
  pose_mean: jax.Array
  pose_std: jax.Array

  def apply(self, crops: jax.Array, poses: jax.Array, subtract_depth: bool = False) -> tuple[jax.Array, jax.Array]:
    """Normalised (crops (..., S, S, 1), poses (..., pose_dim)) of raw crops and poses (metres, radians), the
    crops first relative to each pose's grasp depth ``pose[0]`` with ``subtract_depth``."""
    if subtract_depth:
      crops = relative_crops(crops, poses)
    return (crops - self.image_mean) / self.image_std, (poses - self.pose_mean) / self.pose_std

  @classmethod
  def identity(cls, pose_dim: int) -> Normalization:
    return cls(image_mean=jnp.float32(0.0), image_std=jnp.float32(1.0), pose_mean=jnp.zeros(pose_dim, jnp.float32),
               pose_std=jnp.ones(pose_dim, jnp.float32))


def relative_crops(crops: Any, poses: Any) -> Any:
  """Crops (..., S, S, 1) minus their grasp depth ``poses[..., 0]`` (..., pose_dim): depth behind the grasp
  point, metres (NumPy or JAX arrays)."""
  return crops - poses[..., None, None, :1]


def fit_normalization(batches: Iterable[tuple[np.ndarray, np.ndarray]], subtract_depth: bool = False
                      ) -> Normalization:
  """Fits `Normalization` on a stream of (crops (B, S, S[, 1]) metres, poses (B, pose_dim)) batches; with
  ``subtract_depth``, of the crops relative to their grasp depth (`relative_crops`).

  NaN pixels (invalid depth) are left out of the image statistics. Standard deviations below 1e-6 become 1 (a
  constant input is centred, not blown up). For suction, pass poses whose approach angle has been negated for
  a random half of the rows, as the original does (the network then sees a signed angle, spec section 1.3).

  Raises:
    ValueError: no batch, no valid pixel, or pose batches of different widths.
  """
  n_pix = s_pix = ss_pix = 0.0
  n_pose, s_pose, ss_pose = 0, None, None
  for crops, poses in batches:
    crops = np.asarray(crops, np.float64)
    poses = np.asarray(poses, np.float64).reshape(len(poses), -1)
    if subtract_depth:
      crops = relative_crops(crops.reshape(*crops.shape[:3], 1), poses)
    valid = crops[np.isfinite(crops)]
    n_pix, s_pix, ss_pix = n_pix + valid.size, s_pix + valid.sum(), ss_pix + np.square(valid).sum()
    if s_pose is None:
      s_pose, ss_pose = np.zeros(poses.shape[1]), np.zeros(poses.shape[1])
    if poses.shape[1] != s_pose.shape[0]:
      raise ValueError(f'fit_normalization: poses: expected {s_pose.shape[0]} columns in every batch, got '
                       f'{poses.shape[1]}')
    n_pose, s_pose, ss_pose = n_pose + len(poses), s_pose + poses.sum(0), ss_pose + np.square(poses).sum(0)
  if n_pix == 0 or n_pose == 0:
    raise ValueError('fit_normalization: batches: expected at least one batch with valid pixels, got none')
  image_mean, pose_mean = s_pix / n_pix, s_pose / n_pose
  image_std = np.sqrt(max(ss_pix / n_pix - image_mean**2, 0.0))
  pose_std = np.sqrt(np.maximum(ss_pose / n_pose - pose_mean**2, 0.0))
  return Normalization(image_mean=jnp.float32(image_mean),
                       image_std=jnp.float32(image_std if image_std > _MIN_STD else 1.0),
                       pose_mean=jnp.asarray(pose_mean, jnp.float32),
                       pose_std=jnp.asarray(np.where(pose_std > _MIN_STD, pose_std, 1.0), jnp.float32))


__all__ = ['Normalization', 'fit_normalization', 'relative_crops']
