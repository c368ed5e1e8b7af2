"""What the command lines share: reporting bad input (exit code 2) in one form."""

from __future__ import annotations

import sys

BAD_INPUT_EXIT = 2


def report_bad_input(error: BaseException) -> int:
  """Prints ``error: <message>`` to stderr (an operating-system error as ``error: <file>: <reason>``) and returns
  the bad-input exit code, 2."""
  if isinstance(error, OSError) and error.strerror:
    print(f'error: {error.filename or ""}: {error.strerror}', file=sys.stderr)
  else:
    print(f'error: {error}', file=sys.stderr)
  return BAD_INPUT_EXIT


__all__ = ['BAD_INPUT_EXIT', 'report_bad_input']
