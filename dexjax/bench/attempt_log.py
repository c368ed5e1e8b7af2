"""The benchmark's per-attempt log, ``attempts.jsonl``: one JSON object per line, appended as each attempt ends.

Each record is written with a single ``write`` on a file opened for appending, under an exclusive lock
(``flock``: several processes may append to one log), and then flushed to disk (``fsync``), so a killed run
leaves whole records and at most one torn last line, without its newline.
`read_attempts` drops that line (and, with ``repair``, cuts it from the file so the next append starts on a fresh
line); a damaged whole line is an error naming the file and line, never silently skipped.
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
  """A damaged attempt log (a whole line that is not a JSON object)."""


def append_attempt(path: str | os.PathLike[str], record: Mapping[str, Any]) -> None:
  """Appends ``record`` (a JSON-able mapping) as one line of ``path`` and flushes it to disk."""
  line = (json.dumps(plain_json(record, nan_to_none=True), sort_keys=True, allow_nan=False) + '\n').encode('utf-8')
  fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
  try:
    fcntl.flock(fd, fcntl.LOCK_EX)
    written = os.write(fd, line)
    if written != len(line):
      raise OSError(f'{path}: wrote {written} of {len(line)} bytes of an attempt record')
    os.fsync(fd)
  finally:
    os.close(fd)


def read_attempts(path: str | os.PathLike[str], *, repair: bool = False) -> list[dict[str, Any]]:
  """The records of ``path`` in order ([] if it does not exist).

  A last line without its newline is a record torn by a kill: it is dropped, and with ``repair`` cut from the file.

  Raises:
    AttemptLogError: a whole line is not a JSON object (naming the file and line).
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
    if not isinstance(record, dict):
      raise AttemptLogError(f"{path}: line {number}: expected one JSON object per line (an attempt record), got "
                            f'{line[:80]!r}')
    records.append(record)
  good_bytes = len(complete)
  if repair and good_bytes < len(data):
    with open(path, 'r+b') as f:
      f.truncate(good_bytes)
  return records


__all__ = ['AttemptLogError', 'append_attempt', 'read_attempts']
