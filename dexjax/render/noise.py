"""Optional depth-sensor noise (single image (H, W); `vmap` over images and keys). Off unless asked for.

Models (Dex-Net / gqcnn training-time augmentation, see docs/cameras.md):

* `gamma_depth_noise`: multiplicative Gamma noise, mean 1 and variance 1 / shape (gqcnn's ``gamma_shape``);
* `gaussian_process_noise`: spatially correlated additive noise, iid normal on a grid ``scale_factor`` times
  coarser than the image, linearly interpolated up (gqcnn's Gaussian-process approximation);
* `dropout`: a random fraction of pixels becomes invalid (NaN).

Invalid pixels (NaN, infinite or <= 0) are never changed, so NaN stays NaN. Every function is pure: the same
key gives the same result; image shapes and ``scale_factor`` are static.
"""

from __future__ import annotations

import math
import numbers

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct


@struct.dataclass
class SensorNoise:
  """Which noise models `apply_sensor_noise` applies, and their parameters; everything is off by default.

  Attributes:
    use_gamma: static; apply `gamma_depth_noise`.
    gamma_shape: Gamma shape k (> 0); the multiplier has mean 1 and variance 1 / k (gqcnn: 1000).
    use_gp: static; apply `gaussian_process_noise`.
    gp_sigma: per-pixel standard deviation of the correlated noise, metres (>= 0; gqcnn: 0.005).
    gp_scale_factor: static; pixels per noise-grid cell (integer >= 1; gqcnn: 4).
    use_dropout: static; apply `dropout`.
    dropout_rate: fraction of pixels made invalid, in [0, 1] (our default 0.01).
  """

  use_gamma: bool = struct.field(pytree_node=False, default=False)
  gamma_shape: float = 1000.0
  use_gp: bool = struct.field(pytree_node=False, default=False)
  gp_sigma: float = 0.005
  gp_scale_factor: int = struct.field(pytree_node=False, default=4)
  use_dropout: bool = struct.field(pytree_node=False, default=False)
  dropout_rate: float = 0.01

  def validate(self) -> SensorNoise:
    """Checks the parameters and returns ``self``; raises ValueError naming the field and the expected value.

    Traced parameters cannot be checked and are skipped, so call this eagerly, outside `jit`.
    """
    _check_number('SensorNoise: gamma_shape', self.gamma_shape, 'a finite number > 0', lambda x: x > 0)
    _check_number('SensorNoise: gp_sigma', self.gp_sigma, 'a finite number >= 0 (metres)', lambda x: x >= 0)
    _check_number('SensorNoise: dropout_rate', self.dropout_rate, 'a number in [0, 1]',
                  lambda x: 0 <= x <= 1)
    _check_scale_factor('SensorNoise: gp_scale_factor', self.gp_scale_factor)
    return self


def _check_number(where: str, value, expected: str, ok) -> None:
  """Raises ValueError unless the concrete scalar ``value`` is finite and ``ok(value)``; tracers pass."""
  if isinstance(value, jax.core.Tracer):
    return
  try:
    x = float(value)
  except (TypeError, ValueError):
    raise ValueError(f'{where}: expected {expected}, got {value!r}') from None
  if not (math.isfinite(x) and ok(x)):
    raise ValueError(f'{where}: expected {expected}, got {value!r}')


def _check_scale_factor(where: str, value) -> None:
  """Raises ValueError unless ``value`` is a Python integer >= 1 (not a bool)."""
  if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
    raise ValueError(f'{where}: expected an integer >= 1 (pixels per noise cell), got {value!r}')


def _check_image(where: str, depth: jax.Array) -> None:
  """Raises ValueError unless ``depth`` is a single (H, W) image."""
  if jnp.ndim(depth) != 2:
    raise ValueError(f'{where}: depth: expected one (H, W) image (batch with jax.vmap), '
                     f'got shape {jnp.shape(depth)}')


def _valid(depth: jax.Array) -> jax.Array:
  """(H, W) bool: finite, positive depth."""
  return jnp.isfinite(depth) & (depth > 0)


def gamma_depth_noise(key: jax.Array, depth: jax.Array, shape: jax.Array | float = 1000.0) -> jax.Array:
  """Multiplies every valid pixel of the image by one Gamma(shape, 1 / shape) draw (mean 1, variance 1 / shape),
  as gqcnn's multiplicative denoising (spec section 3.4: one multiplier per image, a global scale error).

  Args:
    key: a PRNG key.
    depth: (H, W) float depth image, metres; invalid pixels are returned unchanged.
    shape: Gamma shape k > 0 (gqcnn's ``gamma_shape``, 1000: ~3 % standard deviation).

  Returns:
    (H, W) noisy depth, metres, same dtype.
  """
  _check_image('gamma_depth_noise', depth)
  k = jnp.asarray(shape, jnp.float32)
  factor = jax.random.gamma(key, k, (), jnp.float32) / k
  return jnp.where(_valid(depth), depth * factor.astype(depth.dtype), depth)


def dropout(key: jax.Array, depth: jax.Array, rate: jax.Array | float) -> jax.Array:
  """Makes each valid pixel invalid (NaN) independently with probability ``rate`` in [0, 1].

  Args:
    key: a PRNG key.
    depth: (H, W) float depth image, metres.
    rate: probability that a pixel is dropped.

  Returns:
    (H, W) depth with dropped pixels set to NaN; other pixels unchanged.
  """
  _check_image('dropout', depth)
  drop = jax.random.bernoulli(key, jnp.asarray(rate, jnp.float32), depth.shape)
  return jnp.where(drop & _valid(depth), jnp.nan, depth)


def _interpolation_matrix(n_out: int, scale_factor: int) -> np.ndarray:
  """(n_out, n_grid) float32 linear-interpolation weights from a coarse grid to ``n_out`` pixels.

  Grid node j sits on pixel j * scale_factor (corners aligned), so n_grid = ceil((n_out - 1) / s) + 1.
  """
  n_grid = -(-(n_out - 1) // scale_factor) + 1
  t = np.arange(n_out, dtype=np.float64) / scale_factor
  j = np.minimum(np.floor(t).astype(np.int64), n_grid - 2) if n_grid > 1 else np.zeros(n_out, np.int64)
  w = t - j
  weights = np.zeros((n_out, n_grid), np.float64)
  weights[np.arange(n_out), j] = 1.0 - w
  if n_grid > 1:
    weights[np.arange(n_out), j + 1] += w
  return weights.astype(np.float32)


def _unit_variance_upsampler(n_out: int, scale_factor: int) -> np.ndarray:
  """`_interpolation_matrix` with each row scaled to unit norm, so iid N(0, 1) nodes give N(0, 1) pixels."""
  weights = _interpolation_matrix(n_out, scale_factor)
  return weights / np.linalg.norm(weights, axis=1, keepdims=True)


def gaussian_process_noise(key: jax.Array, depth: jax.Array, sigma: jax.Array | float = 0.005,
                           scale_factor: int = 4) -> jax.Array:
  """Adds spatially correlated normal noise to the valid pixels.

  Draws iid N(0, 1) values on a grid with one node every ``scale_factor`` pixels (corners aligned with the
  image corners), interpolates them bilinearly to every pixel and rescales each pixel by the norm of its
  interpolation weights, so every pixel's noise is N(0, sigma^2) exactly (plain interpolation would lower
  it to ~0.5-1 sigma depending on the position) and neighbours within a cell are strongly correlated.

  Args:
    key: a PRNG key.
    depth: (H, W) float depth image, metres; invalid pixels are returned unchanged.
    sigma: per-pixel standard deviation, metres (gqcnn: 0.005).
    scale_factor: static integer >= 1, pixels per grid cell (gqcnn: 4).

  Returns:
    (H, W) noisy depth, metres, same dtype.
  """
  _check_image('gaussian_process_noise', depth)
  _check_scale_factor('gaussian_process_noise: scale_factor', scale_factor)
  rows = jnp.asarray(_unit_variance_upsampler(depth.shape[0], scale_factor))
  cols = jnp.asarray(_unit_variance_upsampler(depth.shape[1], scale_factor))
  grid = jax.random.normal(key, (rows.shape[1], cols.shape[1]), jnp.float32)
  noise = jnp.asarray(sigma, jnp.float32) * (rows @ grid @ cols.T)
  return jnp.where(_valid(depth), depth + noise.astype(depth.dtype), depth)


def apply_sensor_noise(key: jax.Array, depth: jax.Array, noise: SensorNoise = SensorNoise()) -> jax.Array:
  """Applies the enabled models of ``noise`` in a fixed order: Gamma, then Gaussian process, then dropout.

  Each model uses its own sub-key of ``key`` whether or not the others are enabled, so turning one on or off
  does not change the others' draws. With the default ``SensorNoise()`` the image is returned unchanged.

  Args:
    key: a PRNG key.
    depth: (H, W) float depth image, metres.
    noise: the `SensorNoise` settings (validated when concrete).

  Returns:
    (H, W) noisy depth, metres; invalid pixels stay invalid.
  """
  noise.validate()
  _check_image('apply_sensor_noise', depth)
  gamma_key, gp_key, dropout_key = jax.random.split(key, 3)
  if noise.use_gamma:
    depth = gamma_depth_noise(gamma_key, depth, noise.gamma_shape)
  if noise.use_gp:
    depth = gaussian_process_noise(gp_key, depth, noise.gp_sigma, noise.gp_scale_factor)
  if noise.use_dropout:
    depth = dropout(dropout_key, depth, noise.dropout_rate)
  return depth


_jitted_noise = jax.jit(apply_sensor_noise)


def noisy_depth(key: jax.Array, depth, noise: SensorNoise):
  """Host helper: (H, W) float32 NumPy depth with ``noise`` applied (one jitted `apply_sensor_noise`, compiled once
  per image size), or ``depth`` itself when every noise model is off."""
  import numpy as np  # pylint: disable=g-import-not-at-top
  if not any((noise.use_gamma, noise.use_gp, noise.use_dropout)):
    return np.asarray(depth, np.float32)
  return np.asarray(_jitted_noise(key, jnp.asarray(depth), noise), np.float32)

