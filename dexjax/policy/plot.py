"""Pictures of a plan (matplotlib, Agg), as the seed's videos draw them: the depth image with the planned grasp
(a line between the jaws for the parallel jaw, a dot for suction) and, when the policy kept its samples, one panel
per round with the grasps it scored coloured by quality (red: 0, blue: 1; Movie S2's frames).
"""

from __future__ import annotations

import os

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure

from dexjax.cli import PNG_MARK, atomic_path
from dexjax.policy.scorers import PARALLEL_JAW

_QUALITY = matplotlib.colormaps['RdYlBu']  # red (Q = 0) to blue (Q = 1), as the seed's Movie S2
_PANEL = 3.2  # inches per panel


def _jaw_segments(center: np.ndarray, angle: np.ndarray, depth: np.ndarray, width: float, fx: float) -> np.ndarray:
  """(N, 2, 2) jaw endpoints (u, v) of parallel-jaw grasps: the opening in pixels at their depths."""
  half = 0.5 * fx * width / np.maximum(depth, 1e-6)
  offset = half[:, None] * np.stack([np.cos(angle), np.sin(angle)], axis=-1)
  return np.stack([center - offset, center + offset], axis=1)


def _draw_samples(axes, samples: dict[str, np.ndarray], gripper: str, width: float, fx: float) -> None:
  """Draws one round's valid samples of one gripper, coloured by quality (grey where it has none)."""
  valid = samples['valid']
  if not valid.any():
    return
  quality = samples['quality'][valid]
  colours = np.where(np.isfinite(quality)[:, None], _QUALITY(np.clip(np.nan_to_num(quality), 0, 1)),
                     (0.6, 0.6, 0.6, 1.0))
  center = samples['center'][valid]
  if gripper == PARALLEL_JAW:
    segments = _jaw_segments(center, samples['angle'][valid], samples['depth'][valid], width, fx)
    axes.add_collection(LineCollection(segments, colors=colours, linewidths=1.0, alpha=0.9))
  else:
    axes.scatter(center[:, 0], center[:, 1], s=9, c=colours, edgecolors='none')


def _draw_action(axes, action: dict, fx: float) -> None:
  """The planned grasp: a thick line with jaw ticks (parallel jaw) or a ringed dot (suction)."""
  center = np.asarray(action['pixel'], float)
  if action['gripper'] == PARALLEL_JAW:
    seg = _jaw_segments(center[None], np.array([action['angle']]), np.array([action['depth']]), action['width'], fx)[0]
    axes.plot(seg[:, 0], seg[:, 1], '-', color='lime', linewidth=3, solid_capstyle='butt')
    axes.plot(seg[:, 0], seg[:, 1], 'o', color='lime', markersize=5)
  else:
    axes.plot(center[0], center[1], 'o', color='lime', markersize=10, markeredgecolor='black', markeredgewidth=1.5)


def _rounds(samples: dict[str, np.ndarray]) -> list[dict[str, dict[str, np.ndarray]]]:
  """Per round, the samples of each gripper (samples stacked per gripper have a leading axis of 2)."""
  per_gripper = samples['valid'].ndim == 3
  rounds = samples['valid'].shape[1 if per_gripper else 0]
  out = []
  for r in range(rounds):
    if per_gripper:
      out.append({g: {k: v[i, r] for k, v in samples.items() if k != 'grippers'}
                  for i, g in enumerate(samples['grippers'])})
    else:
      out.append({samples['grippers'][0]: {k: v[r] for k, v in samples.items() if k != 'grippers'}})
  return out


def _view(mask: np.ndarray | None, plan: dict, shape: tuple[int, int], margin: int = 40):
  """((u0, u1), (v0, v1)) pixel window to show: the mask's (and the grasp's) bounding box with a margin, made
  square, or the whole image."""
  h, w = shape
  if mask is None or not mask.any():
    return (0, w), (0, h)
  rows, cols = np.nonzero(mask)
  us, vs = [cols.min(), cols.max()], [rows.min(), rows.max()]
  if plan.get('gripper') is not None:
    us.append(plan['pixel'][0])
    vs.append(plan['pixel'][1])
  half = max(max(us) - min(us), max(vs) - min(vs)) / 2 + margin
  cu, cv = (max(us) + min(us)) / 2, (max(vs) + min(vs)) / 2
  u0, v0 = int(max(0, cu - half)), int(max(0, cv - half))
  return (u0, int(min(w, cu + half))), (v0, int(min(h, cv + half)))


def save_plan_png(path: str | os.PathLike[str], depth: np.ndarray, plan: dict, fx: float,
                  samples: dict[str, np.ndarray] | None = None, mask: np.ndarray | None = None,
                  jaw_width: float = 0.05) -> None:
  """Writes the picture of a plan, atomically, marked as dexjax's (`dexjax.cli.is_dexjax_png`).

  Args:
    path: output PNG.
    depth: (H, W) depth image, metres (the planner's inpainted image).
    plan: the plan record of `dexjax.plan` (``gripper`` None when there is no grasp; ``pixel``, ``angle``,
      ``depth``, ``width``, ``probability``, ``policy``).
    fx: focal length, pixels (jaw opening in pixels).
    samples: optional samples as NumPy arrays: ``center`` (.., R, N, 2), ``angle``, ``depth``, ``quality``,
      ``valid`` (.., R, N), with ``grippers`` naming the leading axis when stacked per gripper (else one name).
    mask: optional (H, W) bool mask of where grasps may lie: outlined, and the view zooms to it.
    jaw_width: jaw opening of the sampled parallel-jaw grasps, metres.
  """
  rounds = _rounds(samples) if samples is not None else []
  panels = len(rounds) + 1
  h, w = depth.shape
  figure = Figure(figsize=(_PANEL * panels, _PANEL + 0.5), dpi=100)
  FigureCanvasAgg(figure)
  axes = np.atleast_1d(figure.subplots(1, panels))
  finite = depth[np.isfinite(depth)]
  low, high = (np.percentile(finite, [1, 99]) if finite.size else (0.0, 1.0))
  (u0, u1), (v0, v1) = _view(mask, plan, (h, w))
  for a in axes:
    a.imshow(depth, cmap='gray_r', vmin=low, vmax=high, interpolation='nearest')
    if mask is not None and mask.any():
      a.contour(mask.astype(float), levels=[0.5], colors='yellow', linewidths=0.5)
    a.set_xlim(u0 - 0.5, u1 - 0.5)
    a.set_ylim(v1 - 0.5, v0 - 0.5)
    a.set_axis_off()
  for r, (a, by_gripper) in enumerate(zip(axes, rounds)):
    counts = []
    for gripper, s in by_gripper.items():
      _draw_samples(a, s, gripper, jaw_width, fx)
      counts.append(f'{gripper.replace("parallel_jaw", "jaw")} {int(s["valid"].sum())}')
    a.set_title(('candidates' if r == 0 else f'CEM iteration {r}') + ': ' + ', '.join(counts), fontsize=8)
  final = axes[-1]
  if plan.get('gripper') is not None:
    _draw_action(final, plan, fx)
    final.set_title(f"{plan['policy']}: {plan['gripper']}, Q = {plan['probability']:.3f}", fontsize=9)
  else:
    final.set_title(f"{plan['policy']}: no grasp", fontsize=9)
  if rounds:
    bar = figure.colorbar(matplotlib.cm.ScalarMappable(norm=matplotlib.colors.Normalize(0, 1), cmap=_QUALITY),
                          ax=list(axes), fraction=0.015, pad=0.01)
    bar.set_label('predicted quality', fontsize=8)
  with atomic_path(path, suffix='.png') as tmp:
    figure.savefig(tmp, format='png', metadata={PNG_MARK: 'dexjax.policy.save_plan_png'})


__all__ = ['save_plan_png']
