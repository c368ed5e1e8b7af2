"""The GQ-CNN's input symmetries: a grasp crop turned 180 degrees or flipped about the grasp pixel shows the same grasp.

Spec section 3.4: a crop is centred on the grasp and rotated so the grasp axis is horizontal, so a 180-degree
rotation, a left-right and an up-down flip about the grasp pixel (S/2, S/2) give the same grasp; for suction the
rotation and the up-down flip negate the approach angle (pose component 1). The three generate four distinct views
(identity, rotation, left-right, up-down; the rotation is both flips). Training draws one at random per example
(`dexjax.train.symmetrize`); a model with ``symmetric_views`` averages its prediction over all four
(`dexjax.models.GraspQualityModel`; deviation 51). Single-example functions: batch them with ``jax.vmap``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

NUM_VIEWS = 4
"""Distinct symmetric views of a crop: identity, 180-degree rotation, left-right flip, up-down flip."""

# (rotate, flip_lr, flip_ud) of each view, in the order `symmetric_views` returns them.
_VIEW_FLAGS = ((False, False, False), (True, False, False), (False, True, False), (False, False, True))


def reflect(image: jax.Array, axis: int) -> jax.Array:
  """``image`` (S, S, C) reflected about index S/2 along ``axis`` (0: rows, 1: columns): i -> S - i; index 0
  (mapped outside the crop) gets 0."""
  s = image.shape[axis]
  source = (s - jnp.arange(s)) % s  # S - i, and 0 for i = 0
  out = jnp.take(image, source, axis=axis)
  keep = (jnp.arange(s) > 0).reshape((-1, 1) if axis == 0 else (1, -1))[..., None]
  return jnp.where(keep, out, 0.0)


def symmetric_view(crop: jax.Array, pose: jax.Array, rotate: jax.Array, flip_lr: jax.Array, flip_ud: jax.Array,
                   suction: bool) -> tuple[jax.Array, jax.Array]:
  """One view of a grasp: crop (S, S, 1) metres and pose (pose_dim,) after an optional 180-degree rotation, then
  an optional left-right and up-down flip (booleans, traced or not); the suction approach angle is negated when
  exactly one of the rotation and the up-down flip is applied."""
  crop = jnp.where(rotate, reflect(reflect(crop, 0), 1), crop)
  crop = jnp.where(flip_lr, reflect(crop, 1), crop)
  crop = jnp.where(flip_ud, reflect(crop, 0), crop)
  if suction:
    pose = pose.at[1].multiply(jnp.where(jnp.logical_xor(rotate, flip_ud), -1.0, 1.0))
  return crop, pose


def symmetric_views(crop: jax.Array, pose: jax.Array, suction: bool) -> tuple[jax.Array, jax.Array]:
  """The `NUM_VIEWS` views of one grasp: crops (4, S, S, 1) and poses (4, pose_dim)."""
  views = [symmetric_view(crop, pose, *flags, suction=suction) for flags in _VIEW_FLAGS]
  return jnp.stack([c for c, _ in views]), jnp.stack([p for _, p in views])


__all__ = ['NUM_VIEWS', 'reflect', 'symmetric_view', 'symmetric_views']
