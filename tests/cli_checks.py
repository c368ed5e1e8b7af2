"""What the hostile-input tests share: running a CLI in-process on bad input and a stand-in for computing."""

from __future__ import annotations

from pathlib import Path

from dexjax import cli


def never(*_, **__):
  """Stands in for a computation that must not start: the inputs are checked before it."""
  raise AssertionError('computed before the inputs were checked')


def one_error_line(capsys, main, argv: list, *needles: str) -> str:
  """Runs a CLI in-process: asserts exit code 2 and exactly one stderr line, ``error: ...`` naming ``needles``,
  no traceback; returns that line."""
  assert main([str(a) for a in argv]) == cli.BAD_INPUT_EXIT
  lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
  assert len(lines) == 1 and lines[0].startswith('error: ') and 'Traceback' not in lines[0], lines
  for needle in needles:
    assert str(needle) in lines[0], (needle, lines[0])
  return lines[0]


def digests(root: Path) -> dict[str, bytes]:
  """The bytes of every file under ``root`` by path: equal before and after a refused command when nothing was
  written, changed or added (no lock file either)."""
  return {str(p): p.read_bytes() for p in Path(root).rglob('*') if p.is_file()}
