"""What a training run reports: ``OUT/metrics.jsonl`` (one JSON object per epoch and gripper), learning curves
(``OUT/curves.png``) and the terminal summary.

Each record holds ``gripper``, ``epoch`` (1-based), ``step``, the epoch's mean training ``train_loss`` and
``train_accuracy`` (class-weighted as the loss is), ``learning_rate``, ``examples_per_s``, and the validation
metrics of `dexjax.train.classification_metrics` prefixed ``val_`` (``val_loss``, ``val_accuracy``,
``val_balanced_accuracy``, ``val_precision``, ``val_recall``, ``val_average_precision``, ...).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from dexjax.geometry.cache import atomic_write_text

METRICS_FILE = 'metrics.jsonl'
CURVES_FILE = 'curves.png'


def read_records(out_dir: str | os.PathLike) -> list[dict[str, Any]]:
  """The records of ``OUT/metrics.jsonl`` in file order (none if the file does not exist)."""
  path = Path(out_dir) / METRICS_FILE
  if not path.exists():
    return []
  with open(path) as f:
    return [json.loads(line) for line in f if line.strip()]


def append_record(out_dir: str | os.PathLike, record: dict[str, Any]) -> None:
  """Appends one record (a line) to ``OUT/metrics.jsonl``."""
  with open(Path(out_dir) / METRICS_FILE, 'a') as f:
    f.write(json.dumps(record) + '\n')


def prune_records(out_dir: str | os.PathLike, gripper: str, last_epoch: int) -> None:
  """Drops ``gripper``'s records after ``last_epoch`` (epochs a resumed run will redo)."""
  records = read_records(out_dir)
  kept = [r for r in records if r['gripper'] != gripper or r['epoch'] <= last_epoch]
  if len(kept) != len(records):
    atomic_write_text(Path(out_dir) / METRICS_FILE, ''.join(json.dumps(r) + '\n' for r in kept))


def plot_curves(out_dir: str | os.PathLike) -> Path | None:
  """``OUT/curves.png``: training / validation loss, validation balanced accuracy and average precision per epoch
  and gripper; None if there is no record yet."""
  records = read_records(out_dir)
  if not records:
    return None
  from matplotlib.figure import Figure  # pylint: disable=g-import-not-at-top  (no pyplot: the caller's backend stays)

  panels = [('loss', ('train_loss', 'val_loss')), ('balanced accuracy', ('val_balanced_accuracy',)),
            ('average precision', ('val_average_precision',))]
  fig = Figure(figsize=(4.2 * len(panels), 3.4), constrained_layout=True)
  axes = fig.subplots(1, len(panels))
  grippers = sorted({r['gripper'] for r in records})
  for ax, (title, keys) in zip(axes, panels):
    for gripper in grippers:
      rows = [r for r in records if r['gripper'] == gripper]
      for key in keys:
        points = [(r['epoch'], r[key]) for r in rows if r.get(key) is not None]
        if points:
          style = '--' if key.startswith('train') else '-'
          ax.plot(*zip(*points), style, marker='o', ms=3, label=f'{gripper} {key.split("_")[0]}')
    if title == 'balanced accuracy':
      ax.axhline(0.5, color='0.6', lw=0.8, ls=':')  # chance
    ax.set_title(title)
    ax.set_xlabel('epoch')
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
      ax.legend(fontsize=7)
    else:  # e.g. average precision of a validation split without a positive
      ax.text(0.5, 0.5, 'not defined yet', ha='center', va='center', transform=ax.transAxes, color='0.5')
  path = Path(out_dir) / CURVES_FILE
  fig.savefig(path, dpi=110)
  return path


def _fmt(value: Any) -> str:
  return '-' if value is None else f'{value:.3f}' if isinstance(value, float) else str(value)


def format_epoch(record: dict[str, Any]) -> str:
  """One line per epoch for the terminal."""
  return (f"{record['gripper']:>12} epoch {record['epoch']:>3}  loss {_fmt(record['train_loss'])}  "
          f"val loss {_fmt(record.get('val_loss'))}  acc {_fmt(record.get('val_accuracy'))}  "
          f"bal acc {_fmt(record.get('val_balanced_accuracy'))}  AP {_fmt(record.get('val_average_precision'))}  "
          f"({record['examples_per_s']:.0f} ex/s)")


def format_summary(results: dict[str, dict[str, Any]], out_dir: str | os.PathLike) -> str:
  """The run's end: the best validation epoch of each gripper and where the outputs are."""
  lines = ['', f'{"gripper":>12}  best epoch  val examples (pos)  accuracy  balanced acc  precision  recall  AP']
  for gripper, best in results.items():
    lines.append(f"{gripper:>12}  {best['epoch']:>10}  {best['val_examples']:>12} ({best['val_positives']:>4})  "
                 f"{_fmt(best['val_accuracy']):>8}  {_fmt(best['val_balanced_accuracy']):>12}  "
                 f"{_fmt(best['val_precision']):>9}  {_fmt(best['val_recall']):>6}  "
                 f"{_fmt(best['val_average_precision'])}")
  out = Path(out_dir)
  lines += ['', f'models:  {out}/<gripper>/best   (dexjax.models.load("{out}/<gripper>"))',
            f'metrics: {out / METRICS_FILE}, {out / CURVES_FILE}']
  return '\n'.join(lines)


__all__ = ['CURVES_FILE', 'METRICS_FILE', 'append_record', 'format_epoch', 'format_summary', 'plot_curves',
           'prune_records', 'read_records']
