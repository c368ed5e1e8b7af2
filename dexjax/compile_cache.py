"""JAX's persistent compilation cache under dexjax's cache directory, for the commands that compile large programs
(`python -m dexjax.plan`, the benchmark's workers), without the false XLA:CPU warning each cache hit prints.

Every program XLA:CPU loads from the cache on a host with AVX-512 logs (jaxlib 0.10)::

  E... cpu_aot_loader.cc:195] Loading XLA:CPU AOT result. Target machine feature +prefer-no-gather is not
  supported on the host machine. ... This could lead to execution errors such as SIGILL.

once for ``+prefer-no-gather`` and once for ``+prefer-no-scatter``, even in a fresh cache written by the same
process on the same machine: XLA adds these two LLVM *tuning* attributes to the compile target of every AVX-512
host, and the loader then looks for them among the host's instruction-set features, where they never are
(openxla/xla#44565, jax-ml/jax#38445; later XLA skips ``prefer-`` and ``fast-`` attributes there). It is a log
line, not a rejection: the program is loaded and runs. Keying the cache directory by the host cannot help (the
features differ on the very machine that compiled), and ``XLA_FLAGS=--xla_cpu_max_isa=AVX2`` avoids it only by
giving up AVX-512 code for every program. So `persistent_compilation_cache` passes the process's standard error
through `quiet_tuning_feature_warnings`, which drops exactly those lines (a tuning attribute, ``+prefer-...`` or
``+fast-...``); every other line, including this warning for a real instruction-set feature (a cache written by
another machine), passes unchanged. ``DEXJAX_SHOW_AOT_WARNINGS=1`` keeps them all.
"""

from __future__ import annotations

import contextlib
import os
import re
import select
import subprocess
import sys
import threading
from pathlib import Path

#: The loader's line for a compile-target attribute that only tunes code generation (XLA adds ``prefer-no-gather``
#: and ``prefer-no-scatter`` on AVX-512 hosts); a missing instruction-set feature (``+avx512f``) does not match.
TUNING_FEATURE_WARNING = re.compile(
    rb'cpu_aot_loader\.cc:\d+\] Loading XLA:CPU AOT result\. Target machine feature \+(?:prefer|fast)-[\w.-]+ is not')

#: Set to 1 to see XLA's tuning-attribute warnings (`quiet_tuning_feature_warnings` then does nothing).
SHOW_WARNINGS_ENV = 'DEXJAX_SHOW_AOT_WARNINGS'

# The filter process's program: this file run as a namespace (standard library only), forwarding its stdin.
_FILTER_MAIN = 'import runpy, sys; runpy.run_path(sys.argv[1])["forward_without_tuning_warnings"](0, 1)'
_FILTER = {'depth': 0, 'saved': None, 'process': None}
_FILTER_LOCK = threading.Lock()
_LINGERING: list[subprocess.Popen] = []  # filters other processes still write to (started inside the block)


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
  and subprocesses share one cache of every program. Inside the block, the false warning of each cache hit is
  left out of standard error (`quiet_tuning_feature_warnings`). Best effort: an unwritable cache only costs the
  time."""
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
    with quiet_tuning_feature_warnings():
      yield
  finally:
    for name, value in before.items():
      jax.config.update(name, value)
    compilation_cache.reset_cache()


@contextlib.contextmanager
def quiet_tuning_feature_warnings():
  """Inside the block, the process's standard error (file descriptor 2: Python, C++ logs, child processes) goes
  through a small filter process that leaves out XLA:CPU's false warning for a cached program's tuning attributes
  (`TUNING_FEATURE_WARNING`) and forwards everything else, line by line (a partial line, e.g. a progress bar, once
  nothing follows for 50 ms). Being a separate process, the filter still forwards what a crashing process wrote
  last. Nested and concurrent blocks share one filter. Does nothing with ``DEXJAX_SHOW_AOT_WARNINGS=1``, off
  POSIX, or when standard error cannot be redirected."""
  with _FILTER_LOCK:
    if _FILTER['depth'] == 0 and os.environ.get(SHOW_WARNINGS_ENV, '0') in ('', '0'):
      _start_filter()
    _FILTER['depth'] += 1
  try:
    yield
  finally:
    with _FILTER_LOCK:
      _FILTER['depth'] -= 1
      if _FILTER['depth'] == 0:
        _stop_filter()


def forward_without_tuning_warnings(source: int, target: int, linger: float = 0.05) -> None:
  """Copies file descriptor ``source`` to ``target`` until end of file, leaving out the lines that match
  `TUNING_FEATURE_WARNING`; a partial line is passed on once nothing follows for ``linger`` seconds. Stops when
  ``target`` is closed. The filter process of `quiet_tuning_feature_warnings`."""
  pending = b''
  while True:
    if pending and not select.select([source], [], [], linger)[0]:
      if _write(target, pending) is None:
        return
      pending = b''
      continue
    chunk = os.read(source, 1 << 16)
    if not chunk:
      break
    *lines, pending = (pending + chunk).split(b'\n')
    kept = b''.join(line + b'\n' for line in lines if not TUNING_FEATURE_WARNING.search(line))
    if kept and _write(target, kept) is None:
      return
  _write(target, pending)


def _write(fd: int, data: bytes) -> int | None:
  """Writes all of ``data`` to ``fd``; returns its length, or None when ``fd`` is closed."""
  view = memoryview(data)
  try:
    while view:
      view = view[os.write(fd, view):]
  except OSError:
    return None
  return len(data)


def _start_filter() -> None:
  """Points file descriptor 2 at a pipe read by a filter process that writes to the previous standard error."""
  if os.name != 'posix' or not sys.executable:
    return
  _reap_lingering()
  _flush_stderr()
  try:
    saved = os.dup(2)
  except OSError:
    return
  read, write = os.pipe()
  try:  # a new session: Ctrl-C stops the program, while the filter forwards its traceback
    process = subprocess.Popen([sys.executable, '-I', '-S', '-c', _FILTER_MAIN, os.path.abspath(__file__)],
                               stdin=read, stdout=saved, stderr=saved, start_new_session=True)
  except OSError:
    for fd in (saved, read, write):
      os.close(fd)
    return
  os.close(read)
  os.dup2(write, 2)
  os.close(write)
  _FILTER.update(saved=saved, process=process)


def _stop_filter() -> None:
  """Points file descriptor 2 back at the previous standard error; waits briefly for the filter to forward the
  rest (it ends once no process writes to the pipe: a child started inside the block may keep it going)."""
  saved, process = _FILTER['saved'], _FILTER['process']
  if process is None:
    return
  _flush_stderr()
  os.dup2(saved, 2)
  os.close(saved)
  _FILTER.update(saved=None, process=None)
  try:
    process.wait(timeout=1.0)
  except subprocess.TimeoutExpired:
    _LINGERING.append(process)


def _reap_lingering() -> None:
  _LINGERING[:] = [p for p in _LINGERING if p.poll() is None]


def _flush_stderr() -> None:
  with contextlib.suppress(Exception):
    sys.stderr.flush()


__all__ = ['SHOW_WARNINGS_ENV', 'TUNING_FEATURE_WARNING', 'default_compilation_cache_dir',
           'forward_without_tuning_warnings', 'persistent_compilation_cache', 'quiet_tuning_feature_warnings']
