"""The benchmark's per-attempt log, ``attempts.jsonl``: one JSON object per line, appended as each attempt ends.

Each record is written with a single ``write`` on a file opened for appending, under an exclusive lock
(``flock``: several processes may append to one log), and then flushed to disk (``fsync``), so a killed run
leaves whole records and at most one torn last line, without its newline.
`read_attempts` drops that line (and, with ``repair``, cuts it from the file so the next append starts on a fresh
line); a damaged whole line (not a JSON object, or, as the benchmark reads it, without a field of
`RECORD_FIELDS`) is an error naming the file and line, never silently skipped.
"""

from __future__ import annotations

import fcntl
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dexjax.config import plain_json


class AttemptLogError(ValueError):
  """A damaged attempt log (a whole line that is not an attempt record)."""


#: Fields every attempt record has (`dexjax.bench.run_trial` writes them) and their JSON types; a resumed run and
#: the summary read them.
RECORD_FIELDS: dict[str, tuple[type, ...]] = {
    'policy': (str,), 'trial': (int,), 'attempt': (int,), 'success': (bool,), 'verdicts': (dict,),
    'objects_at_start': (int,), 'consecutive_failures': (int,), 'plan_seconds': (int, float),
    'motion_seconds': (int, float), 'stop': (str, type(None)), 'state': (dict,)}


def append_attempt(path: str | os.PathLike[str], record: Mapping[str, Any]) -> None:
  """Appends ``record`` (a JSON-able mapping) as one line of ``path`` and flushes it to disk.

  Raises:
    OSError: naming ``path`` (disk full, permission denied).
  """
  line = (json.dumps(plain_json(record, nan_to_none=True), sort_keys=True, allow_nan=False) + '\n').encode('utf-8')
  try:
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
      fcntl.flock(fd, fcntl.LOCK_EX)
      written = os.write(fd, line)
      if written != len(line):
        raise OSError(f'{path}: wrote {written} of {len(line)} bytes of an attempt record')
      os.fsync(fd)
    finally:
      os.close(fd)
  except OSError as e:
    if e.errno is None or e.filename is not None:
      raise
    raise OSError(e.errno, e.strerror, os.fspath(path)) from e  # os.write and os.fsync name no file


def _check_record(record: Any, path: Path, number: int, line: bytes,
                  fields: Mapping[str, tuple[type, ...]]) -> dict[str, Any]:
  """``record`` if it is a JSON object with ``fields`` of their types; `AttemptLogError` naming the file, line and
  field otherwise."""
  if not isinstance(record, dict):
    raise AttemptLogError(f"{path}: line {number}: expected one JSON object per line (an attempt record), got "
                          f'{line[:80]!r}')
  for field, types in fields.items():
    value = record.get(field, ...)
    if value is ... or not isinstance(value, types) or (isinstance(value, bool) and bool not in types):
      problem = 'missing' if value is ... else f'got {value!r}'
      expected = ' or '.join(t.__name__ for t in types)
      raise AttemptLogError(f'{path}: line {number}: field {field!r}: expected {expected} (an attempt record of '
                            f'python -m dexjax.benchmark), {problem}')
  return record


def read_attempts(path: str | os.PathLike[str], *, repair: bool = False,
                  fields: Mapping[str, tuple[type, ...]] | None = None) -> list[dict[str, Any]]:
  """The records of ``path`` in order ([] if it does not exist).

  A last line without its newline is a record torn by a kill: it is dropped, and with ``repair`` cut from the file.
  With ``fields`` (e.g. `RECORD_FIELDS`, as the benchmark reads its log), every record must hold these fields, of
  these JSON types.

  Raises:
    AttemptLogError: a whole line is not an attempt record: not a JSON object, or one of ``fields`` missing or
      of another type (naming the file, line and field).
  """
  path = Path(path)
  if not path.exists():
    return []
  data = path.read_bytes()
  complete = data[:data.rfind(b'\n') + 1]  # whole lines; what follows the last newline is a torn record
  records = []
  for number, line in enumerate(complete.split(b'\n')[:-1], start=1):
    try:
      record = json.loads(line.decode('utf-8'))
    except (UnicodeDecodeError, ValueError):
      record = None
    records.append(_check_record(record, path, number, line, fields or {}))
  good_bytes = len(complete)
  if repair and good_bytes < len(data):
    with open(path, 'r+b') as f:
      f.truncate(good_bytes)
  return records


__all__ = ['AttemptLogError', 'RECORD_FIELDS', 'append_attempt', 'read_attempts']
