"""Object sets: many objects from built-ins, procedural ranges, mesh files and folders, in one list.

A set is described by a list of *sources*, each one of:

* ``'builtin:NAME'`` (one built-in object) or ``'builtin:all'`` (every built-in object);
* ``'builtin:level1'``, ``'builtin:level2'``, ``'builtin:level3'``: the first `LEVEL_SET_SIZE` (100) procedural
  objects of that difficulty level (``'procedural:L{level}/0:100'``), the built-in object sets of dataset
  generation;
* ``'procedural:L{level}/{index}[@{seed}]'`` (one procedural object) or
  ``'procedural:L{level}/{start}:{stop}[@{seed}]'`` (objects start .. stop-1 of a level, Python slice
  semantics, e.g. ``'procedural:L2/0:1000'``; at most `MAX_RANGE_COUNT` (100,000) objects per range and in
  the whole expanded set, checked before any spec is listed);
* a mesh file (OBJ, STL, PLY, GLB, OFF) or a directory of them (see `load_mesh_folder`).

`load_object_set` resolves the sources into one `FolderReport`: every object that loaded, and every file
or spec that did not, with its reason; one bad source never stops the others. `prepare_object_set` then
builds (or loads from the on-disk cache) each object's `ObjectModel` and collision hulls, again moving
objects that fail into the rejections instead of raising. `usable_objects` does both for a config's ``objects``
section and refuses a set of which no object could be used (`NoObjectsError`). The result feeds the quality code
(``.model``) and the heap simulation (`dexjax.sim.heap_objects`).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Sequence
from typing import Any

from dexjax.geometry.mesh_io import MeshError
from dexjax.objects.builtin import BUILTIN_OBJECTS, BUILTIN_PREFIX, mesh_path_problem, resolve_mesh
from dexjax.objects.folder import (FolderReport, LoadedObject, PreparedObject, Rejection, emit_warnings,
                                  load_mesh_folder)
from dexjax.objects.folder import load_file, prepare_object
from dexjax.objects.procedural import (MAX_RANGE_COUNT, PROCEDURAL_LEVELS, PROCEDURAL_PREFIX, procedural_spec,
                                      spec_integers)

#: Objects in each built-in level set ``'builtin:level{1,2,3}'``.
LEVEL_SET_SIZE = 100
#: The ``builtin:`` sources that name a set of objects rather than one object.
BUILTIN_SETS: tuple[str, ...] = (f'{BUILTIN_PREFIX}all',
                                 *(f'{BUILTIN_PREFIX}level{level}' for level in PROCEDURAL_LEVELS))
_RANGE_PATTERN = re.compile(r'L([0-9])/(0|[1-9][0-9]*):(0|[1-9][0-9]*)(?:@(0|[1-9][0-9]*))?')


def expand_object_sources(sources: Iterable[str | os.PathLike[str]]) -> list[str]:
  """Expands ``'builtin:all'`` and procedural ranges into single object specs; paths pass unchanged.

  Args:
    sources: object sources (see the module docstring).

  Returns:
    The sources in order with each range replaced by its members (``'procedural:L1/0:3'`` becomes
    ``['procedural:L1/0', 'procedural:L1/1', 'procedural:L1/2']``).

  Raises:
    ValueError: a malformed procedural range, or one (or the whole expanded set) of more than `MAX_RANGE_COUNT`
      objects (the message names the source and the expected form or the limit; checked before listing).
  """
  expanded = []
  for source in sources:
    source = os.fspath(source)
    if source == BUILTIN_SETS[0]:
      members = [f'{BUILTIN_PREFIX}{name}' for name in BUILTIN_OBJECTS]
    elif source in BUILTIN_SETS:
      members = _procedural_range(f'{PROCEDURAL_PREFIX}L{source[-1]}/0:{LEVEL_SET_SIZE}', len(expanded))
    elif source.startswith(PROCEDURAL_PREFIX) and ':' in source[len(PROCEDURAL_PREFIX):]:
      members = _procedural_range(source, len(expanded))
    else:
      members = [source]
    _check_count(source, len(members), len(expanded))  # ranges were checked before their specs were listed
    expanded.extend(members)
  return expanded


def _procedural_range(source: str, listed: int = 0) -> list[str]:
  """The specs of a ``'procedural:L{level}/{start}:{stop}[@{seed}]'`` range, after ``listed`` objects of the set;
  its size is checked against `MAX_RANGE_COUNT` before any spec is made."""
  match = _RANGE_PATTERN.fullmatch(source[len(PROCEDURAL_PREFIX):])
  numbers = spec_integers(match.groups()) if match is not None else None
  if numbers is None or numbers[0] not in PROCEDURAL_LEVELS or numbers[2] < numbers[1]:
    raise ValueError(f"object source {_shown(source)!r}: expected "
                     "'procedural:L{level}/{start}:{stop}[@{seed}]' with level 1, 2 or 3 and integers "
                     "0 <= start <= stop (e.g. 'procedural:L2/0:1000')")
  level, start, stop, seed = numbers
  _check_count(source, stop - start, listed)
  return [procedural_spec(level, index, seed or 0) for index in range(start, stop)]


def _check_count(source: str, count: int, listed: int) -> None:
  """Refuses a source of ``count`` objects, or one that would grow the set past `MAX_RANGE_COUNT`."""
  if count > MAX_RANGE_COUNT:
    shown = f'{count}' if count < 10**15 else f'about 10^{len(str(count)) - 1}'
    raise ValueError(f'object source {_shown(source)!r}: names {shown} objects; expected at most {MAX_RANGE_COUNT} '
                     'per range (MAX_RANGE_COUNT; split the work into several runs)')
  if listed + count > MAX_RANGE_COUNT:
    raise ValueError(f'object source {_shown(source)!r}: brings the set to {listed + count} objects; expected at '
                     f'most {MAX_RANGE_COUNT} in one set (MAX_RANGE_COUNT; split the work into several runs)')


def _shown(source: str) -> str:
  """``source`` for a message: cut to its first 150 characters (and its length) when longer than 200."""
  return source if len(source) <= 200 else f'{source[:150]}...({len(source)} characters)'


def check_object_sources(sources: Iterable[str | os.PathLike[str]]) -> list[str]:
  """Checks, before any object is built, what can be checked of a set's sources; returns them expanded.

  Procedural ranges must be well formed and of at most `MAX_RANGE_COUNT` objects (`expand_object_sources`), and
  every source that is not a ``builtin:`` or ``procedural:`` spec must be an existing mesh file or folder.
  (Unknown built-in names and broken files are left to `load_object_set`, which rejects them one by one.)

  Raises:
    ValueError: naming the source and what is wrong (``does not exist``, ``is not a regular file``, ...).
  """
  expanded = expand_object_sources(sources)
  for source in expanded:
    if not source.startswith((BUILTIN_PREFIX, PROCEDURAL_PREFIX)):
      problem = mesh_path_problem(source, folder_ok=True)
      if problem is not None:
        raise ValueError(f'object source {_shown(source)!r}: {problem}')
  return expanded


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
    ValueError: ``scale`` is not a finite number > 0, or a procedural range is malformed or names more than
      `MAX_RANGE_COUNT` objects (a mistake in the set's description rather than in one object). A path that does
      not exist or is not a regular file or folder is rejected (``'file not found: ... does not exist'``); see
      `check_object_sources` to refuse it instead.
  """
  if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not (0 < scale < float('inf')):
    raise ValueError(f'load_object_set: scale: expected a finite number > 0, got {scale!r}')
  loaded: list[LoadedObject] = []
  rejected: list[Rejection] = []
  for source in expand_object_sources(sources):
    objects, problems = _load_source(source, scale=scale, recursive=recursive)
    loaded.extend(objects)
    rejected.extend(problems)
  emit_warnings(loaded)
  return FolderReport(loaded=_unique(loaded, rejected), rejected=rejected)


def _load_source(source: str, *, scale: float, recursive: bool) -> tuple[list[LoadedObject], list[Rejection]]:
  """(loaded, rejected) of one expanded source: a built-in or procedural spec, a mesh file or a folder."""
  if source.startswith((BUILTIN_PREFIX, PROCEDURAL_PREFIX)):
    try:
      mesh, name = resolve_mesh(source)
    except (ValueError, MeshError) as e:
      return [], [Rejection(source, _spec_reason(source, e))]
    return [LoadedObject(name=name, path=source, mesh=mesh)], []
  problem = mesh_path_problem(source, folder_ok=True)
  if problem is not None:
    return [], [Rejection(source, problem)]
  if os.path.isdir(source):
    report = load_mesh_folder(source, scale=scale, recursive=recursive)
    folder = os.path.basename(os.path.normpath(source))
    return ([LoadedObject(name=f'{folder}/{o.name}', path=o.path, mesh=o.mesh, warnings=o.warnings)
             for o in report.loaded],
            [Rejection(os.path.join(source, r.file), r.reason) for r in report.rejected])
  outcome = load_file(source, name=os.path.splitext(os.path.basename(source))[0], label=source, scale=scale)
  return ([outcome], []) if isinstance(outcome, LoadedObject) else ([], [outcome])


def _spec_reason(source: str, error: Exception) -> str:
  """Why a spec was rejected; for an unknown ``builtin:`` name, the set names are listed with the objects."""
  if source.startswith(BUILTIN_PREFIX) and source[len(BUILTIN_PREFIX):] not in BUILTIN_OBJECTS:
    return f'{error}; or a set: {", ".join(BUILTIN_SETS)}'
  return str(error)


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


class NoObjectsError(ValueError):
  """No object of the run's sources could be loaded and prepared; the message lists the rejections."""


def usable_objects(config: Any, cache_dir: str | os.PathLike[str] | None = None, progress: bool = False
                   ) -> tuple[list[PreparedObject], list[Rejection]]:
  """(prepared objects, rejections) of a config's object sources (`load_object_set`, then `prepare_object_set`).

  Args:
    config: a config with an ``objects`` section of ``sources``, ``scale`` and ``grid_size``
      (`dexjax.generate.GenerateConfig`, whose section is `dexjax.generate.ObjectsConfig`).
    cache_dir: object cache directory (`prepare_object_set`).
    progress: show a progress bar (tqdm) on stderr.

  Raises:
    NoObjectsError: no object could be used; the message lists each rejected file and its reason.
  """
  report = load_object_set(config.objects.sources, scale=config.objects.scale)
  prepared, rejected = prepare_object_set(report, cache_dir=cache_dir, progress=progress,
                                          grid_size=config.objects.grid_size)
  if not prepared:
    reasons = '; '.join(f'{r.file}: {r.reason}' for r in rejected) or 'no sources'
    raise NoObjectsError(f'objects.sources {list(config.objects.sources)}: no object could be used ({reasons})')
  return prepared, rejected


__all__ = ['BUILTIN_SETS', 'LEVEL_SET_SIZE', 'NoObjectsError', 'check_object_sources', 'expand_object_sources',
           'load_object_set', 'prepare_object_set', 'usable_objects']
