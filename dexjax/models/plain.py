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

from dexjax.models.gqcnn import GQCNNConfig, _dense, _he_truncated


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
    c = self.config
    features = PlainImageStream(c, name='image_stream')(image)
    flat = features.reshape(features.shape[0], -1)
    h = nn.Dropout(c.dropout, deterministic=not train)(nn.relu(_dense(c.fc_size, flat.shape[-1], 'fc3')(flat)))
    q = nn.relu(_dense(c.pose_size, pose.shape[-1], 'pc1')(pose))
    fan_in = c.fc_size + c.pose_size
    merged = (_dense(c.merge_size, fan_in, 'fc4_image', use_bias=False)(h)
              + _dense(c.merge_size, fan_in, 'fc4_pose')(q))
    m = nn.Dropout(c.dropout, deterministic=not train)(nn.relu(merged))
    return _dense(2, c.merge_size, 'fc5', zero_bias=True)(m)


__all__ = ['PlainGQCNN', 'PlainImageStream']
