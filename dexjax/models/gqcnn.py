"""The Dex-Net 4.0 GQ-CNN (spec section 2.2) in Flax, configurable down to a small variant for CPU runs.

Image stream: convolutions (VALID padding, ReLU), 2 x 2 max-pools after the configured layers, a dense layer
(fc3). Pose stream: one dense layer (pc1). Merge: ReLU(fc3 W1 + pc1 W2 + b) (fc4), then two logits [fail,
success] (fc5). `GQCNNConfig()` is the released GQCNN-4.0-PJ / -SUCTION architecture (631,410 / 631,426
parameters for pose dimensions 1 / 2); `GQCNNConfig.small()` a 32 x 32 variant for quick CPU training.

Initialisation (spec section 2.5): every kernel and bias is drawn from a normal truncated at 2 sigma with
sigma = sqrt(2 / fan_in) (the merge layer's two kernels and bias share fan_in = image + pose features), except
the final bias, which is zero.

Inputs are normalised crops (B, S, S, 1) and normalised poses (B, pose_dim); see `dexjax.models.Normalization`.

The convolutions are computed width-blocked (`dexjax.models.width_blocked`): the parameters and, up to float
rounding, the outputs are those of ``flax.linen.Conv``; inference runs 1.6x faster on a 2-core CPU.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
from flax import linen as nn

from dexjax.models.width_blocked import WIDTH_BLOCK, conv_valid

PARALLEL_JAW_POSE_DIM = 1  # gripper depth
SUCTION_POSE_DIM = 2       # gripper depth, approach angle
INPUT_DEPTH_MODES = ('pose_stream', 'im_depth_sub')


@dataclasses.dataclass(frozen=True)
class GQCNNConfig:
  """Architecture of a GQ-CNN (defaults: Dex-Net 4.0, spec section 2.2).

  Attributes:
    crop_size: input crop side S, pixels.
    conv_filters: filters per convolution.
    conv_kernels: kernel side per convolution (VALID padding, stride 1).
    pool_after: indices of the convolutions followed by a 2 x 2, stride 2 max-pool.
    fc_size: image-stream dense layer (fc3) width.
    pose_size: pose-stream dense layer (pc1) width.
    merge_size: merge layer (fc4) width.
    pose_dim: pose input size: 1 (parallel jaw: depth) or 2 (suction: depth, approach angle).
    dropout: dropout rate after fc3 and fc4 in training (Dex-Net 4.0: 0).
    input_depth_mode: ``'pose_stream'`` (Dex-Net 4.0: the crop in metres from the camera) or ``'im_depth_sub'``
      (the grasp depth is subtracted from every crop pixel before normalisation, as gqcnn's mode of that name;
      the pose stream is kept). See `dexjax.models.Normalization.apply`.
  """

  crop_size: int = 96
  conv_filters: tuple[int, ...] = (16, 16, 16, 16)
  conv_kernels: tuple[int, ...] = (9, 5, 5, 5)
  pool_after: tuple[int, ...] = (1, 3)
  fc_size: int = 128
  pose_size: int = 16
  merge_size: int = 128
  pose_dim: int = PARALLEL_JAW_POSE_DIM
  dropout: float = 0.0
  input_depth_mode: str = 'pose_stream'

  @property
  def subtracts_grasp_depth(self) -> bool:
    """True when crops are taken relative to the grasp depth (``input_depth_mode == 'im_depth_sub'``)."""
    return self.input_depth_mode == 'im_depth_sub'

  @classmethod
  def small(cls, pose_dim: int = PARALLEL_JAW_POSE_DIM) -> GQCNNConfig:
    """A ~36k-parameter variant on 32 x 32 crops (Dex-Net 2.0's crop size) for quick CPU training."""
    return cls(crop_size=32, conv_filters=(16, 16, 16), conv_kernels=(5, 3, 3), pool_after=(0, 2), fc_size=64,
               pose_size=16, merge_size=64, pose_dim=pose_dim)

  def feature_size(self) -> int:
    """Side of the image stream's last feature map (17 for Dex-Net 4.0); raises ValueError if it vanishes."""
    size = self.crop_size
    for index, kernel in enumerate(self.conv_kernels):
      size = size - kernel + 1
      if index in self.pool_after:
        size = math.ceil(size / 2)
      if size < 1:
        raise ValueError(f'GQCNNConfig: crop_size {self.crop_size} is too small for conv_kernels '
                         f'{self.conv_kernels} (feature map vanishes after convolution {index})')
    return size

  def validate(self) -> GQCNNConfig:
    """Checks the fields; raises ValueError naming the field and the expected value."""
    if len(self.conv_filters) != len(self.conv_kernels) or not self.conv_kernels:
      raise ValueError(f'GQCNNConfig.conv_filters / conv_kernels: expected equal, non-zero lengths, got '
                       f'{self.conv_filters} and {self.conv_kernels}')
    if any(i < 0 or i >= len(self.conv_kernels) for i in self.pool_after):
      raise ValueError(f'GQCNNConfig.pool_after: expected indices of convolutions in [0, {len(self.conv_kernels)}), '
                       f'got {self.pool_after}')
    if self.pose_dim < 1:
      raise ValueError(f'GQCNNConfig.pose_dim: expected 1 (parallel jaw) or 2 (suction), got {self.pose_dim}')
    if self.input_depth_mode not in INPUT_DEPTH_MODES:
      raise ValueError(f'GQCNNConfig.input_depth_mode: expected one of {INPUT_DEPTH_MODES}, got '
                       f'{self.input_depth_mode!r}')
    if not 0.0 <= self.dropout < 1.0:
      raise ValueError(f'GQCNNConfig.dropout: expected a rate in [0, 1), got {self.dropout}')
    self.feature_size()
    return self


def _he_truncated(fan_in: int):
  """Initializer: normal truncated at +-2 sigma, sigma = sqrt(2 / fan_in) (spec section 2.5)."""
  sigma = math.sqrt(2.0 / fan_in)
  return lambda key, shape, dtype=jnp.float32: sigma * jax.random.truncated_normal(key, -2.0, 2.0, shape, dtype)


class _Conv(nn.Module):
  """A VALID, stride-1 convolution with bias and ReLU, optionally followed by a 2 x 2 max-pool:
  (B, H, W, C) -> (B, H', W', features), H' = H - k + 1 (ceil(H' / 2) when ``pool``), likewise W'.

  Its parameters (``kernel`` (k, k, C, features), ``bias``) and their initial values are those of
  ``nn.Conv(features, (k, k), padding='VALID')`` with the spec's initializer; it is computed width-blocked
  (`dexjax.models.width_blocked.conv_valid`), which gives the same result faster on a CPU.

  With ``pool`` the bias and ReLU come after the pool, on a quarter of the values: a max commutes with adding a
  per-channel constant and with the ReLU (both monotone, also in floating point), so the values are exactly those
  of pool(ReLU(conv + bias)). On this project's 2-core CPU the Dex-Net 4.0 network inferred 5-6 % more crops per
  second (the bias and ReLU after its 88 x 88 layer had been 4 % of the forward pass; 2026-12-05). When the
  ``intermediates`` collection is mutable (``apply(..., capture_intermediates=True)``), ReLU(conv + bias) before
  the pool is also sown there as ``activation`` (`dexjax.models.feature_analysis`); otherwise it is not computed.
  """

  features: int
  kernel_size: int
  width_block: int = WIDTH_BLOCK
  pool: bool = False

  @nn.compact
  def __call__(self, x: jax.Array) -> jax.Array:
    k = self.kernel_size
    init = _he_truncated(k * k * x.shape[-1])
    kernel = self.param('kernel', init, (k, k, x.shape[-1], self.features), jnp.float32)
    bias = self.param('bias', init, (self.features,), jnp.float32)
    y = conv_valid(x, kernel, self.width_block)
    if self.is_mutable_collection('intermediates'):  # layer analysis (`capture_intermediates`): the map before its pool
      self.sow('intermediates', 'activation', nn.relu(y + bias))
    return nn.relu((max_pool_2x2(y) if self.pool else y) + bias)


def _dense(features: int, fan_in: int, name: str, use_bias: bool = True, zero_bias: bool = False) -> nn.Dense:
  init = _he_truncated(fan_in)
  return nn.Dense(features, use_bias=use_bias, kernel_init=init,
                  bias_init=nn.initializers.zeros if zero_bias else init, name=name)


def max_pool_2x2(x: jax.Array) -> jax.Array:
  """2 x 2, stride-2 max-pool with SAME padding: (B, H, W, C) -> (B, ceil(H / 2), ceil(W / 2), C).

  The same values as ``flax.linen.max_pool(x, (2, 2), strides=(2, 2), padding='SAME')`` (odd sides are padded with
  -inf at the end), computed as a reshape and a max so that its gradient is a broadcast rather than XLA's
  select-and-scatter, which took 107 of a training step's ~650 ms at 84 x 84 on this CPU. Where a window has tied
  maxima its gradient is shared between them (flax gives it to one). In a GQ-CNN (`_Conv`) ties come from equal
  input patches (flat regions of a depth crop), where sharing gives the kernel the same gradient, and windows whose
  maximum the ReLU then zeroes pass no gradient either way.
  """
  batch, height, width, channels = x.shape
  x = jnp.pad(x, ((0, 0), (0, height % 2), (0, width % 2), (0, 0)), constant_values=-jnp.inf)
  return x.reshape(batch, (height + 1) // 2, 2, (width + 1) // 2, 2, channels).max(axis=(2, 4))


class ImageStream(nn.Module):
  """Convolutions and pools of a GQ-CNN: (B, S, S, 1) -> (B, F, F, C) features.

  ``width_block``: how the convolutions are computed (`dexjax.models.width_blocked.conv_valid`'s factor; 1 is
  XLA's plain convolution). It changes neither the parameters nor, beyond float rounding, the result.
  """

  config: GQCNNConfig
  width_block: int = WIDTH_BLOCK

  @nn.compact
  def __call__(self, image: jax.Array) -> jax.Array:
    x = image
    for index, (filters, kernel) in enumerate(zip(self.config.conv_filters, self.config.conv_kernels)):
      x = _Conv(filters, kernel, self.width_block, pool=index in self.config.pool_after, name=f'conv{index}')(x)
    return x


class GQCNN(nn.Module):
  """The GQ-CNN: logits (B, 2) [fail, success] of normalised crops (B, S, S, 1) and poses (B, pose_dim).

  ``width_block``: as `ImageStream`'s (computation only; the parameters are the same for every value).
  """

  config: GQCNNConfig = GQCNNConfig()
  width_block: int = WIDTH_BLOCK

  @nn.compact
  def __call__(self, image: jax.Array, pose: jax.Array, train: bool = False) -> jax.Array:
    c = self.config
    features = ImageStream(c, self.width_block, name='image_stream')(image)
    return dense_head(c, features, pose, train)


def dense_head(config: GQCNNConfig, features: jax.Array, pose: jax.Array, train: bool) -> jax.Array:
  """The layers after the image stream: fc3 on the flattened features (B, F, F, C), pc1 on the poses (B, pose_dim),
  the merge fc4 and the logits fc5 (B, 2), each with dropout after fc3 and fc4 in training.

  Call it inside a module's ``nn.compact`` method: the layers become that module's children (``fc3``, ``pc1``,
  ``fc4_image``, ``fc4_pose``, ``fc5``), as in `GQCNN` and `dexjax.models.plain.PlainGQCNN`.
  """
  c = config
  flat = features.reshape(features.shape[0], -1)
  h = nn.relu(_dense(c.fc_size, flat.shape[-1], 'fc3')(flat))
  h = nn.Dropout(c.dropout, deterministic=not train)(h)
  q = nn.relu(_dense(c.pose_size, pose.shape[-1], 'pc1')(pose))
  fan_in = c.fc_size + c.pose_size
  merged = (_dense(c.merge_size, fan_in, 'fc4_image', use_bias=False)(h)
            + _dense(c.merge_size, fan_in, 'fc4_pose')(q))
  m = nn.Dropout(c.dropout, deterministic=not train)(nn.relu(merged))
  return _dense(2, c.merge_size, 'fc5', zero_bias=True)(m)


def init_gqcnn(key: jax.Array, config: GQCNNConfig = GQCNNConfig()):
  """Parameters of a freshly initialised `GQCNN` for ``config`` (a pytree of float32 arrays)."""
  config.validate()
  image = jnp.zeros((1, config.crop_size, config.crop_size, 1), jnp.float32)
  return GQCNN(config).init(key, image, jnp.zeros((1, config.pose_dim), jnp.float32))['params']


def success_probability(logits: jax.Array) -> jax.Array:
  """p(success) (...,) = softmax(logits)[..., 1] of logits (..., 2)."""
  return jax.nn.softmax(logits, axis=-1)[..., 1]


def num_parameters(params) -> int:
  """Total number of scalars in a parameter pytree."""
  return sum(int(x.size) for x in jax.tree.leaves(params))


__all__ = ['GQCNN', 'GQCNNConfig', 'ImageStream', 'PARALLEL_JAW_POSE_DIM', 'SUCTION_POSE_DIM', 'init_gqcnn',
           'dense_head', 'max_pool_2x2', 'num_parameters', 'success_probability']
