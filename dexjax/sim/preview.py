"""Pictures of settled heaps: posed meshes drawn in the bin with matplotlib (Agg), one row per object set.

`posed_meshes` places a heap's meshes at their settled poses (world frame); `save_heap_sheet` draws rows of
heaps into a PNG; `procedural_heap_rows` builds such rows from the procedural difficulty levels (objects,
cached convex decompositions, sampled states, settling). All faces of a heap go into one
`Poly3DCollection`, so matplotlib's painter's algorithm sorts them across objects; the bin floor is drawn
underneath and the walls as outlines. This is a picture for people, not the depth renderer.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence

import jax
import matplotlib
import numpy as np
import trimesh
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from dexjax.objects.preview import shaded_colours
from dexjax.objects.sets import load_object_set, prepare_object_set
from dexjax.sim.bodies import heap_objects
from dexjax.sim.heap import Bin, HeapDistribution, sample_heap_states
from dexjax.sim.scene import SettleSettings, quat_to_matrix
from dexjax.sim.settling import SettleResult, settle

_DPI = 100
_ELEVATION, _AZIMUTH = 50.0, -60.0  # Camera angles, degrees.
_PALETTE = tuple(c for i, c in enumerate(matplotlib.colormaps['tab10'].colors) if i != 3)  # red: flagged


@dataclasses.dataclass(frozen=True, eq=False)
class HeapRow:
  """One row of a heap sheet: B settled heaps of one object set.

  Attributes:
    label: row title, e.g. ``'level 2'``.
    meshes: the N available meshes in their object frames, metres (``object_ids`` index into them).
    object_ids: (B, P) int object ids per heap slot (-1 in padded slots), as in `HeapState.object_ids`.
    result: the `SettleResult` of those B heaps.
  """
  label: str
  meshes: Sequence[trimesh.Trimesh]
  object_ids: np.ndarray
  result: SettleResult


def posed_meshes(meshes: Sequence[trimesh.Trimesh], object_ids: np.ndarray, poses: np.ndarray,
                 mask: np.ndarray) -> list[tuple[int, trimesh.Trimesh]]:
  """One heap's meshes moved to their poses.

  Args:
    meshes: the N available meshes, object frames, metres.
    object_ids: (P,) ids into ``meshes`` per slot.
    poses: (P, 7) object-frame poses in the world frame: position (metres), quaternion (w, x, y, z).
    mask: (P,) bool, the heap's slots.

  Returns:
    [(slot, world-frame mesh)] for the heap's slots, in slot order.
  """
  placed = []
  for slot in np.flatnonzero(np.asarray(mask, bool)):
    transform = np.eye(4)
    transform[:3, :3] = quat_to_matrix(np.asarray(poses[slot], np.float64)[3:])
    transform[:3, 3] = poses[slot][:3]
    placed.append((int(slot), meshes[int(object_ids[slot])].copy().apply_transform(transform)))
  return placed


def _draw_bin(axes: matplotlib.axes.Axes, b: Bin) -> None:
  """The bin floor as a grey square and the walls' inner edges as lines."""
  hx, hy, h = 0.5 * b.inner_size[0], 0.5 * b.inner_size[1], b.wall_height
  corners = np.array([[-hx, -hy, 0.0], [hx, -hy, 0.0], [hx, hy, 0.0], [-hx, hy, 0.0]])
  axes.add_collection3d(Poly3DCollection([corners], facecolors=[(0.85, 0.85, 0.85, 1.0)], edgecolors='none'))
  top = corners + np.array([0.0, 0.0, h])
  for ring in (corners, top):
    closed = np.vstack([ring, ring[:1]])
    axes.plot(closed[:, 0], closed[:, 1], closed[:, 2], color='0.4', linewidth=0.8)
  for lo, hi in zip(corners, top):
    axes.plot(*np.stack([lo, hi]).T, color='0.4', linewidth=0.8)


def _draw_heap(axes: matplotlib.axes.Axes, placed: list[tuple[int, trimesh.Trimesh]], b: Bin,
               flagged: np.ndarray) -> None:
  """Draws the bin and the posed meshes; flagged slots (left the bin, never settled) are drawn in red."""
  axes.computed_zorder = False  # The floor first, then every face of the heap sorted together.
  _draw_bin(axes, b)
  if placed:
    triangles = np.concatenate([np.asarray(m.vertices)[np.asarray(m.faces)] for _, m in placed])
    normals = np.concatenate([m.face_normals for _, m in placed])
    base = np.concatenate([np.tile((1.0, 0.0, 0.0) if flagged[slot] else _PALETTE[slot % len(_PALETTE)],
                                   (len(m.faces), 1)) for slot, m in placed])
    colours = shaded_colours(normals, base, elevation=_ELEVATION, azimuth=_AZIMUTH)
    axes.add_collection3d(Poly3DCollection(triangles, facecolors=colours, edgecolors=colours, linewidths=0.2))
  half = 0.5 * max(b.inner_size) + b.wall_thickness
  axes.set_xlim(-half, half)
  axes.set_ylim(-half, half)
  axes.set_zlim(0.0, b.wall_height + 0.05)
  axes.set_box_aspect((2 * half, 2 * half, b.wall_height + 0.05), zoom=1.05)
  axes.view_init(elev=_ELEVATION, azim=_AZIMUTH)
  axes.set_axis_off()


def save_heap_sheet(path: str | os.PathLike[str], rows: Sequence[HeapRow], *, bin: Bin = Bin(),  # pylint: disable=redefined-builtin
                    cell_pixels: int = 300) -> None:
  """Draws every heap of every row into a PNG grid (rows by the largest number of heaps in a row).

  Each cell is titled with the heap's object count and steps; objects that left the bin or never settled
  are drawn in red.

  Raises:
    ValueError: no rows, or ``cell_pixels`` < 16.
  """
  if not rows:
    raise ValueError('save_heap_sheet: rows: expected at least one row of heaps')
  if isinstance(cell_pixels, bool) or not isinstance(cell_pixels, int) or cell_pixels < 16:
    raise ValueError(f'save_heap_sheet: cell_pixels must be an integer >= 16, got {cell_pixels!r}')
  cols = max(len(row.result.steps) for row in rows)
  figure = Figure(figsize=(cols * cell_pixels / _DPI, len(rows) * cell_pixels / _DPI), dpi=_DPI)
  FigureCanvasAgg(figure)
  for r, row in enumerate(rows):
    res = row.result
    for b in range(len(res.steps)):
      axes = figure.add_axes((b / cols, 1.0 - (r + 1) / len(rows), 1.0 / cols, 1.0 / len(rows)), projection='3d')
      placed = posed_meshes(row.meshes, np.asarray(row.object_ids[b]), res.poses[b], res.mask[b])
      _draw_heap(axes, placed, bin, res.left_bin[b] | res.never_settled[b])
      title = f'{row.label}: {int(res.mask[b].sum())} objects, {int(res.steps[b])} steps'
      axes.text2D(0.5, 0.97, title, transform=axes.transAxes, ha='center', va='top', fontsize=8)
  figure.savefig(os.fspath(path), dpi=_DPI, format='png')


def procedural_heap_rows(*, levels: Sequence[int] = (1, 2, 3), heaps_per_level: int = 3, pool: int = 12,
                         seed: int = 0, backend: str = 'auto', settings: SettleSettings = SettleSettings(),
                         distribution: HeapDistribution = HeapDistribution(),
                         cache_dir: str | os.PathLike[str] | None = None) -> list[HeapRow]:
  """Settles ``heaps_per_level`` heaps per difficulty level, drawn from that level's first ``pool`` objects.

  Objects are ``'procedural:L{level}/0:{pool}@{seed}'``; their collision hulls come from the cache
  (`dexjax.objects.prepare_object_set` with ``model=False``), so only the first call pays for the convex
  decompositions. Heap states use key ``jax.random.key(seed + level)``.

  Raises:
    ValueError: ``pool`` smaller than ``distribution.min_count``, a bad level, or ``heaps_per_level`` < 1.
    RuntimeError: an object could not be prepared.
  """
  if isinstance(heaps_per_level, bool) or not isinstance(heaps_per_level, int) or heaps_per_level < 1:
    raise ValueError(f'procedural_heap_rows: heaps_per_level must be an integer >= 1, got {heaps_per_level!r}')
  rows = []
  for level in levels:
    prepared, rejected = prepare_object_set(load_object_set([f'procedural:L{level}/0:{pool}@{seed}']),
                                            cache_dir=cache_dir, model=False)
    if rejected:
      raise RuntimeError(f'procedural_heap_rows: level {level}: {"; ".join(map(str, rejected))}')
    states = sample_heap_states(jax.random.key(seed + level), heaps_per_level, len(prepared), distribution)
    result = settle(heap_objects(prepared), states, backend=backend, settings=settings)
    rows.append(HeapRow(label=f'level {level}', meshes=[p.mesh for p in prepared],
                        object_ids=np.asarray(states.object_ids), result=result))
  return rows
