"""Width-blocked convolutions (`dexjax.models.width_blocked`): the same cross-correlation as SciPy's and XLA's
plain convolution for any width, kernel and factor, the same gradients, and a GQ-CNN whose parameters and outputs
do not depend on how its convolutions are computed."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.signal import correlate

from dexjax.models import GQCNN, GQCNNConfig, ImageStream, SUCTION_POSE_DIM, init_gqcnn
from dexjax.models.plain import PlainGQCNN, PlainImageStream
from dexjax.models.width_blocked import FILTER_GRADIENT_CHUNK, blocked_kernel, conv_valid


def _scipy_conv(images: np.ndarray, kernel: np.ndarray) -> np.ndarray:
  """Reference: VALID cross-correlation, one (image, input channel, output channel) at a time, in float64."""
  batch, _, _, cin = images.shape
  out = [[sum(correlate(images[n, :, :, c].astype(np.float64), kernel[:, :, c, o].astype(np.float64), 'valid')
              for c in range(cin)) for o in range(kernel.shape[-1])] for n in range(batch)]
  return np.asarray(out).transpose(0, 2, 3, 1)


@pytest.mark.parametrize('height, width, kh, kw, cin, cout, factor', [
    (12, 12, 5, 5, 1, 3, 2),    # even width, odd kernel: no padding
    (11, 13, 3, 3, 2, 4, 2),    # odd width: padded on the right, extra columns dropped
    (10, 9, 4, 4, 3, 2, 2),     # even kernel
    (9, 17, 3, 5, 2, 2, 3),     # a factor that divides nothing here
    (8, 16, 9, 9, 1, 2, 4),     # kernel wider than a block several times over
    (7, 7, 3, 3, 2, 2, 1),      # factor 1: XLA's own convolution
])
def test_conv_valid_is_scipys_cross_correlation(height, width, kh, kw, cin, cout, factor):
  rng = np.random.default_rng(height * width + factor)
  kh = min(kh, height)
  images = rng.normal(size=(2, height, width, cin)).astype(np.float32)
  kernel = rng.normal(size=(kh, kw, cin, cout)).astype(np.float32)
  out = np.asarray(conv_valid(jnp.asarray(images), jnp.asarray(kernel), factor))
  assert out.shape == (2, height - kh + 1, width - kw + 1, cout)
  np.testing.assert_allclose(out, _scipy_conv(images, kernel), rtol=1e-5, atol=1e-4)


def test_a_bad_factor_names_the_field():
  with pytest.raises(ValueError, match='width_block: expected an integer >= 1, got 0'):
    conv_valid(jnp.zeros((1, 4, 4, 1)), jnp.zeros((3, 3, 1, 1)), 0)


def test_blocked_kernel_places_each_tap_once_per_output_phase():
  """Every (output phase b, input phase q, cell V) holds w[:, f V + q - b] where that column exists, else zeros."""
  kernel = jnp.arange(1, 1 + 2 * 5 * 1 * 1, dtype=jnp.float32).reshape(2, 5, 1, 1)
  blocked = np.asarray(blocked_kernel(kernel, 2))  # (2, 3, 2 (q), 2 (b))
  assert blocked.shape == (2, 3, 2, 2)
  for v in range(3):
    for q in range(2):
      for b in range(2):
        tap = 2 * v + q - b
        expected = kernel[:, tap, 0, 0] if 0 <= tap < 5 else np.zeros(2)
        np.testing.assert_array_equal(blocked[:, v, q, b], expected)
  # Each output phase sees every kernel column exactly once.
  assert np.count_nonzero(blocked[..., 0]) == np.count_nonzero(blocked[..., 1]) == 10


def _scipy_filter_gradient(images: np.ndarray, cotangent: np.ndarray) -> np.ndarray:
  """Reference: d/dkernel of sum(conv(images, kernel) * cotangent), one correlation per (n, c, o), float64."""
  batch, _, _, cin = images.shape
  grad = [[sum(correlate(images[n, :, :, c].astype(np.float64), cotangent[n, :, :, o].astype(np.float64), 'valid')
               for n in range(batch)) for o in range(cotangent.shape[-1])] for c in range(cin)]
  return np.asarray(grad).transpose(2, 3, 0, 1)  # (c, o, kh, kw) -> (kh, kw, c, o)


@pytest.mark.parametrize('batch', [2, FILTER_GRADIENT_CHUNK + 3], ids=['one-chunk', 'two-chunks'])
def test_gradients_match_the_plain_convolution_and_scipy(batch):
  """Both gradients of the blocked convolution equal the plain one's; the filter gradient (summed over chunks of
  `FILTER_GRADIENT_CHUNK` examples, the second a partial one) equals SciPy's correlation of images and cotangent."""
  rng = np.random.default_rng(batch)
  images = jnp.asarray(rng.normal(size=(batch, 10, 11, 3)), jnp.float32)
  kernel = jnp.asarray(rng.normal(size=(3, 3, 3, 4)), jnp.float32)
  cotangent = jnp.asarray(rng.normal(size=(batch, 8, 9, 4)), jnp.float32)
  loss = lambda x, w, f: jnp.sum(conv_valid(x, w, f) * cotangent)
  plain = jax.grad(loss, argnums=(0, 1))(images, kernel, 1)
  blocked = jax.grad(loss, argnums=(0, 1))(images, kernel, 2)
  for a, b in zip(plain, blocked):
    np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-5, atol=1e-4)
  np.testing.assert_allclose(np.asarray(blocked[1]), _scipy_filter_gradient(np.asarray(images), np.asarray(cotangent)),
                             rtol=1e-5, atol=1e-3)


def test_forward_mode_derivatives_match_the_plain_convolution():
  """The custom JVP is the convolution's own: tangents in the images, the kernel, or both."""
  rng = np.random.default_rng(3)
  images, d_images = (jnp.asarray(rng.normal(size=(FILTER_GRADIENT_CHUNK + 1, 9, 10, 2)), jnp.float32)
                      for _ in range(2))
  kernel, d_kernel = (jnp.asarray(rng.normal(size=(3, 5, 2, 3)), jnp.float32) for _ in range(2))
  zero_images, zero_kernel = jnp.zeros_like(images), jnp.zeros_like(kernel)
  for tangents in [(d_images, d_kernel), (d_images, zero_kernel), (zero_images, d_kernel)]:
    out, tangent = jax.jvp(lambda x, w: conv_valid(x, w, 2), (images, kernel), tangents)
    expected = conv_valid(tangents[0], kernel, 1) + conv_valid(images, tangents[1], 1)
    np.testing.assert_allclose(np.asarray(out), np.asarray(conv_valid(images, kernel, 1)), rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(np.asarray(tangent), np.asarray(expected), rtol=1e-5, atol=1e-4)
  # Differentiating only the kernel (as training does) computes no input gradient: one convolution per chunk of
  # the filter gradient and none for the images.
  hlo = jax.jit(jax.grad(lambda w: jnp.sum(conv_valid(images, w, 2)))).lower(kernel).as_text()
  assert hlo.count('stablehlo.convolution') == 2  # FILTER_GRADIENT_CHUNK + 1 examples: two chunks


@pytest.mark.parametrize('config', [GQCNNConfig.small(pose_dim=SUCTION_POSE_DIM),
                                    GQCNNConfig(crop_size=46, conv_kernels=(9, 5, 5, 5))],
                         ids=['small', 'dexnet4-layers'])
def test_gqcnn_is_independent_of_the_width_block(config):
  """Same parameters (tree and initial values) and features as the network in flax's plain layers
  (`dexjax.models.plain`: nn.Conv, nn.max_pool), and the same logits computed plainly (factor 1) and blocked (2)."""
  params = init_gqcnn(jax.random.key(4), config)
  crops = jax.random.normal(jax.random.key(5), (3, config.crop_size, config.crop_size, 1))
  poses = jnp.ones((3, config.pose_dim))
  # The plain layers' parameters under the same names and key: the same tree and the same initial values.
  jax.tree.map(np.testing.assert_array_equal, PlainGQCNN(config).init(jax.random.key(4), crops, poses)['params'],
               params)
  features = PlainImageStream(config).apply({'params': params['image_stream']}, crops)
  reference = PlainGQCNN(config).apply({'params': params}, crops, poses)
  for f in (1, 2):
    logits = GQCNN(config, width_block=f).apply({'params': params}, crops, poses)
    np.testing.assert_allclose(np.asarray(logits), np.asarray(reference), rtol=1e-5, atol=1e-5)
  blocked_features = ImageStream(config).apply({'params': params['image_stream']}, crops)
  np.testing.assert_allclose(np.asarray(blocked_features), np.asarray(features), rtol=1e-5, atol=1e-5)


def test_gqcnn_parameter_gradients_are_the_plain_networks_where_pools_tie():
  """The GQ-CNN pools before its bias and ReLU (`_Conv`), the plain network after them (nn.max_pool gives a tied
  window's gradient to one input, `max_pool_2x2` shares it): on crops with flat regions, where neighbouring
  convolution outputs are equal, every parameter's gradient is still the plain network's."""
  config = GQCNNConfig.small(pose_dim=SUCTION_POSE_DIM)
  params = init_gqcnn(jax.random.key(6), config)
  crops = jax.random.normal(jax.random.key(7), (4, config.crop_size, config.crop_size, 1))
  crops = crops.at[:, 4:20, 6:26].set(0.3).at[1:3, 12:, :].set(-0.2)  # flat regions: tied pool windows
  poses = jax.random.normal(jax.random.key(8), (4, config.pose_dim))
  features = ImageStream(config).apply({'params': params['image_stream']}, crops)
  first_conv = conv_valid(crops, params['image_stream']['conv0']['kernel'], 1)  # XLA's plain convolution
  windows = np.asarray(first_conv[:, :28, :28]).reshape(4, 14, 2, 14, 2, -1)
  assert np.any(windows[:, :, 0, :, 0] == windows[:, :, 1, :, 1])  # the crops do tie pool windows
  assert float(jnp.mean(features > 0)) > 0.2  # and the ReLUs pass gradients

  def loss(network):
    return lambda p: jnp.sum(jax.nn.log_softmax(network.apply({'params': p}, crops, poses))[:, 1])

  expected = jax.grad(loss(PlainGQCNN(config)))(params)
  for f in (1, 2):
    got = jax.grad(loss(GQCNN(config, width_block=f)))(params)
    jax.tree.map(lambda a, b: np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-6),
                 got, expected)
