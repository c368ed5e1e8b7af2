"""Content-addressed cache files: where dexjax caches live, their keys, and atomic writes.

The generic helpers behind every dexjax on-disk cache (the object-model cache of `dexjax.geometry.cache`, the
solids of `dexjax.geometry.winding`, `dexjax.objects.collision`'s collision hulls) and run files:

* `default_cache_dir`: ``$DEXJAX_CACHE`` (`CACHE_ENV_VAR`) or ``~/.cache/dexjax/objects``;
* `content_key` / `mesh_content_key`: a hex SHA-256 over a JSON header (format version and every parameter that
  affects the cached result) and the dtype, shape and bytes of arrays;
* `atomic_write_npz` / `atomic_write_text`: readers see the old file or the whole new one, never a partial one.

This module imports nothing from dexjax, so any module can use it without an import cycle;
`dexjax.geometry.cache` re-exports these names.
"""

from __future__ import annotations

import hashlib
import json
import os
import secrets
from typing import Any

import numpy as np
import trimesh

CACHE_ENV_VAR: str = 'DEXJAX_CACHE'
"""Environment variable naming the cache directory."""


def default_cache_dir() -> str:
  """``$DEXJAX_CACHE`` if set and non-empty, else ``~/.cache/dexjax/objects``."""
  env = os.environ.get(CACHE_ENV_VAR, '')
  return os.path.expanduser(env if env else os.path.join('~', '.cache', 'dexjax', 'objects'))


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


__all__ = ['CACHE_ENV_VAR', 'atomic_write_npz', 'atomic_write_text', 'content_key', 'default_cache_dir',
           'mesh_content_key']
