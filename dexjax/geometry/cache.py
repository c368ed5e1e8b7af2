"""On-disk cache of built `ObjectModel`s.

A model is stored as ``<cache_dir>/<key>.npz`` where the key is a SHA-256 over the cache format version,
the input mesh (vertex and face arrays: dtype, shape and bytes) and every build parameter after applying
the defaults of `build_object_model` (so ``grid_size=100`` and the default share an entry). The ``name``
argument only labels error messages and is not part of the key.

Files are written atomically (temporary file in the same directory, then `os.replace`), so concurrent
readers never see a partial file. A file that cannot be read or does not match its key is reported with a
`RuntimeWarning`, rebuilt and replaced. A cache directory that cannot be written only produces a warning.

The generic cache helpers (`CACHE_ENV_VAR`, `default_cache_dir`, `content_key` / `mesh_content_key`,
`atomic_write_npz` and `atomic_write_text`) live in `dexjax.geometry.content_cache`, which imports nothing from
dexjax; they are re-exported here.
"""

from __future__ import annotations

import dataclasses
import inspect
import os
import warnings
from typing import Any

import jax.numpy as jnp
import numpy as np
import trimesh

from dexjax.geometry.build import build_object_model
from dexjax.geometry.content_cache import (CACHE_ENV_VAR, atomic_write_npz, atomic_write_text, content_key,
                                           default_cache_dir, mesh_content_key)
from dexjax.geometry.object_model import ObjectModel

CACHE_FORMAT_VERSION: int = 1
"""Bump when the stored arrays or the way they are computed change; old entries are then ignored."""

_FIELDS = tuple(f.name for f in dataclasses.fields(ObjectModel))
_NAME_ONLY_PARAMS = frozenset({'name'})
_BUILD_SIGNATURE = inspect.signature(build_object_model)


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


__all__ = ['CACHE_ENV_VAR', 'CACHE_FORMAT_VERSION', 'atomic_write_npz', 'atomic_write_text', 'build_params',
           'cache_key', 'cached_object_model', 'content_key', 'default_cache_dir', 'mesh_content_key']
