"""Stride-1 VALID convolutions computed on width-blocked images: the same result as XLA's plain convolution, with
twice the channels per product, which XLA's CPU convolution runs faster.

A GQ-CNN's convolutions have few channels (1 or 16 in, 16 out), and XLA's CPU convolution is slow at such narrow
matrix products: on this project's 2-core machine the Dex-Net 4.0 network's first layer (9 x 9, 1 -> 16) ran at
11 % of the float32 matmul rate and its 16 -> 16 layers at 38-41 %. Blocking the width by a factor f makes the
same convolution f times wider on both sides:

* the image (B, H, W, C) is read as (B, H, W / f, f C): pixel column f J + q, channel c becomes cell column J,
  channel (q, c). In row-major NHWC this is a free reshape, not a copy;
* the kernel (k, k, C, O) becomes (k, K', f C, f O) with K' = ceil((k + f - 1) / f) cells:
  ``W'[u, V, (q, c), (b, o)] = w[u, f V + q - b, c, o]`` where 0 <= f V + q - b < k, else 0;
* the output cell (i, J), channel (b, o) is the output pixel (i, f J + b), channel o; reshaping back is free too.

Each output block reads K' f >= k input columns, so the product does (K' f / k) times the multiply-adds (1.2 for
k = 5, f = 2; 1.33 for k = 3), but at twice the channels XLA runs every layer faster, and the whole network's
inference 1.6 times faster (``benchmarks/train_throughput.py``, README "GQ-CNN training"). The reason, found later:
XLA (jaxlib 0.10) gives a convolution to YNNPACK only when it has more than 16 input or output channels; a GQ-CNN's
plain 1 -> 16 and 16 -> 16 layers fall back to XLA's generic convolution, their blocked forms (2 -> 32, 32 -> 32)
run in YNNPACK's kernels. Widths that f does not divide are padded on the right with zeros and the extra output
columns dropped, so any image size and kernel work. The parameters are the plain kernel's.

Gradients: the input gradient is the width-blocked convolution's own (faster than XLA's plain one here), but the
filter gradient is not: XLA's filter gradient of the blocked kernel took twice as long as that of the plain kernel
(e.g. 323 vs 159 ms for the 88 x 88, 16 -> 16 layer at batch 64), and the plain one is itself fastest computed over
chunks of `FILTER_GRADIENT_CHUNK` examples and summed (that layer 154 -> 62-85 ms: XLA ran the whole batch's on one
core, the chunks on both and in cache). A custom JVP gives the convolution this derivative; training the Dex-Net 4.0
network ran 1.5-1.9x faster than with flax's plain layers (README "GQ-CNN training").
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

WIDTH_BLOCK = 2
"""Default blocking factor f: measured best for every GQ-CNN layer on this CPU (f = 4 and 8 were no faster)."""

FILTER_GRADIENT_CHUNK = 8
"""Examples per filter-gradient convolution: the kernel's gradient is a sum of one convolution per chunk."""


def _cells(kernel_size: int, factor: int) -> int:
  """K': input cells one output cell reads."""
  return math.ceil((kernel_size + factor - 1) / factor)


def blocked_kernel(kernel: jax.Array, factor: int = WIDTH_BLOCK) -> jax.Array:
  """The kernel of the width-blocked convolution.

  Args:
    kernel: (kh, kw, C, O) HWIO convolution kernel.
    factor: width blocking factor f >= 1.

  Returns:
    (kh, K', f C, f O) kernel, K' = ceil((kw + f - 1) / f); input channels ordered (q, c), output (b, o).
  """
  kh, kw, cin, cout = kernel.shape
  cells = _cells(kw, factor)
  v, q, b = np.meshgrid(np.arange(cells), np.arange(factor), np.arange(factor), indexing='ij')
  tap = factor * v + q - b                                              # (K', f, f): kernel column read
  valid = (tap >= 0) & (tap < kw)
  gathered = jnp.take(kernel, np.clip(tap, 0, kw - 1).ravel(), axis=1)  # (kh, K' f f, C, O)
  gathered = gathered.reshape(kh, cells, factor, factor, cin, cout) * valid[None, ..., None, None]
  # (kh, V, q, b, c, o) -> (kh, V, q, c, b, o)
  return gathered.transpose(0, 1, 2, 4, 3, 5).reshape(kh, cells, factor * cin, factor * cout)


def conv_valid(images: jax.Array, kernel: jax.Array, factor: int = WIDTH_BLOCK) -> jax.Array:
  """Stride-1 VALID cross-correlation of a batch, computed width-blocked by ``factor`` (1: XLA's plain convolution).

  Args:
    images: (B, H, W, C) float images, NHWC.
    kernel: (kh, kw, C, O) HWIO kernel, kh <= H, kw <= W.
    factor: width blocking factor f >= 1.

  Returns:
    (B, H - kh + 1, W - kw + 1, O): ``out[n, i, j, o] = sum_{u, v, c} images[n, i + u, j + v, c] kernel[u, v, c, o]``,
    as ``jax.lax.conv_general_dilated`` with VALID padding, up to floating-point summation order.

  Raises:
    ValueError: ``factor`` is not an integer >= 1.
  """
  if not isinstance(factor, int) or factor < 1:
    raise ValueError(f'width_block: expected an integer >= 1, got {factor!r}')
  if factor == 1:
    return _conv(images, kernel)
  return _blocked_conv(images, kernel, factor)


@functools.partial(jax.custom_jvp, nondiff_argnums=(2,))
def _blocked_conv(images: jax.Array, kernel: jax.Array, factor: int) -> jax.Array:
  """`conv_valid` for ``factor`` > 1; its derivative in the kernel is XLA's plain convolution (`_blocked_conv_jvp`)."""
  return _blocked_forward(images, kernel, factor)


def _blocked_forward(images: jax.Array, kernel: jax.Array, factor: int) -> jax.Array:
  """The width-blocked convolution itself (module docstring)."""
  batch, height, width, cin = images.shape
  kh, kw, _, cout = kernel.shape
  out_width = width - kw + 1
  out_cells = math.ceil(out_width / factor)
  padded = factor * (out_cells + _cells(kw, factor) - 1)  # >= width: the columns the last cell reads
  images = jnp.pad(images, ((0, 0), (0, 0), (0, padded - width), (0, 0)))
  blocked = images.reshape(batch, height, padded // factor, factor * cin)
  out = _conv(blocked, blocked_kernel(kernel, factor))               # (B, H', out_cells, f O)
  return out.reshape(batch, height - kh + 1, out_cells * factor, cout)[:, :, :out_width]


def _blocked_conv_jvp(factor, primals, tangents):
  """Tangent of the convolution, bilinear in (images, kernel): blocked in the images, plain in the kernel.

  Reverse mode transposes each term: the images' term into the width-blocked input gradient (faster than XLA's
  plain one on this CPU) and the kernel's term, written as one plain convolution per `FILTER_GRADIENT_CHUNK`
  examples, into the sum of XLA's plain filter gradients of the chunks (module docstring). Zero tangents (e.g. the
  input crops when only the parameters are differentiated) are skipped, so no work is done for them.
  """
  images, kernel = primals
  d_images, d_kernel = tangents
  out = _blocked_forward(images, kernel, factor)
  terms = []
  if not isinstance(d_images, SymbolicZero):
    terms.append(_blocked_forward(d_images, kernel, factor))
  if not isinstance(d_kernel, SymbolicZero):
    chunks = range(0, images.shape[0], FILTER_GRADIENT_CHUNK)
    terms.append(jnp.concatenate([_conv(images[i:i + FILTER_GRADIENT_CHUNK], d_kernel) for i in chunks]))
  return out, functools.reduce(jnp.add, terms) if terms else jnp.zeros_like(out)


_blocked_conv.defjvp(_blocked_conv_jvp, symbolic_zeros=True)


def _conv(images: jax.Array, kernel: jax.Array) -> jax.Array:
  return jax.lax.conv_general_dilated(images, kernel, (1, 1), 'VALID', dimension_numbers=('NHWC', 'HWIO', 'NHWC'))


__all__ = ['WIDTH_BLOCK', 'blocked_kernel', 'conv_valid']
