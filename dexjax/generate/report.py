"""What a generation run produced: row statistics (JSON and a terminal table) and a picture of one shard image.

`RowStats` accumulates the rows of shard after shard (a run never holds all rows) and turns into a plain-JSON
summary; `summarize_rows` and `merge_summaries` are the one-shot and the dict-level forms of the same thing.
`save_generation_png` draws one image of a shard with its labelled grasps beside a grid of the grasp-centred
crops the GQ-CNNs are trained on (matplotlib, Agg).
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Any, Mapping

import jax
import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Circle

from dexjax.cli import PNG_MARK, atomic_path
from dexjax.data.shards import GRIPPER_NAMES, Shard
from dexjax.quality.heap_reward import REWARD_FAILURES
from dexjax.sampling.crops import grasp_crop

_DPI = 100
_PANEL_INCHES = 4.8       # height of the depth panel and of the crop grid
_FIGURE_HEIGHT_PX = 560   # (_PANEL_INCHES + 0.8) * _DPI: panels plus title and margins
_REWARD_COLOURS = ('#e8322a', '#2fd158')  # reward 0 red, reward 1 green
_INVALID_COLOUR = '#3050ff'  # NaN depth, and crop pixels off the image
_SUPERVISOR = 1           # POLICY_NAMES code of the algorithmic supervisor
_JAW_WIDTH = 0.05         # metres, ParallelJawGripper().max_width: the rows do not record the opening
_CUP_RADIUS = 0.01        # metres, SuctionGripper().cup_radius
_SHORT = {'parallel_jaw': 'jaw', 'suction': 'suction'}

# (H, W) depth, (K, 2) centres, (K,) angles, static crop size -> (K, c, c) crops.
_crops = jax.jit(jax.vmap(grasp_crop, in_axes=(None, 0, 0, None)), static_argnums=3)


@dataclasses.dataclass
class _GripperCounts:
  rows: int = 0
  positives: int = 0
  supervisor_rows: int = 0
  supervisor_positives: int = 0
  probability_sum: float = 0.0
  failures: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(len(REWARD_FAILURES), np.int64))

  def merge(self, other: _GripperCounts) -> None:
    self.rows += other.rows
    self.positives += other.positives
    self.supervisor_rows += other.supervisor_rows
    self.supervisor_positives += other.supervisor_positives
    self.probability_sum += other.probability_sum
    self.failures = self.failures + other.failures

  def to_dict(self) -> dict[str, Any]:
    return {
      "rows": self.rows,
      "positives": self.positives,
      "positive_rate": self.positives / self.rows if self.rows else None,
      "supervisor_rows": self.supervisor_rows,
      "supervisor_positives": self.supervisor_positives,
      "mean_robust_probability": self.probability_sum / self.rows if self.rows else None,
      "failures": {name: int(n) for name, n in zip(REWARD_FAILURES, self.failures)},
    }


@dataclasses.dataclass
class RowStats:
  """Running row statistics of a generation run, one `_GripperCounts` per `GRIPPER_NAMES` entry.

  Feed each shard's rows to `add` (or combine accumulators with `merge`); `to_dict` gives the JSON summary.
  """

  grippers: dict[str, _GripperCounts] = dataclasses.field(
      default_factory=lambda: {name: _GripperCounts() for name in GRIPPER_NAMES})

  @property
  def rows(self) -> int:
    return sum(c.rows for c in self.grippers.values())

  def add(self, rows: Mapping[str, np.ndarray]) -> RowStats:
    """Counts ``rows`` (`ROW_SCHEMA` fields gripper, reward, policy, failure, robust_probability; leading axis M).

    Returns self. Raises ValueError naming the field when a gripper or failure code is out of range.
    """
    gripper = np.asarray(rows["gripper"]).astype(np.int64).reshape(-1)
    reward = np.asarray(rows["reward"]).reshape(-1) == 1
    supervisor = np.asarray(rows["policy"]).reshape(-1) == _SUPERVISOR
    failure = np.asarray(rows["failure"]).astype(np.int64).reshape(-1)
    probability = np.asarray(rows["robust_probability"], np.float64).reshape(-1)
    _check_codes("gripper", gripper, len(GRIPPER_NAMES))
    _check_codes("failure", failure, len(REWARD_FAILURES))
    for code, name in enumerate(GRIPPER_NAMES):
      sel = gripper == code
      counts = self.grippers[name]
      counts.rows += int(sel.sum())
      counts.positives += int((sel & reward).sum())
      counts.supervisor_rows += int((sel & supervisor).sum())
      counts.supervisor_positives += int((sel & supervisor & reward).sum())
      counts.probability_sum += float(probability[sel].sum())
      counts.failures = counts.failures + np.bincount(failure[sel], minlength=len(REWARD_FAILURES))
    return self

  def merge(self, other: RowStats) -> RowStats:
    """Adds the counts of ``other`` into self; returns self."""
    for name, counts in other.grippers.items():
      self.grippers.setdefault(name, _GripperCounts()).merge(counts)
    return self

  def to_dict(self, seconds: float | None = None) -> dict[str, Any]:
    """Plain-JSON summary: total ``rows``, ``positives``, ``positive_rate`` (None without rows), per-gripper
    counts under ``grippers`` and, when ``seconds`` (wall time) is given, ``seconds`` and ``rows_per_s``."""
    total = _GripperCounts()
    for counts in self.grippers.values():
      total.merge(counts)
    summary: dict[str, Any] = {
      "rows": total.rows,
      "positives": total.positives,
      "positive_rate": total.positives / total.rows if total.rows else None,
      "grippers": {name: counts.to_dict() for name, counts in self.grippers.items()},
    }
    if seconds is not None:
      summary["seconds"] = float(seconds)
      summary["rows_per_s"] = total.rows / seconds if seconds > 0 else None
    return summary

  @classmethod
  def from_dict(cls, summary: Mapping[str, Any]) -> RowStats:
    """The accumulator of a `to_dict` summary (the probability sum is recovered as mean x rows)."""
    stats = cls()
    for name, entry in summary["grippers"].items():
      mean = entry["mean_robust_probability"]
      stats.grippers[name] = _GripperCounts(
          rows=int(entry["rows"]), positives=int(entry["positives"]), supervisor_rows=int(entry["supervisor_rows"]),
          supervisor_positives=int(entry.get("supervisor_positives", 0)),
          probability_sum=float(mean) * int(entry["rows"]) if mean is not None else 0.0,
          failures=np.array([int(entry["failures"].get(f, 0)) for f in REWARD_FAILURES], np.int64))
    return stats


def _check_codes(field: str, codes: np.ndarray, count: int) -> None:
  if codes.size and (codes.min() < 0 or codes.max() >= count):
    raise ValueError(f"rows field '{field}': expected codes in [0, {count}), got [{codes.min()}, {codes.max()}]")


def summarize_rows(rows: Mapping[str, np.ndarray], seconds: float | None = None) -> dict[str, Any]:
  """Plain-JSON summary of one set of rows (`RowStats.to_dict`)."""
  return RowStats().add(rows).to_dict(seconds)


def merge_summaries(a: Mapping[str, Any], b: Mapping[str, Any]) -> dict[str, Any]:
  """The summary of the rows of both summaries; ``seconds`` add up when both have them."""
  seconds = a["seconds"] + b["seconds"] if "seconds" in a and "seconds" in b else None
  return RowStats.from_dict(a).merge(RowStats.from_dict(b)).to_dict(seconds)


def _fmt(value: Any, digits: int = 3) -> str:
  if value is None:
    return "-"
  if isinstance(value, float):
    return f"{value:.{digits}f}"
  return str(value)


def format_summary(summary: Mapping[str, Any]) -> str:
  """A plain-text table of a summary for the terminal: one column per gripper plus the total."""
  names = list(summary["grippers"])
  entries = [summary["grippers"][n] for n in names]
  total = {"rows": summary["rows"], "positives": summary["positives"], "positive_rate": summary["positive_rate"]}
  for key in ("supervisor_rows", "supervisor_positives"):
    total[key] = sum(e.get(key, 0) for e in entries)
  weighted = sum((e["mean_robust_probability"] or 0.0) * e["rows"] for e in entries)
  total["mean_robust_probability"] = weighted / summary["rows"] if summary["rows"] else None
  total["failures"] = {f: sum(e["failures"].get(f, 0) for e in entries) for f in REWARD_FAILURES}
  columns = entries + [total]
  lines = [("", names + ["total"])]
  for key, label in (("rows", "rows"), ("positives", "positives"), ("positive_rate", "positive rate"),
                     ("supervisor_rows", "supervisor rows"), ("supervisor_positives", "supervisor positives"),
                     ("mean_robust_probability", "mean robust probability")):
    lines.append((label, [_fmt(c.get(key)) for c in columns]))
  for failure in REWARD_FAILURES[1:]:
    lines.append((f"failure: {failure}", [_fmt(c["failures"].get(failure, 0)) for c in columns]))
  label_width = max(len(label) for label, _ in lines)
  widths = [max(len(cells[i]) for _, cells in lines) for i in range(len(columns))]
  text = [label.ljust(label_width) + "".join("  " + c.rjust(w) for c, w in zip(cells, widths))
          for label, cells in lines]
  text.insert(1, "-" * len(text[0]))
  if "seconds" in summary:
    text.append(f"{summary['rows']} rows in {summary['seconds']:.1f} s ({_fmt(summary.get('rows_per_s'), 2)} rows/s)")
  return "\n".join(text)


def select_crop_rows(rows: Mapping[str, np.ndarray], image_index: int, num_crops: int) -> np.ndarray:
  """Up to ``num_crops`` row indices of image ``image_index``, deterministic and mixed: round-robin over the
  (gripper, reward) groups (parallel jaw 1, suction 1, parallel jaw 0, suction 0), supervisor rows first and
  then row order within a group."""
  index = np.flatnonzero(np.asarray(rows["image_index"]) == image_index)
  groups = []
  for reward in (1, 0):
    for code in range(len(GRIPPER_NAMES)):
      sel = index[(rows["gripper"][index] == code) & (rows["reward"][index] == reward)]
      order = np.lexsort((sel, rows["policy"][sel] != _SUPERVISOR))  # supervisor first, then row index
      groups.append(list(sel[order]))
  chosen: list[int] = []
  while len(chosen) < num_crops and any(groups):
    for group in groups:
      if group and len(chosen) < num_crops:
        chosen.append(int(group.pop(0)))
  return np.asarray(chosen, np.int64)


def grasp_crops(depth: np.ndarray, centers: np.ndarray, angles: np.ndarray, crop_size: int = 96) -> np.ndarray:
  """(K, crop_size, crop_size) float32 grasp-centred crops (metres) of a depth image (H, W) at ``centers`` (K, 2)
  (u, v) pixels and ``angles`` (K,) radians (`dexjax.sampling.grasp_crop`, one jit per crop size)."""
  if len(centers) == 0:
    return np.zeros((0, crop_size, crop_size), np.float32)
  return np.asarray(_crops(np.asarray(depth, np.float32), np.asarray(centers, np.float32),
                           np.asarray(angles, np.float32), crop_size))


def _pixel_sizes(rows: Mapping[str, np.ndarray], sel: np.ndarray, fx: float) -> np.ndarray:
  """(K,) jaw opening (parallel jaw) or cup radius (suction) of rows ``sel`` in pixels: fx x size / grasp depth."""
  size = np.where(rows["gripper"][sel] == 0, _JAW_WIDTH, _CUP_RADIUS)
  depth = np.asarray(rows["grasp_depth"][sel], np.float64)
  return fx * size / np.where(depth > 1e-6, depth, np.inf)


def _draw_grasp(axes, center, angle: float, approach_angle: float, gripper: int, size_px: float,
                colour: str, supervisor: bool) -> None:
  """One grasp at ``center`` (u, v) pixels: a jaw segment of ``size_px`` along (cos a, sin a), or a suction cup
  of radius ``size_px`` with a tick along the in-plane approach direction (-sin a, cos a)."""
  u, v = float(center[0]), float(center[1])
  width = 2.4 if supervisor else 1.2
  c, s = math.cos(angle), math.sin(angle)
  if gripper == 0:
    half = 0.5 * size_px
    axes.plot([u - half * c, u + half * c], [v - half * s, v + half * s], color=colour, lw=width,
              marker='|', markersize=4 + 2 * width, solid_capstyle='butt')
  else:
    axes.add_patch(Circle((u, v), max(size_px, 1.0), fill=False, edgecolor=colour, lw=width))
    tick = max(size_px, 1.0) * (1.0 + 2.0 * math.sin(approach_angle))
    axes.plot([u, u - tick * s], [v, v + tick * c], color=colour, lw=width)
  if supervisor:
    axes.plot([u], [v], marker='*', color=colour, markeredgecolor='black', markersize=9, markeredgewidth=0.5)


def generation_png_size(depth_shape: tuple[int, int], num_crops: int) -> tuple[int, int]:
  """(height, width) pixels of the `save_generation_png` figure for a depth image (H, W) and ``num_crops``."""
  height, width = depth_shape
  cols = max(1, math.ceil(math.sqrt(num_crops)))
  grid_rows = max(1, math.ceil(num_crops / cols))
  left = _PANEL_INCHES * width / height + 1.2   # depth panel plus colour bar
  right = _PANEL_INCHES * cols / grid_rows * 1.15 if num_crops > 0 else 0.0  # crops plus their titles
  return _FIGURE_HEIGHT_PX, int(round((left + right + 0.4) * _DPI))


def save_generation_png(path: str | os.PathLike[str], shard: Shard, image_index: int = 0, *, num_crops: int = 16,
                        crop_size: int = 96) -> np.ndarray:
  """Writes one image of a shard with its labelled grasps (left) and grasp-centred crops of them (right).

  Left: the depth image (grey, metres) with every row of the image drawn in green (reward 1) or red (reward 0):
  parallel jaw as a segment along the jaw axis, fx x 0.05 m / grasp_depth pixels long; suction as a cup circle
  (radius fx x 0.01 m / grasp_depth) with a tick along the in-plane approach direction; supervisor rows thicker
  and starred. Right: up to ``num_crops`` crops (`select_crop_rows`), ``crop_size`` pixels, each titled with
  gripper, reward and robust probability, the jaw axis (horizontal) or cup (approach tick down) at the centre.
  An image without rows is drawn without grasps and crops. The PNG is `generation_png_size` pixels, written
  atomically and marked as dexjax's picture (`dexjax.cli.is_dexjax_png`).

  Returns:
    (K,) int64 indices of the rows shown as crops.

  Raises:
    IndexError naming the shard file and field ``image_index`` when the image does not exist.
  """
  num_images = len(shard.images["depth"])
  if not 0 <= image_index < num_images:
    raise IndexError(f"shard '{shard.path}': field 'image_index': expected an image in [0, {num_images}), "
                     f"got {image_index}")
  rows = shard.rows
  depth = np.asarray(shard.images["depth"][image_index], np.float32)
  fx = float(shard.images["camera_intrinsics"][image_index][0])
  own = np.flatnonzero(np.asarray(rows["image_index"]) == image_index)
  chosen = select_crop_rows(rows, image_index, num_crops)
  fig_h, fig_w = generation_png_size(depth.shape, num_crops)
  figure = Figure(figsize=(fig_w / _DPI, fig_h / _DPI), dpi=_DPI)
  FigureCanvasAgg(figure)
  left_w = _PANEL_INCHES * depth.shape[1] / depth.shape[0] + 1.4
  left_fig, right_fig = figure.subfigures(1, 2, width_ratios=[left_w, max(fig_w / _DPI - left_w, 1e-3)])
  _draw_depth_panel(left_fig, depth, rows, own, fx)
  _draw_crop_grid(right_fig, depth, rows, chosen, fx, num_crops, crop_size)
  heap = int(shard.images["heap_id"][image_index])
  positives = int((rows["reward"][own] == 1).sum())
  figure.suptitle(f"{shard.path.name} image {image_index} (heap {heap}): {len(own)} grasps, {positives} positive",
                  fontsize=10)
  with atomic_path(path, suffix='.png') as tmp:  # marked as dexjax's picture, so a rerun may replace it
    figure.savefig(tmp, dpi=_DPI, format='png', metadata={PNG_MARK: 'dexjax.generate.save_generation_png'})
  return chosen


def _draw_depth_panel(sub, depth: np.ndarray, rows, own: np.ndarray, fx: float) -> None:
  axes = sub.subplots()
  cmap = matplotlib.colormaps['gray'].with_extremes(bad=_INVALID_COLOUR)
  shown = axes.imshow(np.ma.masked_invalid(depth), cmap=cmap, interpolation='nearest')
  sub.colorbar(shown, ax=axes, fraction=0.046, pad=0.02, label='depth (m)')
  sizes = _pixel_sizes(rows, own, fx)
  for i, size in zip(own, sizes):
    _draw_grasp(axes, rows["center"][i], float(rows["angle"][i]), float(rows["approach_angle"][i]),
                int(rows["gripper"][i]), float(size), _REWARD_COLOURS[int(rows["reward"][i] == 1)],
                int(rows["policy"][i]) == _SUPERVISOR)
  axes.set_xlim(-0.5, depth.shape[1] - 0.5)
  axes.set_ylim(depth.shape[0] - 0.5, -0.5)
  axes.set_title("green: reward 1, red: 0, star: supervisor" if len(own) else "no grasps on this image", fontsize=8)
  axes.set_axis_off()


def _draw_crop_grid(sub, depth: np.ndarray, rows, chosen: np.ndarray, fx: float, num_crops: int,
                    crop_size: int) -> None:
  if num_crops <= 0:
    return
  cols = max(1, math.ceil(math.sqrt(num_crops)))
  grid = sub.subplots(max(1, math.ceil(num_crops / cols)), cols, squeeze=False)
  crops = grasp_crops(depth, rows["center"][chosen], rows["angle"][chosen], crop_size)
  sizes = _pixel_sizes(rows, chosen, fx)
  finite = depth[np.isfinite(depth) & (depth > 0)]  # the depth panel's grey scale, for comparable crops
  low, high = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
  high = max(high, low + 1e-6)
  cmap = matplotlib.colormaps['gray'].with_extremes(bad=_INVALID_COLOUR)
  middle = crop_size // 2  # the grasp pixel (`dexjax.sampling.crop_coordinates`)
  for k, axes in enumerate(grid.ravel()):
    axes.set_axis_off()
    if k >= len(chosen):
      continue
    i = chosen[k]
    outside = ~np.isfinite(crops[k]) | (crops[k] <= 0)  # off the image (read as 0) or invalid
    axes.imshow(np.ma.masked_where(outside, crops[k]), cmap=cmap, vmin=low, vmax=high, interpolation='nearest')
    colour = _REWARD_COLOURS[int(rows["reward"][i] == 1)]
    # In the crop the image direction (cos a, sin a) is +column: draw with angle 0.
    _draw_grasp(axes, (middle, middle), 0.0, float(rows["approach_angle"][i]), int(rows["gripper"][i]),
                float(sizes[k]), colour, int(rows["policy"][i]) == _SUPERVISOR)
    axes.set_xlim(-0.5, crop_size - 0.5)
    axes.set_ylim(crop_size - 0.5, -0.5)
    name = _SHORT.get(GRIPPER_NAMES[int(rows["gripper"][i])], "?")
    axes.set_title(f"{name} r={int(rows['reward'][i])} p={float(rows['robust_probability'][i]):.2f}",
                   fontsize=7)
