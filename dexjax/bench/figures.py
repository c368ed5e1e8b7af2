"""The benchmark's figures (PNG, matplotlib), drawn from results.json's content (`dexjax.bench.summarize_run`).

* ``reliability.png``: reliability per policy and object level with 95 % Wilson intervals, mean picks per hour
  and judge agreement in the legend (the seed's headline comparison);
* ``per_object.png``: each policy's per-object reliability with 95 % intervals (the seed's Fig. S2);
* ``difficulty.png``: each object's reliability averaged over the policies, hardest first, with the standard
  error of that mean (the seed's Fig. S3);
* ``calibration.png``: per judge, each policy's reliability diagram at its chosen grasps (predicted probability
  against realised success; `dexjax.bench.choice_calibration`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from matplotlib.figure import Figure  # no pyplot: drawing a figure leaves the caller's backend and figures alone

_MAX_OBJECTS = 60  # objects drawn per per-object panel (the hardest first when there are more)


def _policy_label(name: str, entry: dict) -> str:
  """A policy's name in the figures; the supervisor's marked as using privileged state."""
  return name.replace('_', ' ') + (' (privileged state)' if entry.get('privileged') else '')


def _short(name: str) -> str:
  return name if len(name) <= 28 else '...' + name[-25:]


def plot_reliability(results: Mapping[str, Any], path: str | os.PathLike[str]) -> None:
  """Reliability per policy (bar groups) and level (bars) with 95 % Wilson intervals."""
  policies = results['policies']
  levels = sorted({level for entry in policies.values() for level in entry['per_level']}, key=str)
  fig = Figure(figsize=(max(5.0, 1.2 + 1.7 * len(policies) * max(1.0, len(levels) / 2)), 4.0))
  ax = fig.subplots()
  width = 0.8 / max(1, len(levels))
  for j, level in enumerate(levels):
    xs, ys, lo, hi = [], [], [], []
    for i, entry in enumerate(policies.values()):
      counts = entry['per_level'].get(level)
      if not counts or not counts['attempts']:
        continue
      xs.append(i + (j - (len(levels) - 1) / 2) * width)
      ys.append(counts['reliability'])
      lo.append(max(0.0, counts['reliability'] - counts['wilson_95'][0]))
      hi.append(max(0.0, counts['wilson_95'][1] - counts['reliability']))
    label = f'level {level}' if level not in ('None', None) else 'other objects'
    ax.bar(xs, ys, width, yerr=[lo, hi], capsize=3, label=label)
  ax.set_xticks(range(len(policies)))
  ax.set_xticklabels([f"{_policy_label(name, entry)}\n{entry['mpph']:.0f} MPPH" + (
      f"\nagreement {entry['judge_agreement']:.2f}" if entry['judge_agreement'] == entry['judge_agreement'] else '')
                      for name, entry in policies.items()], fontsize=8)
  ax.set_ylim(0, 1.05)
  ax.set_ylabel('reliability (successes / attempts)')
  ax.legend(fontsize=8, loc='lower right')
  ax.set_title(f"Universal Picking benchmark, judged by {results['config']['judge']}", fontsize=10)
  fig.tight_layout()
  fig.savefig(path, dpi=120)


def plot_per_object(results: Mapping[str, Any], path: str | os.PathLike[str]) -> None:
  """Fig. S2: per-object reliability with 95 % intervals (the seed's standard-error interval), one panel per
  policy, objects in difficulty order."""
  policies = results['policies']
  order = list(results['object_difficulty'])[:_MAX_OBJECTS]
  fig = Figure(figsize=(3.2 * len(policies) + 1.5, 0.22 * len(order) + 1.2))
  axes = fig.subplots(1, len(policies), sharey=True, squeeze=False)
  for ax, (name, entry) in zip(axes[0], policies.items()):
    ys, xs, lo, hi = [], [], [], []
    for y, obj in enumerate(order):
      counts = entry['per_object'].get(obj)
      if counts is None:
        continue
      ys.append(y)
      xs.append(counts['reliability'])
      lo.append(max(0.0, counts['reliability'] - counts['sem_95'][0]))
      hi.append(max(0.0, counts['sem_95'][1] - counts['reliability']))
    ax.errorbar(xs, ys, xerr=[lo, hi], fmt='o', markersize=3, capsize=2)
    ax.set_xlim(-0.05, 1.05)
    ax.set_title(_policy_label(name, entry), fontsize=9)
    ax.set_xlabel('reliability')
  axes[0][0].set_yticks(range(len(order)))
  axes[0][0].set_yticklabels([_short(o) for o in order], fontsize=6)
  axes[0][0].invert_yaxis()
  fig.tight_layout()
  fig.savefig(path, dpi=120)


def plot_difficulty(results: Mapping[str, Any], path: str | os.PathLike[str]) -> None:
  """Fig. S3: each object's reliability averaged over the policies, hardest first, +- one standard error."""
  difficulty = list(results['object_difficulty'].items())[:_MAX_OBJECTS]
  fig = Figure(figsize=(max(4.0, 0.18 * len(difficulty) + 1.5), 3.4))
  ax = fig.subplots()
  xs = range(len(difficulty))
  ax.bar(xs, [d['reliability'] for _, d in difficulty], yerr=[d['sem'] for _, d in difficulty], capsize=2)
  ax.set_xticks(list(xs))
  ax.set_xticklabels([_short(name) for name, _ in difficulty], rotation=90, fontsize=6)
  ax.set_ylim(0, 1.05)
  ax.set_ylabel('mean reliability over policies')
  ax.set_title('Object difficulty (hardest first)', fontsize=10)
  fig.tight_layout()
  fig.savefig(path, dpi=120)


def plot_calibration(results: Mapping[str, Any], path: str | os.PathLike[str]) -> None:
  """Reliability diagrams of the chosen grasps, one panel per judge: each policy's mean predicted probability
  per bin against the fraction the judge calls successes (marker area ~ attempts), the diagonal of a calibrated
  policy, and each policy's expected calibration error and precision at the choice in the legend."""
  policies = results['policies']
  judges = sorted({judge for entry in policies.values() for judge in entry.get('at_choice', {})})
  fig = Figure(figsize=(4.2 * max(1, len(judges)), 4.2))
  axes = fig.subplots(1, max(1, len(judges)), squeeze=False)[0]
  for ax, judge in zip(axes, judges):
    ax.plot([0, 1], [0, 1], color='0.6', lw=1, ls='--')
    for name, entry in policies.items():
      choice = entry.get('at_choice', {}).get(judge)
      if choice is None:
        continue
      full = [b for b in choice['calibration']['bins'] if b['count']]
      label = (f"{_policy_label(name, entry)}: ECE {choice['calibration']['ece']:.2f}, "
               f"precision {choice['precision']['all']['precision']:.2f}")
      ax.plot([b['mean_q'] for b in full], [b['success'] for b in full], marker='', lw=1)
      ax.scatter([b['mean_q'] for b in full], [b['success'] for b in full], s=[8 + 2 * b['count'] for b in full],
                 alpha=0.7, label=label, color=ax.lines[-1].get_color())
    ax.set_xlim(0, 1)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel('predicted probability q of the chosen grasp')
    ax.set_ylabel(f'success under the {judge} judge')
    ax.set_title(f'Calibration at the choice ({judge})', fontsize=10)
    ax.legend(fontsize=6, loc='upper left')
  fig.tight_layout()
  fig.savefig(path, dpi=120)


def save_figures(results: Mapping[str, Any], out_dir: str | os.PathLike[str]) -> list[str]:
  """Writes the figures into ``out_dir`` (the per-object ones only with objects attempted, the calibration one
  only with a judged grasp); returns their file names."""
  out = Path(out_dir)
  names = []
  judged = any(entry.get('at_choice') for entry in results['policies'].values())
  for name, draw in (('reliability.png', plot_reliability), ('per_object.png', plot_per_object),
                     ('difficulty.png', plot_difficulty), ('calibration.png', plot_calibration)):
    if name in ('per_object.png', 'difficulty.png') and not results['object_difficulty']:
      continue
    if name == 'calibration.png' and not judged:
      continue
    draw(results, out / name)
    names.append(name)
  return names


__all__ = ['plot_calibration', 'plot_difficulty', 'plot_per_object', 'plot_reliability', 'save_figures']
