"""The suite's file order (longest first, tests/conftest.py) and the script that records it (tests/durations.py)."""

from __future__ import annotations

import json
import types

import conftest
import durations


def test_file_seconds_sums_each_file_s_cases_classes_included(tmp_path):
  xml = tmp_path / "junit.xml"
  xml.write_text("""<?xml version="1.0"?><testsuites><testsuite name="pytest">
    <testcase classname="tests.test_a" name="test_one" time="1.5"/>
    <testcase classname="tests.test_a.TestGroup" name="test_two" time="2.0"/>
    <testcase classname="tests.test_b" name="test_three" time="10.25"/>
    </testsuite></testsuites>""")
  assert durations.file_seconds(str(xml)) == {"tests/test_b.py": 10.25, "tests/test_a.py": 3.5}


def test_files_run_longest_first_unknown_files_before_all_and_each_file_keeps_its_order(tmp_path, monkeypatch):
  recorded = tmp_path / "durations.json"
  recorded.write_text(json.dumps({"tests/test_short.py": 1.0, "tests/test_long.py": 90.0}))
  monkeypatch.setattr(conftest, "DURATIONS", recorded)
  item = lambda path, name: types.SimpleNamespace(location=(path, 0, name))
  items = [item("tests/test_short.py", "a"), item("tests/test_long.py", "b"), item("tests/test_short.py", "c"),
           item("tests/test_new.py", "d"), item("tests/test_long.py", "e")]
  conftest.pytest_collection_modifyitems(None, items)
  assert [i.location[2] for i in items] == ["d", "b", "e", "a", "c"]
