"""Depth instances (`dexjax.policy.depth_instances`) against SciPy's connected components of the same link graph."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from dexjax.policy.instances import depth_instances

H, W = 40, 52


def _reference(depth: np.ndarray, mask: np.ndarray, jump: float) -> np.ndarray:
  """(H, W) component index of every pixel: SciPy's connected components of the graph whose edges join
  4-neighbours both in ``mask`` with |depth difference| <= jump (float32 arithmetic, as the kernel's)."""
  index = np.arange(depth.size).reshape(depth.shape)
  right = mask[:, :-1] & mask[:, 1:] & (np.abs(depth[:, :-1] - depth[:, 1:]) <= jump)
  down = mask[:-1] & mask[1:] & (np.abs(depth[:-1] - depth[1:]) <= jump)
  rows = np.r_[index[:, :-1][right], index[:-1][down]]
  cols = np.r_[index[:, 1:][right], index[1:][down]]
  graph = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(depth.size, depth.size))
  return connected_components(graph, directed=False)[1].reshape(depth.shape)


def _same_partition(got: np.ndarray, want: np.ndarray, mask: np.ndarray) -> bool:
  pairs = set(zip(got[mask].tolist(), want[mask].tolist()))
  return len(pairs) == len(set(got[mask].tolist())) == len(set(want[mask].tolist()))


def test_components_match_scipy_on_random_steps_and_holes():
  rng = np.random.default_rng(0)
  for _ in range(4):
    # Steps of 3 mm (some links break at a 4 mm jump, some do not) on a noisy ramp, 20 % of pixels off the mask.
    depth = (0.7 + 0.003 * rng.integers(0, 3, (H, W)) + np.cumsum(rng.normal(0, 5e-4, (H, W)), axis=1) * 0.1)
    depth = depth.astype(np.float32)
    mask = rng.random((H, W)) < 0.8
    got = np.asarray(depth_instances(depth, mask, 0.004))
    want = _reference(depth, mask, np.float32(0.004))
    assert _same_partition(got, want, mask)
    assert np.all(got[~mask] == 0) and np.all(got[mask] > 0)
    assert len(np.unique(want[mask])) > 20  # the case is not trivial: many components


def test_labels_are_the_first_pixel_of_each_object_and_long_snakes_converge():
  # A one-pixel-wide serpentine (a component ~1,000 px long) beside a raised square: two objects.
  depth = np.full((H, W), 0.7, np.float32)
  mask = np.zeros((H, W), bool)
  mask[0:29:2, 1:W - 1] = True  # rows 0-28
  for r in range(1, 28, 2):
    mask[r, W - 2 if r % 4 == 1 else 1] = True
  depth[29:39, 20:30], mask[29:39, 20:30] = 0.69, True  # touching the snake's last row, 1 cm above it
  got = np.asarray(depth_instances(depth, mask))
  want = _reference(depth, mask, np.float32(0.004))
  assert _same_partition(got, want, mask) and len(np.unique(got[mask])) == 2
  assert got[0, 1] == 1 + 1  # the first pixel of the snake in row-major order (flat index 1)
  assert got[30, 25] == 1 + 29 * W + 20


def test_non_finite_depths_are_background():
  depth = np.full((H, W), 0.7, np.float32)
  depth[:, 20] = np.nan
  got = np.asarray(depth_instances(depth, np.ones((H, W), bool)))
  assert np.all(got[:, 20] == 0) and len(np.unique(got[:, :20])) == 1 and got[0, 0] != got[0, 21]
