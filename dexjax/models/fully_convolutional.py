"""A trained GQ-CNN slid over a whole image as a convolution, without retraining: a single-depth, axis-aligned
sliding window.

This is *not* the FC-GQ-CNN of spec section 2.3: that network is trained for dense use (unrotated crops, 16
angular output bins for the parallel jaw, the image taken relative to each candidate gripper depth and scored at
several depths); here one pose (gripper depth, approach angle) is applied to every cell and crops are not rotated,
so a cell scores only the grasp whose axis is the image's x axis at that pixel.

The dense fc3 layer becomes a VALID convolution whose F x F x C kernel is fc3's kernel reshaped (the flatten
order is NHWC, so no transpose), and the pose and merge layers are applied per output cell. Output cell (i, j)
is exactly the patch model's score of the S x S crop whose top-left pixel is (s i, s j), i.e. centred at
(s i + S / 2, s j + S / 2), where s = 2 ** (number of pools) is the network's stride (4 for Dex-Net 4.0). The
pose (gripper depth, and approach angle for suction) is one vector for every cell, or one per cell.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from dexjax.models.gqcnn import GQCNNConfig, ImageStream, success_probability


def output_stride(config: GQCNNConfig) -> int:
  """Pixels between neighbouring output cells: 2 ** (number of pools)."""
  return 2 ** len(config.pool_after)


def score_map_shape(config: GQCNNConfig, height: int, width: int) -> tuple[int, int]:
  """(H', W') cells of the score map of an H x W image: one per crop position on the stride grid."""
  s = output_stride(config)
  return (height - config.crop_size) // s + 1, (width - config.crop_size) // s + 1


def score_map(params, config: GQCNNConfig, image: jax.Array, pose: jax.Array) -> jax.Array:
  """p(success) of every stride-aligned crop of one normalised image.

  Args:
    params: `GQCNN` parameters (``init_gqcnn`` layout).
    config: their `GQCNNConfig`.
    image: (H, W, 1) normalised depth image, H, W >= crop size.
    pose: (pose_dim,) normalised pose for every cell, or (H', W', pose_dim) one per cell.

  Returns:
    (H', W') float32 success probabilities (`score_map_shape`).
  """
  features = ImageStream(config).apply({'params': params['image_stream']}, image[None])
  f, channels = config.feature_size(), features.shape[-1]
  kernel = params['fc3']['kernel'].reshape(f, f, channels, config.fc_size)
  h = jax.lax.conv_general_dilated(features, kernel, (1, 1), 'VALID',
                                   dimension_numbers=('NHWC', 'HWIO', 'NHWC'))[0]
  rows, cols = score_map_shape(config, image.shape[0], image.shape[1])
  h = jax.nn.relu(h[:rows, :cols] + params['fc3']['bias'])  # SAME pools may add cells past the image's edge
  pose = jnp.broadcast_to(pose, (rows, cols, config.pose_dim))
  q = jax.nn.relu(pose @ params['pc1']['kernel'] + params['pc1']['bias'])
  m = jax.nn.relu(h @ params['fc4_image']['kernel'] + q @ params['fc4_pose']['kernel'] + params['fc4_pose']['bias'])
  logits = m @ params['fc5']['kernel'] + params['fc5']['bias']
  return success_probability(logits)


__all__ = ['output_stride', 'score_map', 'score_map_shape']
