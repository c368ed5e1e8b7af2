"""A PNG of a rendered view: the depth image (metres, colour bar) beside its segmentation mask (matplotlib, Agg)."""

from __future__ import annotations

import os

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from dexjax.cli import PNG_MARK, atomic_path
from dexjax.render.rendering import BIN_LABEL, INVALID_LABEL, DepthImage

_DPI = 100


def mask_colours(mask: np.ndarray) -> np.ndarray:
  """(H, W, 3) float RGB of a slot mask: a tab10 colour per slot, light grey bin, black invalid pixels."""
  palette = np.asarray(matplotlib.colormaps['tab10'].colors)
  rgb = palette[np.clip(mask, 0, None) % len(palette)]
  rgb[mask == BIN_LABEL] = 0.85
  rgb[mask == INVALID_LABEL] = 0.0
  return rgb


def save_depth_png(path: str | os.PathLike[str], image: DepthImage, *, title: str | None = None) -> None:
  """Writes the depth image (viridis, NaN pixels red, colour bar in metres) and the mask side by side, marked
  as dexjax's picture (`dexjax.cli.is_dexjax_png`), atomically.

  Args:
    path: output PNG file.
    image: a `DepthImage` (depth (H, W) float32 metres, mask (H, W) int32).
    title: optional figure title.
  """
  height, width = image.depth.shape
  figure = Figure(figsize=(2 * width / _DPI + 1.2, height / _DPI + 0.6), dpi=_DPI)
  FigureCanvasAgg(figure)
  left, right = figure.subplots(1, 2)
  cmap = matplotlib.colormaps['viridis'].with_extremes(bad='red')
  shown = left.imshow(np.ma.masked_invalid(image.depth), cmap=cmap, interpolation='nearest')
  figure.colorbar(shown, ax=left, fraction=0.046, pad=0.02, label='depth (m)')
  left.set_title(f'depth ({image.backend})', fontsize=9)
  right.imshow(mask_colours(image.mask), interpolation='nearest')
  slots = sorted(int(s) for s in np.unique(image.mask) if s >= 0)
  right.set_title(f'mask: {len(slots)} objects', fontsize=9)
  for axes in (left, right):
    axes.set_axis_off()
  if title:
    figure.suptitle(title, fontsize=10)
  with atomic_path(path, suffix='.png') as tmp:
    figure.savefig(tmp, dpi=_DPI, format='png', metadata={PNG_MARK: 'dexjax.render.save_depth_png'})


