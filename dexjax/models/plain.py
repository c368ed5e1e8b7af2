"""The GQ-CNN written plainly in flax's standard layers: the reference dexjax's network is checked against (tests)
and the baseline it is timed against (`benchmarks/train_throughput.py`).

``nn.Conv`` (XLA's own convolution, VALID), ``nn.max_pool`` (2 x 2, stride 2, SAME), ``nn.Dense``, the whole batch
in one pass: the network as a Flax user writes it from the spec (and as gqcnn does with ``tf.nn.conv2d`` and
``tf.nn.max_pool``), without `dexjax.models.GQCNN`'s width-blocked convolutions and their chunked filter gradients,
its reshape max-pool, or `dexjax.models.chunked`'s inference in chunks. Its parameter tree and initial values are
``GQCNN``'s (same names, same initializers), so one set of parameters runs in both.
"""

from __future__ import annotations

import jax
from flax import linen as nn

from dexjax.models.gqcnn import GQCNNConfig, _he_truncated, dense_head


class PlainImageStream(nn.Module):
  """Convolutions and pools, (B, S, S, 1) -> (B, F, F, C), in ``nn.Conv`` and ``nn.max_pool``."""

  config: GQCNNConfig

  @nn.compact
  def __call__(self, x: jax.Array) -> jax.Array:
    for index, (filters, k) in enumerate(zip(self.config.conv_filters, self.config.conv_kernels)):
      init = _he_truncated(k * k * x.shape[-1])
      x = nn.relu(nn.Conv(filters, (k, k), padding='VALID', kernel_init=init, bias_init=init, name=f'conv{index}')(x))
      if index in self.config.pool_after:
        x = nn.max_pool(x, (2, 2), strides=(2, 2), padding='SAME')
    return x


class PlainGQCNN(nn.Module):
  """Logits (B, 2) [fail, success] of normalised crops (B, S, S, 1) and poses (B, pose_dim), as `GQCNN`."""

  config: GQCNNConfig = GQCNNConfig()

  @nn.compact
  def __call__(self, image: jax.Array, pose: jax.Array, train: bool = False) -> jax.Array:
    features = PlainImageStream(self.config, name='image_stream')(image)
    return dense_head(self.config, features, pose, train)  # nn.Dense layers, GQCNN's names and initializers


__all__ = ['PlainGQCNN', 'PlainImageStream']
