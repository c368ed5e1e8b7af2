"""Writes tests/durations.json (seconds per test file) from a JUnit XML report of a whole run, e.g.

  python -m pytest -q --junitxml=/tmp/junit.xml && python tests/durations.py /tmp/junit.xml

`conftest.pytest_collection_modifyitems` runs the files longest first by it. Each test case's time is its setup,
call and teardown (pytest's default ``junit_duration_report``), so a module fixture counts for its file."""

from __future__ import annotations

import collections
import json
import pathlib
import sys
import xml.etree.ElementTree as ET


def file_seconds(junit_xml: str) -> dict[str, float]:
  """Test file (path relative to the repository, as pytest reports it) -> summed seconds of its test cases."""
  totals = collections.defaultdict(float)
  for case in ET.parse(junit_xml).getroot().iter("testcase"):
    module = case.get("classname", "").split(".")  # tests.test_x or tests.test_x.TestClass
    path = "/".join(part for part in module if not part[:1].isupper()) + ".py"
    totals[path] += float(case.get("time", 0.0))
  return dict(sorted(totals.items(), key=lambda kv: -kv[1]))


def main(argv: list[str]) -> int:
  if len(argv) != 2:
    print(__doc__, file=sys.stderr)
    return 2
  seconds = {path: round(s, 1) for path, s in file_seconds(argv[1]).items()}
  out = pathlib.Path(__file__).with_name("durations.json")
  out.write_text(json.dumps(seconds, indent=1) + "\n")
  print(f"{out}: {len(seconds)} files, {sum(seconds.values()):.0f} s in all")
  return 0


if __name__ == "__main__":
  sys.exit(main(sys.argv))
