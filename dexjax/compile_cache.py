"""JAX's persistent compilation cache under dexjax's cache directory, for the commands that compile large programs
(`python -m dexjax.plan`, the benchmark's workers)."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path


def default_compilation_cache_dir() -> str:
  """``$DEXJAX_CACHE/jax``: where `persistent_compilation_cache` keeps programs when the process has no JAX cache."""
  from dexjax.geometry.cache import default_cache_dir  # pylint: disable=g-import-not-at-top
  return os.path.join(default_cache_dir(), 'jax')


@contextlib.contextmanager
def persistent_compilation_cache():
  """Keeps what is compiled inside the block in ``$DEXJAX_CACHE/jax`` (JAX's persistent cache; compilations over
  1 s), so a rerun (e.g. a plan on an image of the same size with a network of the same architecture, or a
  benchmark worker's planners and judges) skips most of the compilation. Scoped: JAX's previous cache settings are
  restored afterwards, so a program (or test session) that enters it does not go on writing every later
  compilation there. A cache the process already has (``jax_compilation_cache_dir``, e.g. from
  ``JAX_COMPILATION_CACHE_DIR``) is used instead of ``$DEXJAX_CACHE/jax``, and a lower threshold it already has
  (``JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS``) is kept: the test suite sets both, so its CLI runs, Ray workers
  and subprocesses share one cache of every program. Best effort: an unwritable cache only costs the time."""
  import jax  # pylint: disable=g-import-not-at-top
  from jax.experimental.compilation_cache import compilation_cache  # pylint: disable=g-import-not-at-top
  names = ('jax_compilation_cache_dir', 'jax_persistent_cache_min_compile_time_secs')
  before = {name: getattr(jax.config, name) for name in names}
  try:
    directory = Path(before[names[0]] or default_compilation_cache_dir())
    directory.mkdir(parents=True, exist_ok=True)
  except OSError:
    yield
    return
  compilation_cache.reset_cache()
  jax.config.update(names[0], os.fspath(directory))
  jax.config.update(names[1], min(1.0, before[names[1]]))
  try:
    yield
  finally:
    for name, value in before.items():
      jax.config.update(name, value)
    compilation_cache.reset_cache()


__all__ = ['default_compilation_cache_dir', 'persistent_compilation_cache']
