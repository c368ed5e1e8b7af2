"""Training examples of one gripper from dataset rows: grasp-centred crops, pose vectors, labels, augmentation.

Rows come from `dexjax.data.iterate_rows` (each with its depth image). A GQ-CNN example of a row is the
``crop_size`` crop centred on the grasp and rotated so the grasp axis is horizontal (`dexjax.sampling.grasp_crop`,
spec section 1.2, made here so the crop size stays a training parameter), the pose vector (gripper depth for the
parallel jaw; depth and approach angle for suction; spec section 1.4) and the label, the row's reward S (1 when
the grasp is collision-free, contacts one object and its robust probability exceeds 0.5).

`symmetrize` is the original's augmentation (spec section 3.4) for one example: independent coin flips for a
180-degree rotation, a left-right and an up-down flip, all about the grasp pixel (S/2, S/2) so it stays the crop
centre; for suction the rotation and the up-down flip negate the approach angle.
"""

from __future__ import annotations

from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from dexjax.data.shards import GRIPPER_NAMES
from dexjax.sampling.crops import grasp_crop

_crops = jax.jit(jax.vmap(grasp_crop, in_axes=(0, 0, 0, None)), static_argnums=3)


def _check_gripper(gripper: str) -> None:
  if gripper not in GRIPPER_NAMES:
    raise ValueError(f'gripper: expected one of {GRIPPER_NAMES}, got {gripper!r}')


def pose_vectors(rows: Mapping[str, np.ndarray], gripper: str) -> np.ndarray:
  """(M, pose_dim) float32 network pose inputs: [grasp_depth] (parallel jaw) or [grasp_depth, approach_angle]."""
  _check_gripper(gripper)
  columns = [rows['grasp_depth']] + ([rows['approach_angle']] if gripper == 'suction' else [])
  return np.stack(columns, axis=-1).astype(np.float32)


def gripper_examples(batch: Mapping[str, np.ndarray], gripper: str, crop_size: int = 96) -> dict[str, np.ndarray]:
  """The examples of ``gripper`` in a loader batch: ``crops`` (M, S, S, 1) metres (NaN depth becomes 0, as the
  crop's border), ``poses`` (M, pose_dim), ``labels`` (M,) int32, ``robust_probability`` (M,)."""
  _check_gripper(gripper)
  sel = np.asarray(batch['gripper']) == GRIPPER_NAMES.index(gripper)
  rows = {k: np.asarray(v)[sel] for k, v in batch.items()}
  if not sel.any():
    return {'crops': np.zeros((0, crop_size, crop_size, 1), np.float32), 'poses': pose_vectors(rows, gripper),
            'labels': np.zeros(0, np.int32), 'robust_probability': np.zeros(0, np.float32)}
  depth = np.nan_to_num(rows['depth'], nan=0.0)
  crops = np.asarray(_crops(jnp.asarray(depth), jnp.asarray(rows['center']), jnp.asarray(rows['angle']), crop_size))
  return {'crops': crops[..., None], 'poses': pose_vectors(rows, gripper),
          'labels': (rows['reward'] == 1).astype(np.int32),
          'robust_probability': rows['robust_probability'].astype(np.float32)}


def _reflect(image: jax.Array, axis: int) -> jax.Array:
  """``image`` (S, S, C) reflected about index S/2 along ``axis``: i -> S - i; index 0 (mapped outside) gets 0."""
  s = image.shape[axis]
  source = (s - jnp.arange(s)) % s  # S - i, and 0 for i = 0
  out = jnp.take(image, source, axis=axis)
  keep = (jnp.arange(s) > 0).reshape((-1, 1) if axis == 0 else (1, -1))[..., None]
  return jnp.where(keep, out, 0.0)


def symmetrize(key: jax.Array, crop: jax.Array, pose: jax.Array, suction: bool) -> tuple[jax.Array, jax.Array]:
  """One example's random symmetry (see the module doc): crop (S, S, 1), pose (pose_dim,) -> the same shapes."""
  rotate, flip_lr, flip_ud = jax.random.bernoulli(key, 0.5, (3,))
  rotated = _reflect(_reflect(crop, 0), 1)
  crop = jnp.where(rotate, rotated, crop)
  crop = jnp.where(flip_lr, _reflect(crop, 1), crop)
  crop = jnp.where(flip_ud, _reflect(crop, 0), crop)
  if suction:
    sign = jnp.where(rotate ^ flip_ud, -1.0, 1.0)
    pose = pose.at[1].multiply(sign)
  return crop, pose


__all__ = ['gripper_examples', 'pose_vectors', 'symmetrize']
