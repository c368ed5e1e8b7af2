"""Binary classification metrics of a grasp-quality network on a validation split (NumPy, plain JSON out).

Predicted label = p(success) > threshold (0.5). Accuracy, balanced accuracy (mean of the true-positive and
true-negative rates), precision, recall, and average precision (area under the precision-recall curve as the
step sum over the ranked scores, sum_k (R_k - R_{k-1}) P_k, with ties in score ranked together: the definition
of scikit-learn's ``average_precision_score``). Undefined values (no positive, nothing predicted positive) are
None, so the output stays valid JSON.
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


__all__ = ['average_precision', 'classification_metrics']
