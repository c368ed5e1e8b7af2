"""What the command lines share: one way to report bad input, the exit codes, and the checks of output paths
made before any computing.

Exit codes of every ``python -m dexjax.*`` command (``docs/errors.md``):

* 0 (`OK_EXIT`): success.
* 1 (`FAILURE_EXIT`): the command ran and reports a failure it defines in its ``--help`` (``objects check``: no
  object loaded; ``sim settle``: an object left the bin, never settled or was rejected; ``generate``: some shards
  failed, the others are written).
* 2 (`BAD_INPUT_EXIT`): bad input, reported as one ``error: ...`` line on stderr, never a traceback: usage
  (argparse), a missing, unreadable or malformed file (config, mesh, grasps, camera, shard, checkpoint), a value
  out of range or contradicting another, an output that cannot or must not be written (`check_output_file`,
  `check_output_dir`), a file system error while writing (disk full, permission denied; named with its file).
* 130 (`INTERRUPTED_EXIT`): interrupted (Ctrl-C); what was finished is kept (rerun to resume where supported).

Warnings (e.g. an implausible mesh scale) print as ``warning: ...`` lines on stderr.

This module uses the standard library only, so a command can import it before its slow imports.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import os
import secrets
import struct
import sys
import tempfile
import warnings
import zipfile
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

OK_EXIT = 0
FAILURE_EXIT = 1
BAD_INPUT_EXIT = 2
INTERRUPTED_EXIT = 130

#: Set (to anything) to get Python's traceback instead of the one-line ``error:`` report (for bug reports).
DEBUG_ENV_VAR = 'DEXJAX_DEBUG'

#: Keyword of the PNG text chunk that marks a picture as written by dexjax (`stamp_png`, `is_dexjax_png`).
PNG_MARK = 'dexjax'
_PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'


class OutputError(ValueError):
  """An output path that cannot or must not be written; the message names the option, the path and what was
  expected."""

  def __init__(self, option: str, path: str | os.PathLike[str], problem: str):
    self.option, self.path, self.problem = option, os.fspath(path), problem
    super().__init__(f"{option}: '{self.path}': {problem}")


def _bad_input_types() -> tuple[type[BaseException], ...]:
  """The library's error classes that mean bad input (imported lazily: their modules are loaded by then)."""
  types: list[type[BaseException]] = [ValueError, OSError, ImportError]
  for module, name in (('dexjax.data.shards', 'ShardError'),):
    loaded = sys.modules.get(module)
    if loaded is not None:
      types.append(getattr(loaded, name))
  return tuple(types)


def report_bad_input(error: BaseException) -> int:
  """Prints ``error: <message>`` to stderr and returns the bad-input exit code, 2.

  An operating-system error prints as ``error: <file>: <reason>``; disk full adds what to do (written work is
  kept: every dexjax writer replaces files atomically).
  """
  if isinstance(error, OSError) and error.strerror:
    where = error.filename if error.filename is not None else '(unknown file)'
    hint = ''
    if error.errno in (errno.ENOSPC, errno.EDQUOT):
      hint = '; free some space and rerun (files already written are complete and kept)'
    elif error.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
      hint = '; expected a writable location'
    print(f'error: {where}: {error.strerror}{hint}', file=sys.stderr)
  else:
    print(f'error: {error}', file=sys.stderr)
  return BAD_INPUT_EXIT


def report_failure(error: BaseException | str) -> int:
  """Prints ``error: <message>`` to stderr and returns the command-defined failure exit code, 1."""
  print(f'error: {error}', file=sys.stderr)
  return FAILURE_EXIT


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:  # pylint: disable=unused-argument
  print(f'warning: {message}', file=sys.stderr if file is None else file)


def command(main: Callable[[list[str] | None], int]) -> Callable[[list[str] | None], int]:
  """Wraps a command's ``main(argv) -> exit code`` so that every bad input (`ValueError` and its subclasses
  such as `dexjax.config.ConfigError` and `dexjax.geometry.MeshError`, `OSError`, `ImportError`,
  `dexjax.data.ShardError`) becomes one ``error: ...`` line and exit code 2, Ctrl-C exit code 130, and warnings
  ``warning: ...`` lines, all on stderr. Other exceptions are bugs and keep their traceback (as do all with
  ``$DEXJAX_DEBUG`` set)."""

  @functools.wraps(main)
  def wrapped(argv: list[str] | None = None) -> int:
    saved = warnings.showwarning
    warnings.showwarning = _show_warning
    try:
      return main(argv)
    except KeyboardInterrupt:
      if os.environ.get(DEBUG_ENV_VAR):
        raise
      print('error: interrupted', file=sys.stderr)
      return INTERRUPTED_EXIT
    except Exception as error:  # pylint: disable=broad-except (filtered just below; bugs are re-raised)
      if isinstance(error, _bad_input_types()) and not os.environ.get(DEBUG_ENV_VAR):
        return report_bad_input(error)
      raise
    finally:
      warnings.showwarning = saved

  return wrapped


def _probe_writable(directory: Path, option: str, path: Path) -> None:
  """Creates and removes a temporary file in ``directory`` (also catches read-only file systems and root)."""
  try:
    with tempfile.TemporaryFile(dir=directory):
      pass
  except OSError as e:
    raise OutputError(option, path, f"cannot write in the directory '{directory}' ({e.strerror}); expected a "
                                    'writable directory') from None


def check_output_file(path: str | os.PathLike[str], *, option: str = '--out',
                      owned: Callable[[Path], bool] | None = None, overwrite: bool = False) -> Path:
  """Checks, before any computing, that a command may write the file ``path``; returns it as a `Path`.

  The parent directory must exist and be writable, ``path`` must not be a directory, and an existing file is
  only replaced when ``owned(path)`` recognises it as this command's own earlier output, or with ``overwrite``
  (the command's ``--overwrite``).

  Raises:
    OutputError: naming ``option``, the path and what was expected.
  """
  path = Path(path)
  if path.is_dir():
    raise OutputError(option, path, 'is a directory; expected a file name')
  parent = path.parent if str(path.parent) else Path('.')
  if not parent.exists():
    raise OutputError(option, path, f"the directory '{parent}' does not exist; expected an existing directory "
                                    '(create it first)')
  if not parent.is_dir():
    raise OutputError(option, path, f"'{parent}' is not a directory; expected an existing directory")
  if path.exists() or path.is_symlink():
    if not path.is_file():
      raise OutputError(option, path, 'exists and is not a regular file; expected a new file name')
    if not overwrite and not (owned is not None and _safely(owned, path)):
      raise OutputError(option, path, 'exists and was not written by this command; expected a new file name '
                                      '(or pass --overwrite to replace it)')
    if not os.access(path, os.W_OK):
      raise OutputError(option, path, 'exists and is read-only; expected a writable file')
  _probe_writable(parent, option, path)
  return path


def check_output_dir(path: str | os.PathLike[str], *, option: str = '--out') -> Path:
  """Checks, before any computing, that a command may create or write into the directory ``path``: it is a
  directory or does not exist yet, and its nearest existing ancestor is a writable directory (missing levels
  are created by the command). What the directory may already hold is the command's rule.

  Raises:
    OutputError: naming ``option``, the path and what was expected.
  """
  path = Path(path)
  if path.exists() and not path.is_dir():
    raise OutputError(option, path, 'exists and is not a directory; expected a directory (or a new name)')
  existing = path
  while not existing.exists():
    if existing.parent == existing:
      break
    existing = existing.parent
  if not existing.is_dir():
    raise OutputError(option, path, f"'{existing}' is a file, not a directory; expected a directory path")
  _probe_writable(existing, option, path)
  return path


def check_distinct(*pairs: tuple[str, str | os.PathLike[str] | None]) -> None:
  """Raises `OutputError` if two of the (option, path) outputs name the same file (None: not given)."""
  seen: dict[str, str] = {}
  for option, path in pairs:
    if path is None:
      continue
    key = os.path.realpath(path)
    if key in seen:
      raise OutputError(option, path, f'is also the {seen[key]} output; expected distinct files')
    seen[key] = option


def _safely(predicate: Callable[[Path], bool], path: Path) -> bool:
  try:
    return bool(predicate(path))
  except (OSError, ValueError, zipfile.BadZipFile):
    return False


def owned_json(*keys: str) -> Callable[[Path], bool]:
  """Recognises a JSON file this command wrote: an object holding every one of ``keys``."""

  def owned(path: Path) -> bool:
    from dexjax.config import parse_json  # pylint: disable=g-import-not-at-top (refuses hostile nesting)
    data = parse_json(path.read_text(encoding='utf-8'), os.fspath(path))
    return isinstance(data, dict) and all(k in data for k in keys)

  return owned


def owned_npz(*names: str) -> Callable[[Path], bool]:
  """Recognises an ``.npz`` file this command wrote: a zip archive holding every one of the arrays ``names``."""

  def owned(path: Path) -> bool:
    with zipfile.ZipFile(path) as archive:
      members = set(archive.namelist())
    return all(f'{n}.npy' in members for n in names)

  return owned


def _png_chunks(data: bytes) -> Iterator[tuple[bytes, int, int]]:
  """(type, start of the chunk, end of the chunk) of each chunk of the PNG bytes ``data``."""
  if not data.startswith(_PNG_SIGNATURE):
    raise ValueError('not a PNG file')
  offset = len(_PNG_SIGNATURE)
  while offset + 8 <= len(data):
    length, kind = struct.unpack('>I4s', data[offset:offset + 8])
    end = offset + 12 + length
    yield kind, offset, end
    if kind == b'IEND':
      return
    offset = end


def is_dexjax_png(path: str | os.PathLike[str]) -> bool:
  """True if ``path`` is a PNG carrying dexjax's text chunk (`PNG_MARK`), i.e. a picture dexjax wrote."""
  data = Path(path).read_bytes()
  for kind, start, end in _png_chunks(data):
    if kind in (b'tEXt', b'iTXt') and data[start + 8:end - 4].startswith(PNG_MARK.encode() + b'\0'):
      return True
  return False


def stamp_png(path: str | os.PathLike[str], what: str) -> None:
  """Adds dexjax's text chunk (``PNG_MARK: what``) to the PNG ``path`` (atomically), so that a later run
  recognises the picture as its own output. A missing file or one already stamped is left alone."""
  path = Path(path)
  if not path.is_file() or is_dexjax_png(path):
    return
  data = path.read_bytes()
  ihdr_end = next(end for kind, _, end in _png_chunks(data) if kind == b'IHDR')
  body = b'tEXt' + PNG_MARK.encode() + b'\0' + what.encode('latin-1', 'replace')
  chunk = struct.pack('>I', len(body) - 4) + body + struct.pack('>I', zlib.crc32(body) & 0xFFFFFFFF)
  atomic_write(path, lambda f: f.write(data[:ihdr_end] + chunk + data[ihdr_end:]))


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], suffix: str = '') -> Iterator[Path]:
  """Yields a temporary path in ``path``'s directory to write to; on success it is moved over ``path`` with
  `os.replace` (readers see the old file or the whole new one; the permissions are the old file's, or the
  umask's), on any error it is removed. An `OSError` while writing (disk full, permission denied) is re-raised
  naming ``path``."""
  path = Path(path)
  directory = path.parent if str(path.parent) else Path('.')
  tmp = None
  try:
    tmp = _new_temporary(directory, f'.{path.name}.tmp-', suffix)
    if path.exists():
      os.chmod(tmp, path.stat().st_mode & 0o7777)  # the new version keeps the old file's permissions
    yield Path(tmp)
    os.replace(tmp, path)
  except OSError as e:
    if e.filename not in (None, tmp, os.fspath(directory)) or e.errno is None:
      raise
    raise type(e)(e.errno, e.strerror, os.fspath(path)) from e
  finally:
    if tmp is not None and os.path.exists(tmp):
      os.remove(tmp)


def _new_temporary(directory: Path, prefix: str, suffix: str) -> str:
  """Creates an empty file ``directory/<prefix><random><suffix>`` with an ordinary new file's permissions (0666
  less the umask; `tempfile.mkstemp` would give 0600) and returns its name."""
  while True:
    tmp = os.path.join(directory, f'{prefix}{secrets.token_hex(8)}{suffix}')
    try:
      os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
      return tmp
    except FileExistsError:
      continue


def atomic_write(path: str | os.PathLike[str], write: Callable[[IO[bytes]], Any]) -> None:
  """Calls ``write(binary file)`` on a temporary file next to ``path``, flushes it to disk and moves it over
  ``path`` (see `atomic_path`): nothing already there is lost if writing fails."""
  with atomic_path(path) as tmp:
    with open(tmp, 'wb') as f:
      write(f)
      f.flush()
      os.fsync(f.fileno())


def add_overwrite_flag(parser: Any) -> None:
  """``--overwrite``: the one flag with which a command replaces an existing output it did not write."""
  parser.add_argument('--overwrite', action='store_true',
                      help='replace existing output files this command did not write (default: refuse, exit 2)')


__all__ = ['BAD_INPUT_EXIT', 'DEBUG_ENV_VAR', 'FAILURE_EXIT', 'INTERRUPTED_EXIT', 'OK_EXIT', 'PNG_MARK', 'OutputError',
           'add_overwrite_flag', 'atomic_path', 'atomic_write', 'check_distinct', 'check_output_dir',
           'check_output_file', 'command', 'is_dexjax_png', 'owned_json', 'owned_npz', 'report_bad_input',
           'report_failure', 'stamp_png']
