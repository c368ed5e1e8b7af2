"""On-disk cache of built `ObjectModel`s.

A model is stored as ``<cache_dir>/<key>.npz`` where the key is a SHA-256 over the cache format version,
the input mesh (vertex and face arrays: dtype, shape and bytes) and every build parameter after applying
the defaults of `build_object_model` (so ``grid_size=100`` and the default share an entry). The ``name``
argument only labels error messages and is not part of the key.

Files are written atomically (temporary file in the same directory, then `os.replace`), so concurrent
readers never see a partial file. A file that cannot be read or does not match its key is reported with a
`RuntimeWarning`, rebuilt and replaced. A cache directory that cannot be written only produces a warning.

`content_key` / `mesh_content_key`, `atomic_write_npz` and `atomic_write_text` are the generic key and write
helpers; other caches (e.g. `dexjax.objects.collision`'s collision hulls) and run files reuse them.
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
import json
import os
import secrets
import warnings
from typing import Any

import jax.numpy as jnp
import numpy as np
import trimesh

from dexjax.geometry.build import build_object_model
from dexjax.geometry.object_model import ObjectModel

CACHE_FORMAT_VERSION: int = 1
"""Bump when the stored arrays or the way they are computed change; old entries are then ignored."""

CACHE_ENV_VAR: str = 'DEXJAX_CACHE'
"""Environment variable naming the cache directory."""

_FIELDS = tuple(f.name for f in dataclasses.fields(ObjectModel))
_NAME_ONLY_PARAMS = frozenset({'name'})
_BUILD_SIGNATURE = inspect.signature(build_object_model)


def default_cache_dir() -> str:
  """``$DEXJAX_CACHE`` if set and non-empty, else ``~/.cache/dexjax/objects``."""
  env = os.environ.get(CACHE_ENV_VAR, '')
  return os.path.expanduser(env if env else os.path.join('~', '.cache', 'dexjax', 'objects'))


def build_params(**build_kwargs: Any) -> dict[str, Any]:
  """The full set of `build_object_model` keyword arguments that affect the result (defaults applied).

  Raises:
    TypeError: an argument `build_object_model` does not accept.
  """
  bound = _BUILD_SIGNATURE.bind(None, **build_kwargs)  # None stands in for the mesh.
  bound.apply_defaults()
  params = dict(bound.arguments)
  params.pop('mesh')
  return {k: _plain(v) for k, v in sorted(params.items()) if k not in _NAME_ONLY_PARAMS}


def cache_key(mesh: trimesh.Trimesh, **build_kwargs: Any) -> str:
  """Hex SHA-256 identifying the model `build_object_model(mesh, **build_kwargs)` would produce."""
  header = {'format': CACHE_FORMAT_VERSION, 'params': build_params(**build_kwargs)}
  return mesh_content_key(header, mesh)


def content_key(header: dict[str, Any], *arrays: np.ndarray) -> str:
  """Hex SHA-256 over a JSON-serialisable ``header`` and the dtype, shape and bytes of each array.

  The generic key behind every dexjax on-disk cache: put a format version and every parameter that
  affects the cached result into ``header``.
  """
  digest = hashlib.sha256()
  digest.update(json.dumps(header, sort_keys=True).encode())
  for array in arrays:
    array = np.ascontiguousarray(array)
    digest.update(f'{array.dtype.str}{array.shape}'.encode())
    digest.update(array.tobytes())
  return digest.hexdigest()


def mesh_content_key(header: dict[str, Any], mesh: trimesh.Trimesh) -> str:
  """`content_key` of ``header`` and a mesh's (V, 3) float64 vertices and (F, 3) int64 faces."""
  return content_key(header, np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64))


def cached_object_model(
    mesh: trimesh.Trimesh, *, cache_dir: str | os.PathLike[str] | None = None, **build_kwargs: Any
) -> ObjectModel:
  """`build_object_model(mesh, **build_kwargs)`, loaded from the on-disk cache when possible.

  Args:
    mesh: triangle mesh in metres (see `build_object_model`).
    cache_dir: cache directory; `default_cache_dir()` when None. Created if missing.
    **build_kwargs: keyword arguments of `build_object_model` (grid_size, padding, num_surface_samples,
      seed, name).

  Returns:
    The `ObjectModel` (float32 jax arrays), identical to a fresh build with the same arguments.
  """
  params = build_params(**build_kwargs)  # Validates the argument names before any work.
  key = cache_key(mesh, **build_kwargs)
  directory = os.fspath(cache_dir) if cache_dir is not None else default_cache_dir()
  path = os.path.join(directory, f'{key}.npz')
  if os.path.exists(path):
    try:
      return _read(path, key, params)
    except Exception as e:  # Any unreadable file is rebuilt; never crash on a bad cache entry.
      warnings.warn(
          f"dexjax object cache: '{path}' is corrupt or unreadable ({type(e).__name__}: {e}); "
          'rebuilding it', RuntimeWarning, stacklevel=2)
  model = build_object_model(mesh, **build_kwargs)
  try:
    _write_atomic(path, key, model)
  except OSError as e:
    warnings.warn(
        f"dexjax object cache: could not write '{path}' ({e}); continuing without caching",
        RuntimeWarning, stacklevel=2)
  return model


def _plain(value: Any) -> Any:
  """Converts numpy scalars to Python scalars so build parameters serialise to stable JSON."""
  return value.item() if isinstance(value, np.generic) else value


def _read(path: str, key: str, params: dict[str, Any]) -> ObjectModel:
  """Loads and checks one cache file; raises ValueError (or an I/O error) if it is not a valid entry."""
  with np.load(path, allow_pickle=False) as data:
    stored_key = str(data['cache_key']) if 'cache_key' in data.files else None
    if stored_key != key:
      raise ValueError(f'stored key {stored_key!r} does not match the file name')
    missing = [f for f in _FIELDS if f not in data.files]
    if missing:
      raise ValueError(f'missing fields {missing}')
    arrays = {f: np.array(data[f]) for f in _FIELDS}
  d, s = params['grid_size'], params['num_surface_samples']
  expected = {
      'sdf': (d, d, d), 'sdf_grad': (d, d, d, 3), 'origin': (3,), 'voxel_size': (),
      'surface_points': (s, 3), 'surface_normals': (s, 3), 'center_of_mass': (3,), 'volume': (),
      'inertia': (3, 3), 'bounds': (2, 3),
  }
  for field, shape in expected.items():
    array = arrays[field]
    if array.shape != shape or array.dtype != np.float32:
      raise ValueError(f'field {field!r} has shape {array.shape} {array.dtype}; expected {shape} float32')
    if not np.isfinite(array).all():
      raise ValueError(f'field {field!r} contains NaN or inf')
  return ObjectModel(**{f: jnp.asarray(a) for f, a in arrays.items()})


def _write_atomic(path: str, key: str, model: ObjectModel) -> None:
  """Writes ``model`` to ``path`` as .npz (with its key) via `atomic_write_npz`."""
  atomic_write_npz(path, {'cache_key': np.array(key), **{f: np.asarray(getattr(model, f)) for f in _FIELDS}})


def _atomic_write(path: str | os.PathLike[str], suffix: str, write) -> None:
  """Calls ``write(binary file)`` on a temporary file in ``path``'s directory (created if missing), flushes it
  to disk and moves it over ``path`` with `os.replace`; on any error the temporary file is removed (the old
  ``path``, if any, is untouched) and an `OSError` (disk full, permission denied) is re-raised naming ``path``."""
  path = os.fspath(path)
  directory = os.path.dirname(path) or '.'
  tmp = None
  try:
    os.makedirs(directory, exist_ok=True)
    fd, tmp = _temporary_file(directory, suffix, path)
    with os.fdopen(fd, 'wb') as f:
      write(f)
      f.flush()
      os.fsync(f.fileno())
    os.replace(tmp, path)
  except OSError as e:
    if e.errno is None or e.filename not in (None, tmp, directory):
      raise
    raise type(e)(e.errno, e.strerror, path) from e
  finally:
    if tmp is not None and os.path.exists(tmp):
      os.remove(tmp)


def _temporary_file(directory: str, suffix: str, path: str) -> tuple[int, str]:
  """(descriptor, name) of a new file ``directory/.tmp-<random><suffix>`` with the permissions of ``path`` if
  it exists, else the umask's (0666 less the umask, as an ordinary new file; `tempfile.mkstemp` would give 0600)."""
  while True:
    tmp = os.path.join(directory, f'.tmp-{secrets.token_hex(8)}{suffix}')
    try:
      fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except FileExistsError:
      continue
    try:
      os.chmod(tmp, os.stat(path).st_mode & 0o7777)
    except FileNotFoundError:
      pass
    return fd, tmp


def atomic_write_npz(path: str | os.PathLike[str], arrays: dict[str, np.ndarray]) -> None:
  """Writes ``arrays`` to ``path`` as an uncompressed .npz so that readers never see a partial file.

  The data go to a temporary file in the same directory (created if missing), are flushed to disk and
  then moved over ``path`` with `os.replace`; on any error the temporary file is removed.

  Raises:
    OSError: the directory cannot be created or written.
  """
  _atomic_write(path, '.npz', lambda f: np.savez(f, **arrays))


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
  """Writes ``text`` (UTF-8) to ``path`` the way `atomic_write_npz` writes arrays: readers see the old file or
  the whole new one.

  Raises:
    OSError: the directory cannot be created or written.
  """
  _atomic_write(path, '.txt', lambda f: f.write(text.encode('utf-8')))
