"""How good are the grasps a policy chooses, and does it know? Precision at the choice and calibration.

A learned policy is only as good as the grasp it executes: a GQ-CNN with a high balanced accuracy over random
candidates can still be wrong where the optimiser looks (the CEM maximises the network's output, so the chosen
grasp is the network's most confident one, false positives included; issue 43). These metrics read the
benchmark's attempt records (`dexjax.bench.trial`), each a chosen grasp with the policy's predicted probability
``q`` and a verdict per judge:

* `precision_at_choice`: the fraction of chosen grasps a judge calls successes, per gripper and over both (the
  top-1 precision of the policy on the bins it was shown), with a 95 % Wilson interval; attempts without a grasp
  are counted apart (``no_grasp``), not as failures of a grasp;
* `calibration`: the chosen grasps binned by ``q`` (``bins`` equal-width bins on [0, 1]), each bin's mean ``q``
  beside the fraction the judge calls successes (a reliability diagram), and the expected calibration error
  ECE = sum_b n_b / n |mean q_b - success_b| (Naeini et al. 2015; Guo et al. 2017).

The analytic judge's verdict is the labels' definition of success (what a GQ-CNN is trained to predict), so its
calibration measures the network; the physics judge's measures the network and the labels together.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from dexjax.bench.picking_metrics import wilson_interval
from dexjax.policy.scorers import GRIPPERS

#: Equal-width bins of the predicted probability in the calibration curve (Guo et al. 2017 use 15; with a few
#: hundred attempts per policy, 10 keeps most bins populated).
CALIBRATION_BINS = 10
# Bins are [low, high): a q stored in float32 a hair below an edge (0.7 is 0.69999999) belongs above it.
_EDGE = 1e-6


def _judged(records: Iterable[Mapping[str, Any]], judge: str) -> list[Mapping[str, Any]]:
  """The records with a grasp and a verdict of ``judge``."""
  return [r for r in records if r.get('gripper') is not None and r.get(judge) is not None]


def _precision(rows: Sequence[Mapping[str, Any]], judge: str) -> dict[str, Any]:
  chosen, successes = len(rows), sum(bool(r[judge]) for r in rows)
  lo, hi = wilson_interval(successes, chosen)
  return {'chosen': chosen, 'successes': successes, 'precision': successes / chosen if chosen else math.nan,
          'wilson_95': [lo, hi], 'mean_q': (sum(float(r['q']) for r in rows) / chosen) if chosen else math.nan}


def precision_at_choice(records: Iterable[Mapping[str, Any]], judge: str = 'analytic') -> dict[str, Any]:
  """Top-1 precision of the chosen grasps under ``judge`` (``'analytic'`` or ``'physics'``).

  Args:
    records: attempt records with ``gripper`` (None: no grasp), ``q`` and the judge's boolean verdict.
    judge: the record field holding the verdict.
  Returns:
    ``{'all': counts, 'parallel_jaw': counts, 'suction': counts, 'no_grasp': int}``; counts are ``chosen``,
    ``successes``, ``precision`` (NaN without a grasp), ``wilson_95`` and ``mean_q`` (the policy's own mean
    prediction, to read the precision against).
  """
  records = list(records)
  rows = _judged(records, judge)
  out = {'all': _precision(rows, judge)}
  for gripper in GRIPPERS:
    out[gripper] = _precision([r for r in rows if r['gripper'] == gripper], judge)
  out['no_grasp'] = sum(r.get('gripper') is None for r in records)
  return out


def calibration(records: Iterable[Mapping[str, Any]], judge: str = 'analytic',
                bins: int = CALIBRATION_BINS) -> dict[str, Any]:
  """The reliability diagram and expected calibration error of the chosen grasps' predicted ``q``.

  Args:
    records: attempt records (as `precision_at_choice`).
    judge: the record field holding the verdict.
    bins: equal-width bins [low, high) on [0, 1] (within 1e-6 of an edge counts as on it); ``q`` = 1 falls in
      the last.
  Returns:
    ``{'ece': float (NaN without a grasp), 'count': int, 'bins': [{'low', 'high', 'count', 'mean_q',
    'success'}]}``, empty bins included (``mean_q`` and ``success`` NaN).
  """
  if not isinstance(bins, int) or bins < 1:
    raise ValueError(f'calibration: bins: expected an integer >= 1, got {bins!r}')
  rows = [r for r in _judged(records, judge) if r.get('q') is not None and math.isfinite(float(r['q']))]
  groups: list[list[Mapping[str, Any]]] = [[] for _ in range(bins)]
  for r in rows:
    groups[min(max(int(float(r['q']) * bins + _EDGE), 0), bins - 1)].append(r)
  table, ece = [], 0.0
  for b, group in enumerate(groups):
    n = len(group)
    mean_q = sum(float(r['q']) for r in group) / n if n else math.nan
    success = sum(bool(r[judge]) for r in group) / n if n else math.nan
    table.append({'low': b / bins, 'high': (b + 1) / bins, 'count': n, 'mean_q': mean_q, 'success': success})
    if n:
      ece += n / len(rows) * abs(mean_q - success)
  return {'ece': ece if rows else math.nan, 'count': len(rows), 'bins': table}


def choice_summary(records: Iterable[Mapping[str, Any]], judges: Sequence[str] = ('analytic', 'physics'),
                   bins: int = CALIBRATION_BINS) -> dict[str, Any]:
  """``{judge: {'precision': precision_at_choice, 'calibration': calibration}}`` of one policy's records, for
  each judge that gave a verdict on at least one of them."""
  records = list(records)
  return {judge: {'precision': precision_at_choice(records, judge), 'calibration': calibration(records, judge, bins)}
          for judge in judges if _judged(records, judge)}


__all__ = ['CALIBRATION_BINS', 'calibration', 'choice_summary', 'precision_at_choice']
