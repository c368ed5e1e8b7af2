"""The GQ-CNN written plainly with flax's standard layers, for `train_throughput.py`'s in-run baseline.

``nn.Conv`` (XLA's own convolution, VALID), ``nn.max_pool`` (2 x 2, stride 2, SAME), ``nn.Dense`` and the whole
batch in one pass: the network as a Flax user writes it from the spec (and as gqcnn does with ``tf.nn.conv2d`` and
``tf.nn.max_pool``), without dexjax's width-blocked convolutions, their chunked filter gradients, its reshape
max-pool or its chunked inference. Its parameter tree is `dexjax.models.GQCNN`'s, so the same parameters run in
both; the benchmark checks in the run that both give the same logits.
"""

from __future__ import annotations

from flax import linen as nn
import jax

from dexjax.models import GQCNNConfig


class _PlainImageStream(nn.Module):
  config: GQCNNConfig

  @nn.compact
  def __call__(self, x: jax.Array) -> jax.Array:
    for index, (filters, k) in enumerate(zip(self.config.conv_filters, self.config.conv_kernels)):
      x = nn.relu(nn.Conv(filters, (k, k), padding='VALID', name=f'conv{index}')(x))
      if index in self.config.pool_after:
        x = nn.max_pool(x, (2, 2), strides=(2, 2), padding='SAME')
    return x


class PlainGQCNN(nn.Module):
  """Logits (B, 2) of normalised crops (B, S, S, 1) and poses (B, pose_dim); `dexjax.models.GQCNN`'s parameters."""

  config: GQCNNConfig

  @nn.compact
  def __call__(self, image: jax.Array, pose: jax.Array, train: bool = False) -> jax.Array:
    c = self.config
    features = _PlainImageStream(c, name='image_stream')(image)
    h = nn.relu(nn.Dense(c.fc_size, name='fc3')(features.reshape(features.shape[0], -1)))
    h = nn.Dropout(c.dropout, deterministic=not train)(h)
    q = nn.relu(nn.Dense(c.pose_size, name='pc1')(pose))
    merged = nn.Dense(c.merge_size, use_bias=False, name='fc4_image')(h) + nn.Dense(c.merge_size, name='fc4_pose')(q)
    m = nn.Dropout(c.dropout, deterministic=not train)(nn.relu(merged))
    return nn.Dense(2, name='fc5')(m)
