"""Training examples of one gripper from dataset rows: grasp-centred crops, pose vectors, labels, augmentation.

Rows come from `dexjax.data.iterate_rows` (each with its depth image). A GQ-CNN example of a row is the
``crop_size`` crop centred on the grasp and rotated so the grasp axis is horizontal (`dexjax.sampling.grasp_crop`,
spec section 1.2, made here so the crop size stays a training parameter), the pose vector (gripper depth for the
parallel jaw; depth and approach angle for suction; spec section 1.4) and the label, the row's reward S (1 when
the grasp is collision-free, contacts one object and its robust probability exceeds 0.5).

`symmetrize` is the original's augmentation (spec section 3.4) for one example: independent coin flips for a
180-degree rotation, a left-right and an up-down flip, all about the grasp pixel (S/2, S/2) so it stays the crop
centre; for suction the rotation and the up-down flip negate the approach angle (`dexjax.models.symmetry`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import jax
import numpy as np

from dexjax.data.shards import GRIPPER_NAMES
from dexjax.models.symmetry import symmetric_view
from dexjax.quality.heap_reward import decided_by_robustness
from dexjax.sampling.crops import model_crop


def _patch_size(window: int) -> int:
  """Side of a square patch holding every pixel a rotated ``window`` crop (bilinear included) can read."""
  return int(math.ceil(window * math.sqrt(2.0))) + 4


def grasp_patches(depth, centers: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
  """Axis-aligned patches around grasp centres, so crops are made without copying whole images.

  Args:
    depth: the rows' depth images: (M, H, W) float32, or an (M,) object array of (H, W) images (references to
      shared images, as `dexjax.data.iterate_rows` gives with ``stack_images=False``).
    centers: (M, 2) grasp centres (u, v), pixels.
    window: crop window side, pixels.

  Returns:
    (M, P, P) float32 patches (0 outside the image, as `grasp_crop`'s border) and (M, 2) centres in patch pixels;
    ``grasp_crop(patch, local_center, ...)`` equals ``grasp_crop(image, center, ...)``.
  """
  size = _patch_size(window)
  centers = np.asarray(centers, np.float64)
  origin = np.floor(centers).astype(np.int64) - size // 2  # (u0, v0) of each patch
  out = np.zeros((len(centers), size, size), np.float32)
  for k, (u0, v0) in enumerate(origin):
    image = depth[k]
    h, w = image.shape
    r0, r1, c0, c1 = max(v0, 0), min(v0 + size, h), max(u0, 0), min(u0 + size, w)
    if r1 > r0 and c1 > c0:
      out[k, r0 - v0:r1 - v0, c0 - u0:c1 - u0] = image[r0:r1, c0:c1]
  return out, (centers - origin).astype(np.float32)


def _crop_batch(patches: jax.Array, centers: jax.Array, angle: jax.Array, window: int, size: int) -> jax.Array:
  """(M, size, size) crops of the ``window``-pixel grasp windows in patches (M, P, P) (NaN depth read as 0):
  nearest pixels at equal sizes (gqcnn), bilinear resampling otherwise (e.g. 96 -> 32)."""
  return jax.vmap(model_crop, in_axes=(0, 0, 0, None, None))(patches, centers, angle, window, size)


_crops = jax.jit(_crop_batch, static_argnums=(3, 4))


def _bucketed_crops(patches: np.ndarray, centers: np.ndarray, angles: np.ndarray, window: int,
                    size: int) -> np.ndarray:
  """`_crops` of M patches, padded to a power-of-two count (at least 8) so any M compiles one of a few shapes."""
  m = len(patches)
  bucket = max(8, 1 << (m - 1).bit_length())
  pad = lambda x: np.concatenate([x, np.zeros((bucket - m,) + x.shape[1:], x.dtype)])
  return np.asarray(_crops(pad(patches), pad(centers), pad(angles), window, size))[:m]


def _check_gripper(gripper: str) -> None:
  if gripper not in GRIPPER_NAMES:
    raise ValueError(f'gripper: expected one of {GRIPPER_NAMES}, got {gripper!r}')


def pose_vectors(rows: Mapping[str, np.ndarray], gripper: str) -> np.ndarray:
  """(M, pose_dim) float32 network pose inputs: [grasp_depth] (parallel jaw) or [grasp_depth, approach_angle]."""
  _check_gripper(gripper)
  columns = [rows['grasp_depth']] + ([rows['approach_angle']] if gripper == 'suction' else [])
  return np.stack(columns, axis=-1).astype(np.float32)


def soft_labels(rows: Mapping[str, np.ndarray]) -> np.ndarray:
  """(M,) float32 soft targets of rows: the robust probability where only robustness decided the reward
  (failure 'none' or 'not_robust'), else 0 (a collision or a wrong object count fails whatever the draws).
  Rows without a ``failure`` field (hand-made batches) get their reward as the target."""
  if 'failure' not in rows:
    return (np.asarray(rows['reward']) == 1).astype(np.float32)
  decided = decided_by_robustness(np.asarray(rows['failure']))
  return np.where(decided, np.asarray(rows['robust_probability'], np.float32), 0.0).astype(np.float32)


def label_probability(probability: np.ndarray, draws: int, threshold: float = 0.5) -> np.ndarray:
  """(M,) float32: the probability that a reward of ``draws`` Monte-Carlo draws is positive (the share of
  successful draws strictly above ``threshold``) for grasps of robust probability ``probability`` (M,): the upper
  tail of Binomial(draws, p), sum over k > threshold * draws of C(draws, k) p^k (1 - p)^(draws - k)."""
  p = np.clip(np.asarray(probability, np.float64), 0.0, 1.0)[..., None]
  k = np.arange(math.floor(threshold * draws) + 1, draws + 1)
  comb = np.array([math.comb(draws, int(i)) for i in k], np.float64)
  return np.sum(comb * p**k * (1.0 - p)**(draws - k), axis=-1).astype(np.float32)


def gripper_examples(batch: Mapping[str, np.ndarray], gripper: str, crop_size: int = 96,
                     crop_window: int | None = None) -> dict[str, np.ndarray]:
  """The examples of ``gripper`` in a loader batch (``depth``: per-row images, stacked or an object array, see
  `grasp_patches`): ``crops`` (M, S, S, 1) metres (NaN depth becomes 0, as the
  crop's border), ``poses`` (M, pose_dim), ``labels`` (M,) int32, ``robust_probability`` (M,), ``soft_labels``
  (M,) (`soft_labels`).

  ``crop_window`` (default ``crop_size``) is the side of the window read around the grasp, in image pixels; it is
  resampled to ``crop_size`` (S) pixels (Dex-Net 2.0's 96 -> 32 downsampling)."""
  _check_gripper(gripper)
  sel = np.asarray(batch['gripper']) == GRIPPER_NAMES.index(gripper)
  rows = {k: np.asarray(v)[sel] for k, v in batch.items()}
  if not sel.any():
    return {'crops': np.zeros((0, crop_size, crop_size, 1), np.float32), 'poses': pose_vectors(rows, gripper),
            'labels': np.zeros(0, np.int32), 'robust_probability': np.zeros(0, np.float32),
            'soft_labels': np.zeros(0, np.float32)}
  window = crop_size if crop_window is None else crop_window
  patches, centers = grasp_patches(rows['depth'], rows['center'], window)
  crops = _bucketed_crops(patches, centers, np.asarray(rows['angle'], np.float32), window, crop_size)
  return {'crops': crops[..., None], 'poses': pose_vectors(rows, gripper),
          'labels': (rows['reward'] == 1).astype(np.int32),
          'robust_probability': rows['robust_probability'].astype(np.float32), 'soft_labels': soft_labels(rows)}


def symmetrize(key: jax.Array, crop: jax.Array, pose: jax.Array, suction: bool) -> tuple[jax.Array, jax.Array]:
  """One example's random symmetry (see the module doc): crop (S, S, 1), pose (pose_dim,) -> the same shapes."""
  rotate, flip_lr, flip_ud = jax.random.bernoulli(key, 0.5, (3,))
  return symmetric_view(crop, pose, rotate, flip_lr, flip_ud, suction)


__all__ = ['grasp_patches', 'gripper_examples', 'pose_vectors', 'soft_labels', 'symmetrize']
