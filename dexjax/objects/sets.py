"""Object sets: many objects from built-ins, procedural ranges, mesh files and folders, in one list.

A set is described by a list of *sources*, each one of:

* ``'builtin:NAME'`` (one built-in object) or ``'builtin:all'`` (every built-in object);
* ``'builtin:level1'``, ``'builtin:level2'``, ``'builtin:level3'``: the first `LEVEL_SET_SIZE` (100) procedural
  objects of that difficulty level (``'procedural:L{level}/0:100'``), the built-in object sets of dataset
  generation;
* ``'procedural:L{level}/{index}[@{seed}]'`` (one procedural object) or
  ``'procedural:L{level}/{start}:{stop}[@{seed}]'`` (objects start .. stop-1 of a level, Python slice
  semantics, e.g. ``'procedural:L2/0:1000'``);
* a mesh file (OBJ, STL, PLY, GLB, OFF) or a directory of them (see `load_mesh_folder`).

`load_object_set` resolves the sources into one `FolderReport`: every object that loaded, and every file
or spec that did not, with its reason; one bad source never stops the others. `prepare_object_set` then
builds (or loads from the on-disk cache) each object's `ObjectModel` and collision hulls, again moving
objects that fail into the rejections instead of raising. The result feeds the quality code (``.model``)
and the heap simulation (`dexjax.sim.heap_objects`).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Sequence
from typing import Any

from dexjax.geometry.mesh_io import MeshError
from dexjax.objects.builtin import BUILTIN_OBJECTS, BUILTIN_PREFIX, resolve_mesh
from dexjax.objects.folder import (FolderReport, LoadedObject, PreparedObject, Rejection, emit_warnings,
                                  load_mesh_folder)
from dexjax.objects.folder import load_file, prepare_object
from dexjax.objects.procedural import PROCEDURAL_LEVELS, PROCEDURAL_PREFIX, procedural_spec

#: Objects in each built-in level set ``'builtin:level{1,2,3}'``.
LEVEL_SET_SIZE = 100
_RANGE_PATTERN = re.compile(r'L([0-9])/(0|[1-9][0-9]*):(0|[1-9][0-9]*)(?:@(0|[1-9][0-9]*))?')


def expand_object_sources(sources: Iterable[str | os.PathLike[str]]) -> list[str]:
  """Expands ``'builtin:all'`` and procedural ranges into single object specs; paths pass unchanged.

  Args:
    sources: object sources (see the module docstring).

  Returns:
    The sources in order with each range replaced by its members (``'procedural:L1/0:3'`` becomes
    ``['procedural:L1/0', 'procedural:L1/1', 'procedural:L1/2']``).

  Raises:
    ValueError: a malformed procedural range (the message names the source and the expected form).
  """
  expanded = []
  for source in sources:
    source = os.fspath(source)
    if source == f'{BUILTIN_PREFIX}all':
      expanded.extend(f'{BUILTIN_PREFIX}{name}' for name in BUILTIN_OBJECTS)
    elif source in tuple(f'{BUILTIN_PREFIX}level{level}' for level in PROCEDURAL_LEVELS):
      expanded.extend(_procedural_range(f'{PROCEDURAL_PREFIX}L{source[-1]}/0:{LEVEL_SET_SIZE}'))
    elif source.startswith(PROCEDURAL_PREFIX) and ':' in source[len(PROCEDURAL_PREFIX):]:
      expanded.extend(_procedural_range(source))
    else:
      expanded.append(source)
  return expanded


def _procedural_range(source: str) -> list[str]:
  """The specs of a ``'procedural:L{level}/{start}:{stop}[@{seed}]'`` range."""
  match = _RANGE_PATTERN.fullmatch(source[len(PROCEDURAL_PREFIX):])
  if match is None or int(match.group(1)) not in PROCEDURAL_LEVELS or int(match.group(3)) < int(match.group(2)):
    raise ValueError(f"object source {source!r}: expected 'procedural:L{{level}}/{{start}}:{{stop}}[@{{seed}}]' "
                     "with level 1, 2 or 3 and integers 0 <= start <= stop (e.g. 'procedural:L2/0:1000')")
  level, start, stop, seed = int(match.group(1)), int(match.group(2)), int(match.group(3)), int(match.group(4) or 0)
  return [procedural_spec(level, index, seed) for index in range(start, stop)]


def load_object_set(sources: Iterable[str | os.PathLike[str]], *, scale: float = 1.0,
                    recursive: bool = False) -> FolderReport:
  """Loads every object named by ``sources`` (see the module docstring), never raising for one bad source.

  Args:
    sources: object sources; procedural ranges and ``'builtin:all'`` are expanded.
    scale: coordinate scale for mesh files and folders (e.g. 0.001 for millimetres); built-in and
      procedural objects are already in metres and are not scaled.
    recursive: also read the sub-directories of folders.

  Returns:
    A `FolderReport`: ``loaded`` in source order (a folder's files sorted by path), each named by its spec
    (built-in, procedural), its file stem (a file) or its path in the folder (a folder's file, prefixed by
    the folder's name); ``rejected`` lists each spec, file or folder entry that failed, with the reason. A
    name seen twice is rejected the second time (``'duplicate object name ...'``).

  Warns:
    ImperfectMeshWarning, ScaleWarning: recorded while loading a file (also kept in `LoadedObject.warnings`).

  Raises:
    ValueError: ``scale`` is not a finite number > 0, or a procedural range is malformed (a mistake in the
      set's description rather than in one object).
  """
  if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not (0 < scale < float('inf')):
    raise ValueError(f'load_object_set: scale: expected a finite number > 0, got {scale!r}')
  loaded: list[LoadedObject] = []
  rejected: list[Rejection] = []
  for source in expand_object_sources(sources):
    if source.startswith((BUILTIN_PREFIX, PROCEDURAL_PREFIX)):
      try:
        mesh, name = resolve_mesh(source)
      except (ValueError, MeshError) as e:
        rejected.append(Rejection(source, str(e)))
      else:
        loaded.append(LoadedObject(name=name, path=source, mesh=mesh))
    elif os.path.isdir(source):
      report = load_mesh_folder(source, scale=scale, recursive=recursive)
      folder = os.path.basename(os.path.normpath(source))
      loaded.extend(LoadedObject(name=f'{folder}/{o.name}', path=o.path, mesh=o.mesh, warnings=o.warnings)
                    for o in report.loaded)
      rejected.extend(Rejection(os.path.join(source, r.file), r.reason) for r in report.rejected)
    else:
      outcome = load_file(source, name=os.path.splitext(os.path.basename(source))[0], label=source, scale=scale)
      (loaded if isinstance(outcome, LoadedObject) else rejected).append(outcome)
  emit_warnings(loaded)
  return FolderReport(loaded=_unique(loaded, rejected), rejected=rejected)


def _unique(loaded: Sequence[LoadedObject], rejected: list[Rejection]) -> list[LoadedObject]:
  """Drops (and reports in ``rejected``) each object whose name was already taken."""
  seen: dict[str, str] = {}
  kept = []
  for o in loaded:
    if o.name in seen:
      rejected.append(Rejection(o.path, f'duplicate object name {o.name!r} (already used by {seen[o.name]}); '
                                        'expected each object once'))
      continue
    seen[o.name] = o.path
    kept.append(o)
  return kept


def prepare_object_set(loaded: FolderReport | Sequence[LoadedObject], *,
                       cache_dir: str | os.PathLike[str] | None = None, progress: bool = False,
                       **prepare_kwargs: Any) -> tuple[list[PreparedObject], list[Rejection]]:
  """Builds (or loads from the cache) every object's model and collision hulls; failures are reported.

  Args:
    loaded: a `FolderReport` (its rejections are carried over) or a sequence of `LoadedObject`.
    cache_dir: cache directory (default ``$DEXJAX_CACHE`` or ``~/.cache/dexjax/objects``).
    progress: show a progress bar (tqdm) on stderr.
    **prepare_kwargs: `prepare_object` arguments (grid_size, max_hulls, max_vertices, ...).

  Returns:
    (prepared, rejected): the objects that were prepared, in order, and the rejections (those of the
    report first, then each object whose preparation raised, with the exception's message).
  """
  items = list(loaded.loaded) if isinstance(loaded, FolderReport) else list(loaded)
  rejected = list(loaded.rejected) if isinstance(loaded, FolderReport) else []
  if progress:
    from tqdm import tqdm  # pylint: disable=g-import-not-at-top
    items = tqdm(items, desc='objects', unit='obj')
  prepared = []
  for o in items:
    try:
      prepared.append(prepare_object(o, cache_dir=cache_dir, **prepare_kwargs))
    except Exception as e:  # One object must never stop the set.
      rejected.append(Rejection(o.path, f'preparing {o.name!r} failed: {type(e).__name__}: {e}'))
  return prepared, rejected
