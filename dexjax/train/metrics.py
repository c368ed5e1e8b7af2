"""Binary classification metrics of a grasp-quality network on a validation split (NumPy, plain JSON out).

Predicted label = p(success) > threshold (0.5). Accuracy, balanced accuracy (mean of the true-positive and
true-negative rates), precision, recall, and average precision (area under the precision-recall curve as the
step sum over the ranked scores, sum_k (R_k - R_{k-1}) P_k, with ties in score ranked together: the definition
of scikit-learn's ``average_precision_score``). Undefined values (no positive, nothing predicted positive) are
None, so the output stays valid JSON.

`bootstrap_intervals` gives how far these two figures would move on another sample of the same population: a
cluster (group) bootstrap, which resamples whole groups of rows (the images, or the objects, of a dataset) with
replacement, because rows of one object or one heap are not independent. With 30 held-out objects the object
sample, not the row count, decides how precise a score on unseen objects is.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def average_precision(scores: np.ndarray, labels: np.ndarray) -> float | None:
  """Average precision of ``scores`` (N,) for binary ``labels`` (N,); None without positives."""
  scores, labels = np.asarray(scores, np.float64), np.asarray(labels).astype(bool)
  positives = int(labels.sum())
  if positives == 0:
    return None
  order = np.argsort(-scores, kind='mergesort')
  scores, labels = scores[order], labels[order]
  last_of_tie = np.r_[np.flatnonzero(np.diff(scores)), len(scores) - 1]  # thresholds between distinct scores
  tp = np.cumsum(labels)[last_of_tie]
  predicted = last_of_tie + 1
  precision, recall = tp / predicted, tp / positives
  return float(np.sum(np.diff(np.r_[0.0, recall]) * precision))


def classification_metrics(scores: np.ndarray, labels: np.ndarray, threshold: float = 0.5) -> dict[str, Any]:
  """Counts and rates of p(success) ``scores`` (N,) against binary ``labels`` (N,) (see the module doc)."""
  scores, labels = np.asarray(scores, np.float64), np.asarray(labels).astype(bool)
  predicted = scores > threshold
  tp, tn = int(np.sum(predicted & labels)), int(np.sum(~predicted & ~labels))
  fp, fn = int(np.sum(predicted & ~labels)), int(np.sum(~predicted & labels))
  n = len(labels)
  ratio = lambda a, b: a / b if b else None
  tpr, tnr = ratio(tp, tp + fn), ratio(tn, tn + fp)
  rates = [r for r in (tpr, tnr) if r is not None]
  return {'examples': n, 'positives': tp + fn, 'accuracy': ratio(tp + tn, n),
          'balanced_accuracy': float(np.mean(rates)) if rates else None, 'precision': ratio(tp, tp + fp),
          'recall': tpr, 'true_negative_rate': tnr, 'average_precision': average_precision(scores, labels)}


_CHUNK = 64  # resamples per vectorised pass (memory: _CHUNK x rows float64)


def _resampled_metrics(scores: np.ndarray, labels: np.ndarray, group_index: np.ndarray,
                       counts: np.ndarray, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
  """Balanced accuracy and average precision (R,) of the data in which group g appears ``counts[r, g]`` times
  (``counts`` (R, G) integers; ``group_index`` (N,) in [0, G)); NaN where a class is absent from a resample."""
  scores, labels = np.asarray(scores, np.float64), np.asarray(labels).astype(bool)
  predicted = scores > threshold
  per_group = np.zeros((4, counts.shape[1]))  # tp, fn, tn, fp per group
  for k, cell in enumerate((predicted & labels, ~predicted & labels, ~predicted & ~labels, predicted & ~labels)):
    np.add.at(per_group[k], group_index[cell], 1.0)
  tp, fn, tn, fp = (counts @ per_group.T).T  # (R,) each
  with np.errstate(invalid='ignore', divide='ignore'):
    balanced = 0.5 * (tp / (tp + fn) + tn / (tn + fp))
  order = np.argsort(-scores, kind='mergesort')
  last_of_tie = np.r_[np.flatnonzero(np.diff(scores[order])), len(scores) - 1]
  sorted_labels, sorted_groups = labels[order], group_index[order]
  ap = np.empty(len(counts))
  for start in range(0, len(counts), _CHUNK):
    weights = counts[start:start + _CHUNK][:, sorted_groups].astype(np.float64)  # (r, N) multiplicity per row
    true_pos = np.cumsum(weights * sorted_labels, axis=1)[:, last_of_tie]
    chosen = np.cumsum(weights, axis=1)[:, last_of_tie]
    positives = true_pos[:, -1:]
    with np.errstate(invalid='ignore', divide='ignore'):
      precision = np.where(chosen > 0, true_pos / np.maximum(chosen, 1e-300), 0.0)
      recall = true_pos / positives
    ap[start:start + _CHUNK] = np.sum(np.diff(recall, prepend=0.0, axis=1) * precision, axis=1)
  return balanced, ap


def bootstrap_intervals(scores: np.ndarray, labels: np.ndarray, groups: np.ndarray, num_resamples: int = 1000,
                        level: float = 0.95, seed: int = 0, threshold: float = 0.5) -> dict[str, Any]:
  """Percentile intervals of balanced accuracy and average precision under a cluster bootstrap.

  Args:
    scores, labels: p(success) (N,) and binary labels (N,), as for `classification_metrics`.
    groups: (N,) any hashable values; rows with equal values are resampled together (all or none).
    num_resamples: bootstrap resamples R (each draws G of the G groups with replacement).
    level: the central probability of each interval.
    seed: the resampling seed (same inputs and seed, same intervals).
    threshold: the decision threshold of the balanced accuracy.

  Returns:
    ``{'groups': G, 'resamples': R, 'level': level, 'balanced_accuracy': [lo, hi], 'average_precision': [lo,
    hi]}``; an interval is None when fewer than half of the resamples define the metric (no positives, or fewer
    than two groups).
  """
  if not 0.0 < level < 1.0 or num_resamples < 1:
    raise ValueError(f'bootstrap_intervals: expected 0 < level < 1 and num_resamples >= 1, got {level}, '
                     f'{num_resamples}')
  groups = np.asarray(groups)
  if groups.shape != np.shape(labels) or np.shape(scores) != np.shape(labels):
    raise ValueError(f'bootstrap_intervals: expected scores, labels and groups of one shape (N,), got '
                     f'{np.shape(scores)}, {np.shape(labels)}, {groups.shape}')
  _, group_index = np.unique(groups, return_inverse=True)
  num_groups = int(group_index.max()) + 1 if len(group_index) else 0
  result = {'groups': num_groups, 'resamples': num_resamples, 'level': level, 'balanced_accuracy': None,
            'average_precision': None}
  if num_groups < 2:  # nothing to resample (no rows, or one group)
    return result
  rng = np.random.default_rng(seed)
  picks = rng.integers(0, num_groups, size=(num_resamples, num_groups))
  counts = np.zeros((num_resamples, num_groups), np.int64)
  np.add.at(counts, (np.arange(num_resamples)[:, None], picks), 1)
  balanced, ap = _resampled_metrics(scores, labels, group_index.reshape(-1), counts, threshold)
  tail = 50.0 * (1.0 - level)

  def interval(values: np.ndarray) -> list[float] | None:
    values = values[np.isfinite(values)]
    if len(values) < num_resamples / 2:
      return None
    return [float(v) for v in np.percentile(values, [tail, 100.0 - tail])]

  return {**result, 'balanced_accuracy': interval(balanced), 'average_precision': interval(ap)}


__all__ = ['average_precision', 'bootstrap_intervals', 'classification_metrics']
