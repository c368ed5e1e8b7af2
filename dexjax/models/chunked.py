"""A GQ-CNN's inference over consecutive chunks of a batch, so that each chunk's feature maps stay in the CPU's caches.

At batch 256 the Dex-Net 4.0 network's first feature map alone is 127 MB (256 x 88 x 88 x 16 float32), and on this
project's 2-core machine moving it to and from memory cost as much as a convolution (the bias and ReLU after the
first layer: 51 of ~290 ms). Run over 16 crops at a time (one after another: ``jax.lax.map``), the same network
evaluated 1.25-1.5x more crops per second (`benchmarks/train_throughput.py`). Running the chunks as independent
parts of one program does not help: XLA then schedules them side by side.

Gradients are those of the whole batch at once (a custom VJP that recomputes the forward pass without chunks): the
backward pass of a loop over chunks ran 30x slower here, XLA's CPU convolutions inside loops being the slow ones.
Only reverse mode is defined (``jax.grad``, ``jax.vjp``); forward mode (``jax.jvp``, ``jax.jacfwd``) is not.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from dexjax.models.gqcnn import GQCNN, GQCNNConfig

INFERENCE_CHUNK = 16
"""Crops per pass of the network in `network_logits` (measured best of 4-128 at batch 256 on this CPU)."""


def network_logits(params, config: GQCNNConfig, crops: jax.Array, poses: jax.Array,
                   chunk: int = INFERENCE_CHUNK) -> jax.Array:
  """Logits (B, 2) of ``GQCNN(config)`` at inference (no dropout), computed ``chunk`` crops at a time.

  Args:
    params: the network's parameters.
    config: its architecture (static).
    crops: (B, S, S, 1) normalised crops.
    poses: (B, pose_dim) normalised poses.
    chunk: at most this many crops per pass (static); 0 or >= B: the whole batch in one pass. A batch of B is
      run as ceil(B / chunk) equal parts, padded with zero crops whose logits are dropped.

  Returns:
    (B, 2) logits [fail, success], equal to the unchunked network's up to float rounding.
  """
  return _chunked_logits(config, int(chunk), params, crops, poses)


def _whole(config: GQCNNConfig, params, crops: jax.Array, poses: jax.Array) -> jax.Array:
  return GQCNN(config).apply({'params': params}, crops, poses, train=False)


@functools.partial(jax.custom_vjp, nondiff_argnums=(0, 1))
def _chunked_logits(config: GQCNNConfig, chunk: int, params, crops: jax.Array, poses: jax.Array) -> jax.Array:
  batch = crops.shape[0]
  if chunk <= 0 or batch <= chunk:
    return _whole(config, params, crops, poses)
  parts = -(-batch // chunk)
  size = -(-batch // parts)
  pad = parts * size - batch

  def split(x: jax.Array) -> jax.Array:
    x = jnp.pad(x, ((0, pad),) + ((0, 0),) * (x.ndim - 1))
    return x.reshape(parts, size, *x.shape[1:])

  logits = jax.lax.map(lambda part: _whole(config, params, *part), (split(crops), split(poses)))
  return logits.reshape(parts * size, -1)[:batch]


def _chunked_forward(config, chunk, params, crops, poses):
  return _chunked_logits(config, chunk, params, crops, poses), (params, crops, poses)


def _chunked_backward(config, chunk, residuals, cotangent):
  del chunk
  _, vjp = jax.vjp(functools.partial(_whole, config), *residuals)
  return vjp(cotangent)


_chunked_logits.defvjp(_chunked_forward, _chunked_backward)

__all__ = ['INFERENCE_CHUNK', 'network_logits']
