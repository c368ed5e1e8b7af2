"""Your own objects: load a folder of mesh files, report what was rejected and why, prepare the rest.

`load_mesh_folder` reads every mesh file in a directory (optionally its sub-directories) with
`dexjax.geometry.load_mesh`, which repairs what it can (merged vertices, consistent winding, holes of up
to `MAX_HOLE_EDGES` edges, overlapping parts unioned, GLB / multi-object scenes flattened with their node
transforms) and refuses the rest with a `MeshError`. One bad file never stops the others: each file ends
up either in `FolderReport.loaded` or in `FolderReport.rejected` with the reason in words.

`prepare_object` turns a loaded object into what the rest of dexjax uses: its `ObjectModel` (signed
distance grid, surface samples, mass properties) and its convex collision hulls, both cached on disk under
``$DEXJAX_CACHE`` keyed by the repaired mesh's content (a deterministic function of the file's bytes and
the scale) and the build parameters, so a second run over the same folder loads instead of rebuilding and
an edited file gets a new entry.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from typing import Any

import numpy as np
import trimesh

from dexjax.geometry.cache import cached_object_model
from dexjax.geometry.mesh_io import SUPPORTED_EXTENSIONS, ImperfectMeshWarning, MeshError, ScaleWarning, load_mesh
from dexjax.geometry.object_model import ObjectModel
from dexjax.objects.collision import CONVEX_SOLIDITY, cached_collision_hulls

COMPANION_EXTENSIONS: tuple[str, ...] = ('.mtl', '.png', '.jpg', '.jpeg')
"""Extensions of files that accompany meshes (OBJ material libraries, textures); skipped silently."""


@dataclasses.dataclass(frozen=True, eq=False)
class LoadedObject:
  """A mesh file that loaded and was repaired into a closed solid.

  Attributes:
    name: the file's path relative to the folder, POSIX separators, without its extension (with it when
      two files differ only by extension), e.g. ``'mug'`` or ``'kitchen/mug'``.
    path: the file's path (the folder joined with the relative path).
    mesh: the repaired, watertight, outward-oriented mesh in metres (after scaling).
    warnings: what loading warned about (warning instances; ``str()`` gives the message, which names the
      file): an imperfect mesh loaded as the solid its winding number encloses
      (`dexjax.geometry.ImperfectMeshWarning`), an implausible size (`dexjax.geometry.ScaleWarning`).
  """
  name: str
  path: str
  mesh: trimesh.Trimesh
  warnings: tuple[Warning, ...] = ()


@dataclasses.dataclass(frozen=True)
class Rejection:
  """A file that was not loaded.

  Attributes:
    file: what was not loaded. From `load_mesh_folder`: the file's path relative to the folder, POSIX
      separators, e.g. ``'broken.stl'``; from `dexjax.objects.load_object_set`, which merges several sources: the
      source spec itself, or a folder's file joined to the folder as given (``'my_objects/broken.stl'``), or the
      object's path, so that every entry names its file unambiguously.
    reason: what is wrong, in words, e.g. ``'empty file (0 bytes); expected a triangle mesh'``.
  """
  file: str
  reason: str

  def __str__(self) -> str:
    return f'{self.file}: {self.reason}'


@dataclasses.dataclass(frozen=True, eq=False)
class FolderReport:
  """Result of `load_mesh_folder`: every candidate file is in exactly one list, both sorted by path.

  Attributes:
    loaded: objects that loaded.
    rejected: files that did not, each with its reason.
  """
  loaded: list[LoadedObject]
  rejected: list[Rejection]

  def to_json(self) -> dict[str, Any]:
    """``{"loaded": [names], "rejected": [{"file": file, "reason": reason}], "warnings": [{"name": name,
    "warning": text}]}``."""
    return {'loaded': [o.name for o in self.loaded],
            'rejected': [{'file': r.file, 'reason': r.reason} for r in self.rejected],
            'warnings': [{'name': o.name, 'warning': str(w)} for o in self.loaded for w in o.warnings]}


@dataclasses.dataclass(frozen=True, eq=False)
class PreparedObject:
  """A loaded object with its (cached) simulation and quality geometry.

  Attributes:
    name: the object's name (see `LoadedObject.name`).
    source: the mesh file it came from.
    mesh: the repaired mesh in metres.
    model: its `ObjectModel` (signed distance grid, surface samples, mass properties); None when prepared
      with ``model=False`` (collision geometry only, e.g. for settling heaps).
    hulls: convex collision pieces, each (V_i, 3) float64 vertices in metres (see
      `dexjax.objects.collision_hulls`).
  """
  name: str
  source: str
  mesh: trimesh.Trimesh
  model: ObjectModel | None
  hulls: tuple[np.ndarray, ...]


def load_mesh_folder(
    directory: str | os.PathLike[str], *, scale: float = 1.0, recursive: bool = False
) -> FolderReport:
  """Loads every mesh file in a folder; reports each file that cannot be used with the reason.

  Candidate files are all regular files except hidden ones (name starting with ``.``) and companion files
  (`COMPANION_EXTENSIONS`); with ``recursive``, also those in non-hidden sub-directories. A file with an
  extension outside `dexjax.geometry.SUPPORTED_EXTENSIONS` (OBJ, STL, PLY, GLB, OFF; case-insensitive) is
  rejected without being read. Every other file goes through `dexjax.geometry.load_mesh`; a `MeshError`
  (empty, unreadable, NaN coordinates, open surface with a large hole, non-manifold, zero volume, ...)
  becomes a rejection with its reason, and so does any other exception (as ``'TypeName: message'``).

  Args:
    directory: the folder to read.
    scale: factor applied to every file's coordinates to get metres, e.g. 0.001 for millimetres.
    recursive: also read sub-directories (names then include the sub-directory, ``'sub/mug'``).

  Returns:
    A `FolderReport`; both lists are sorted by relative path, so the order is deterministic.

  Raises:
    FileNotFoundError: ``directory`` does not exist.
    NotADirectoryError: ``directory`` is not a directory.
    ValueError: ``scale`` is not a finite positive number.
  """
  root = os.fspath(directory)
  if not os.path.exists(root):
    raise FileNotFoundError(f"mesh folder '{root}' does not exist; expected a directory of mesh files")
  if not os.path.isdir(root):
    raise NotADirectoryError(f"mesh folder '{root}' is not a directory; expected a directory of mesh files")
  if not (isinstance(scale, (int, float)) and np.isfinite(scale) and scale > 0):
    raise ValueError(f"load_mesh_folder('{root}'): scale: expected a finite number > 0, got {scale!r}")
  relative = _candidate_files(root, recursive)
  names = _object_names([r for r in relative if os.path.splitext(r)[1].lower() in SUPPORTED_EXTENSIONS])
  loaded, rejected = [], []
  for rel in relative:
    path = os.path.join(root, *rel.split('/'))
    ext = os.path.splitext(rel)[1].lower()
    if ext not in SUPPORTED_EXTENSIONS:
      shown = ext if ext else '(none)'
      rejected.append(Rejection(rel, f"unsupported extension {shown}; expected one of "
                                     f"{', '.join(SUPPORTED_EXTENSIONS)}"))
      continue
    outcome = load_file(path, name=names[rel], label=rel, scale=scale)
    (loaded if isinstance(outcome, LoadedObject) else rejected).append(outcome)
  return FolderReport(loaded=loaded, rejected=rejected)


def load_file(path: str, *, name: str, label: str, scale: float = 1.0) -> LoadedObject | Rejection:
  """Loads one mesh file as object ``name``, or returns its `Rejection` (filed under ``label``); never raises.

  The loader's `ImperfectMeshWarning` and `ScaleWarning` are recorded in `LoadedObject.warnings` instead of
  being emitted (`emit_warnings` emits them)."""
  with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter('always', ImperfectMeshWarning)
    warnings.simplefilter('always', ScaleWarning)
    try:
      mesh = load_mesh(path, scale=float(scale))
    except MeshError as e:
      return Rejection(label, e.reason)
    except Exception as e:  # One bad file must never stop the others.
      return Rejection(label, f'{type(e).__name__}: {e}')
  notes = []
  for w in caught:
    if issubclass(w.category, (ImperfectMeshWarning, ScaleWarning)):
      notes.append(w.message)
    else:  # Not ours to absorb: pass it on.
      warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
  return LoadedObject(name=name, path=path, mesh=mesh, warnings=tuple(notes))


def emit_warnings(objects: list[LoadedObject] | tuple[LoadedObject, ...]) -> None:
  """Emits (`warnings.warn`) the load warnings recorded in each object, e.g. for a CLI's stderr."""
  for o in objects:
    for w in o.warnings:
      warnings.warn(w, stacklevel=2)


def prepare_object(
    loaded: LoadedObject,
    *,
    cache_dir: str | os.PathLike[str] | None = None,
    grid_size: int = 100,
    max_hulls: int = 8,
    max_vertices: int = 64,
    convex_solidity: float = CONVEX_SOLIDITY,
    model: bool = True,
    **build_kwargs: Any,
) -> PreparedObject:
  """Builds (or loads from the on-disk cache) a loaded object's `ObjectModel` and collision hulls.

  Args:
    loaded: an entry of `FolderReport.loaded`.
    cache_dir: cache directory; ``$DEXJAX_CACHE`` or ``~/.cache/dexjax/objects`` when None. Models are
      stored in it, hulls in its ``hulls/`` sub-directory.
    grid_size: signed distance grid resolution per axis (see `dexjax.geometry.build_object_model`).
    max_hulls, max_vertices, convex_solidity: see `dexjax.objects.collision_hulls`.
    model: build the `ObjectModel` (False: only the collision hulls; ``PreparedObject.model`` is None).
    **build_kwargs: further `build_object_model` arguments (padding, num_surface_samples, seed);
      ``name`` defaults to the object's name.

  Returns:
    A `PreparedObject`.
  """
  build_kwargs.setdefault('name', loaded.name)
  object_model = (cached_object_model(loaded.mesh, cache_dir=cache_dir, grid_size=grid_size, **build_kwargs)
                  if model else None)
  hulls = cached_collision_hulls(loaded.mesh, cache_dir=cache_dir, max_hulls=max_hulls,
                                 max_vertices=max_vertices, convex_solidity=convex_solidity)
  return PreparedObject(name=loaded.name, source=loaded.path, mesh=loaded.mesh, model=object_model, hulls=hulls)


def _candidate_files(root: str, recursive: bool) -> list[str]:
  """Sorted relative POSIX paths of the non-hidden, non-companion regular files under ``root``."""
  found = []
  for current, dirs, files in os.walk(root):
    dirs[:] = sorted(d for d in dirs if not d.startswith('.')) if recursive else []
    rel_dir = os.path.relpath(current, root)
    for name in files:
      if name.startswith('.') or os.path.splitext(name)[1].lower() in COMPANION_EXTENSIONS:
        continue
      if not os.path.isfile(os.path.join(current, name)):
        continue
      found.append(name if rel_dir == os.curdir else '/'.join([*rel_dir.split(os.sep), name]))
  return sorted(found)


def _object_names(relative: list[str]) -> dict[str, str]:
  """Maps each relative path to its object name: without extension unless that would be ambiguous."""
  stems: dict[str, int] = {}
  for rel in relative:
    stem = os.path.splitext(rel)[0]
    stems[stem] = stems.get(stem, 0) + 1
  return {rel: (os.path.splitext(rel)[0] if stems[os.path.splitext(rel)[0]] == 1 else rel) for rel in relative}
