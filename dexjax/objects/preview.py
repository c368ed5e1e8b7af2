"""Contact sheets of procedural objects: one row per difficulty level, rendered with matplotlib (Agg).

Faces are drawn as a `Poly3DCollection` with Lambert shading by face normal (a fixed light above and to the
side of the camera) and painter's-algorithm depth sorting, which is enough to read the shapes.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import matplotlib
import numpy as np
import trimesh
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from dexjax.objects.procedural import procedural_families
from dexjax.objects.procedural import procedural_mesh

_DPI = 100
_ELEVATION, _AZIMUTH = 25.0, -60.0  # Camera angles, degrees.
_AMBIENT = 0.3  # Shading = colour * (ambient + (1 - ambient) * max(0, n . light)).
_LEVEL_COLOURS = {1: (0.35, 0.55, 0.85), 2: (0.35, 0.75, 0.45), 3: (0.85, 0.45, 0.35)}


def save_contact_sheet(path: str | os.PathLike[str], *, levels: Sequence[int] = (1, 2, 3), per_level: int = 8,
                       seed: int = 0, cell_pixels: int = 200) -> None:
  """Renders objects 0 .. per_level-1 of each level into a PNG grid (one row per level).

  Args:
    path: output PNG file.
    levels: difficulty levels, one row each (1, 2 or 3).
    per_level: objects per row (indices 0 .. per_level-1, which cycle through the level's families).
    seed: object-set seed.
    cell_pixels: width and height of one cell, pixels; the image is (len(levels) * cell_pixels) rows by
      (per_level * cell_pixels) columns.

  Raises:
    ValueError: no levels, a level outside 1-3, or per_level / cell_pixels < 1.
  """
  levels = tuple(levels)
  if not levels:
    raise ValueError('save_contact_sheet: levels must name at least one level (1, 2 or 3)')
  if isinstance(per_level, bool) or not isinstance(per_level, int) or per_level < 1:
    raise ValueError(f'save_contact_sheet: per_level must be an integer >= 1, got {per_level!r}')
  if isinstance(cell_pixels, bool) or not isinstance(cell_pixels, int) or cell_pixels < 16:
    raise ValueError(f'save_contact_sheet: cell_pixels must be an integer >= 16, got {cell_pixels!r}')
  for level in levels:
    procedural_families(level)  # Raises ValueError naming a bad level.
  rows, cols = len(levels), per_level
  figure = Figure(figsize=(cols * cell_pixels / _DPI, rows * cell_pixels / _DPI), dpi=_DPI)
  FigureCanvasAgg(figure)
  for row, level in enumerate(levels):
    for col in range(cols):
      mesh = procedural_mesh(level, col, seed)
      axes = figure.add_axes((col / cols, 1.0 - (row + 1) / rows, 1.0 / cols, 1.0 / rows), projection='3d')
      _draw_mesh(axes, mesh, _LEVEL_COLOURS.get(level, (0.6, 0.6, 0.6)))
      label = f"{mesh.metadata['name'].split(':', 1)[1]} {mesh.metadata['family']}"
      axes.text2D(0.5, 0.97, label, transform=axes.transAxes, ha='center', va='top', fontsize=7)
  figure.savefig(os.fspath(path), dpi=_DPI, format='png')


def _light_direction(elevation: float, azimuth: float) -> np.ndarray:
  """(3,) unit light direction: towards a camera at (elevation, azimuth) degrees, raised and turned left."""
  elevation, azimuth = np.radians(elevation + 25.0), np.radians(azimuth - 30.0)
  return np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])


def shaded_colours(normals: np.ndarray, colours: np.ndarray | Sequence[float], *, elevation: float = _ELEVATION,
                   azimuth: float = _AZIMUTH) -> np.ndarray:
  """(F, 4) RGBA face colours with Lambert shading for a matplotlib camera at (elevation, azimuth) degrees.

  Args:
    normals: (F, 3) unit face normals, in the plotted frame.
    colours: (3,) or (F, 3) base RGB colours in [0, 1].
  """
  lambert = np.clip(np.asarray(normals) @ _light_direction(elevation, azimuth), 0.0, 1.0)
  rgb = np.broadcast_to(np.asarray(colours, np.float64), (len(lambert), 3))
  rgb = rgb * (_AMBIENT + (1.0 - _AMBIENT) * lambert)[:, None]
  return np.c_[np.clip(rgb, 0.0, 1.0), np.ones(len(rgb))]


def _draw_mesh(axes: matplotlib.axes.Axes, mesh: trimesh.Trimesh, colour: Sequence[float]) -> None:
  """Draws ``mesh`` shaded into 3-D ``axes`` with equal scales and no axis decorations."""
  triangles = np.asarray(mesh.vertices)[np.asarray(mesh.faces)]
  colours = shaded_colours(mesh.face_normals, colour)  # Edges in the face colour hide anti-aliasing seams.
  axes.add_collection3d(Poly3DCollection(triangles, facecolors=colours, edgecolors=colours, linewidths=0.2))
  half = 0.5 * float(np.max(mesh.extents))
  axes.set_xlim(-half, half)
  axes.set_ylim(-half, half)
  axes.set_zlim(-half, half)
  axes.set_box_aspect((1.0, 1.0, 1.0), zoom=1.25)
  axes.view_init(elev=_ELEVATION, azim=_AZIMUTH)
  axes.set_axis_off()
