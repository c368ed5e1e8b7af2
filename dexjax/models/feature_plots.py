"""Figures of the seed's Fig. S1 from `dexjax.models.feature_analysis`: first-layer filters (A), the crops that
most excite the last convolution's channels (B), and t-SNE embeddings of every layer coloured by label (C).

Each function draws into a new matplotlib `Figure` (no pyplot state) and returns it (``fig.savefig(path)``; a
notebook shows it when it is a cell's value)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from matplotlib.figure import Figure


def _grid(n: int, columns: int | None = None) -> tuple[int, int]:
  columns = columns or math.ceil(math.sqrt(n))
  return math.ceil(n / columns), columns


def plot_filters(filters: np.ndarray, title: str = '') -> Figure:
  """(A) One panel per filter of (C, k, k) first-layer weights, each on its own symmetric colour scale."""
  rows, cols = _grid(len(filters))
  fig = Figure(figsize=(1.2 * cols, 1.2 * rows + 0.4))
  axes = fig.subplots(rows, cols, squeeze=False)
  for ax in axes.ravel():
    ax.axis('off')
  for ax, f in zip(axes.ravel(), filters):
    v = float(np.abs(f).max()) or 1.0
    ax.imshow(f, cmap='RdBu_r', vmin=-v, vmax=v, interpolation='nearest')
  fig.suptitle(title or f'first-layer filters ({filters.shape[1]} x {filters.shape[2]})')
  fig.tight_layout()
  return fig


def plot_top_activating(crops: np.ndarray, indices: np.ndarray, labels: np.ndarray | None = None,
                        channels: int | None = None, title: str = '') -> Figure:
  """(B) Row c: the crops (B, S, S[, 1]) at ``indices[c]`` (C, k) from `feature_analysis.top_activating`, each
  on its own depth scale; with ``labels`` (B,), a green (success) or red (failure) frame."""
  indices = indices[:channels] if channels else indices
  rows, cols = indices.shape
  fig = Figure(figsize=(1.0 * cols, 1.0 * rows + 0.4))
  axes = fig.subplots(rows, cols, squeeze=False)
  for c in range(rows):
    for j in range(cols):
      ax, crop = axes[c, j], np.asarray(crops[indices[c, j]]).squeeze()
      ax.imshow(crop, cmap='viridis_r')
      ax.set_xticks([])
      ax.set_yticks([])
      if labels is not None:
        colour = 'tab:green' if labels[indices[c, j]] else 'tab:red'
        for spine in ax.spines.values():
          spine.set_edgecolor(colour)
          spine.set_linewidth(2)
      if j == 0:
        ax.set_ylabel(f'ch {c}', fontsize=7)
  fig.suptitle(title or 'crops that most activate each channel of the last convolution')
  fig.tight_layout()
  return fig


def plot_embeddings(layers: Mapping[str, Mapping[str, Any]], labels: np.ndarray, title: str = '') -> Figure:
  """(C) One panel per layer of `feature_analysis.analyse_layers`: the 2-D t-SNE embedding, negatives grey,
  positives on top in colour, the layer's separation score in its title."""
  names = list(layers)
  rows, cols = _grid(len(names), min(4, len(names)))
  fig = Figure(figsize=(3.0 * cols, 3.0 * rows + 0.4))
  axes = fig.subplots(rows, cols, squeeze=False)
  for ax in axes.ravel():
    ax.axis('off')
  labels = np.asarray(labels).astype(bool)
  for ax, name in zip(axes.ravel(), names):
    emb = np.asarray(layers[name]['embedding'])
    ax.scatter(*emb[~labels].T, s=4, c='0.7', label='failure')
    ax.scatter(*emb[labels].T, s=6, c='tab:green', label='success')
    ax.set_title(f"{name}: {layers[name]['separation']:.2f}", fontsize=9)
  axes.ravel()[0].legend(loc='best', fontsize=7, markerscale=2)
  fig.suptitle(title or 't-SNE of each layer (title: k-NN balanced accuracy in the embedding)')
  fig.tight_layout()
  return fig


__all__ = ['plot_embeddings', 'plot_filters', 'plot_top_activating']
