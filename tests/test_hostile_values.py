"""Hostile values (issue 44): grasp files with a width in the wrong unit, booleans for numbers, non-finite or
absurd magnitudes; object paths that do not exist, are folders or devices; unknown ``builtin:`` names; procedural
ranges too large to list. Every case is one ``error:`` line naming the file or source, the field and the expected
value, exit code 2, never a traceback (docs/errors.md), and is refused before any object is built or any grasp
rated.

The CLIs run in-process through ``main(argv)``; no case compiles the quality solver or builds a mesh.
"""

from __future__ import annotations

import json
import time
import types
from pathlib import Path

import numpy as np
import pytest

import dexjax.objects.sets as sets_module
import dexjax.quality.__main__ as quality_cli
import dexjax.sim.__main__ as sim_cli
from cli_checks import never, one_error_line
from dexjax import cli
from dexjax.benchmark import main as benchmark_main
from dexjax.objects import BUILTIN_OBJECTS, MAX_RANGE_COUNT, expand_object_sources, load_object_set
from dexjax.objects import parse_procedural_spec, procedural_specs
from dexjax.quality.report import MAX_GRASP_VALUE

HUGE_RANGE = 'procedural:L1/0:99999999999'
CUBE_BOUNDS = np.array([[-0.02, -0.02, -0.02], [0.02, 0.02, 0.02]])


@pytest.fixture(autouse=True)
def _cache(cache_dir, monkeypatch):
  monkeypatch.setenv('DEXJAX_CACHE', str(cache_dir))


_never, _bad = never, one_error_line  # tests/cli_checks.py


def _grasp(**fields) -> dict:
  """A valid parallel-jaw grasp on a 4 cm cube at the origin, with ``fields`` replaced."""
  return {'gripper': 'parallel_jaw', 'center': [0.0, 0.0, 0.0], 'axis': [1.0, 0.0, 0.0],
          'approach': [0.0, 0.0, -1.0], 'width': 0.05, **fields}


def _grasp_file(path: Path, *grasps: dict) -> Path:
  path.write_text(json.dumps({'grasps': list(grasps)}))
  return path


def _quality_bad(capsys, tmp_path, grasps: Path, *needles: str) -> str:
  """``quality builtin:cube --grasps GRASPS`` must fail with one line naming the file and ``needles``."""
  return _bad(capsys, quality_cli.main, ['builtin:cube', '--grasps', grasps, '--out', tmp_path / 'out.json'],
              grasps.name, *needles)


def _strict_json(text: str):
  """Decodes ``text``, refusing the NaN / Infinity that Python's json module writes and reads by default."""

  def refuse(constant):
    raise AssertionError(f'not strict JSON: {constant}')

  return json.loads(text, parse_constant=refuse)


# --- W1: a width in the wrong unit ------------------------------------------------------------------------------------


def test_width_outside_the_grippers_range_is_refused(tmp_path, capsys, monkeypatch):
  monkeypatch.setattr(quality_cli, 'load_object_model', _never)
  monkeypatch.setattr(quality_cli, 'evaluate_report', _never)
  metres = _grasp_file(tmp_path / 'metres.json', _grasp(), _grasp(width=5))  # 5 m on a 5 cm gripper
  _quality_bad(capsys, tmp_path, metres, 'grasps[1]', "'width'", 'is 5', '[0, 0.05]')
  assert not (tmp_path / 'out.json').exists()


# --- W2: booleans are not numbers -------------------------------------------------------------------------------------


@pytest.mark.parametrize('field, value', [('center', [True, 0, 0.02]), ('axis', [1, False, 0]), ('width', True)])
def test_booleans_in_grasp_files_are_refused(tmp_path, capsys, monkeypatch, field, value):
  monkeypatch.setattr(quality_cli, 'load_object_model', _never)
  grasps = _grasp_file(tmp_path / 'bools.json', _grasp(**{field: value}))
  _quality_bad(capsys, tmp_path, grasps, 'grasps[0]', f"'{field}'", 'boolean', 'expected a number')


# --- W3: non-finite and absurd magnitudes; the report is strict JSON --------------------------------------------------


@pytest.mark.parametrize('center_text, shown', [('1e308', '1e+308'), ('1e400', 'non-finite'), ('NaN', 'non-finite'),
                                                ('-Infinity', 'non-finite'), ('1' + '0' * 400, '400 digits')])
def test_non_finite_and_huge_grasp_numbers_are_refused(tmp_path, capsys, monkeypatch, center_text, shown):
  monkeypatch.setattr(quality_cli, 'load_object_model', _never)
  grasps = tmp_path / 'huge.json'
  grasps.write_text('{"grasps": [{"gripper": "suction", "approach": [0, 0, -1], "center": [%s, 0, 0.02]}]}'
                    % center_text)
  _quality_bad(capsys, tmp_path, grasps, 'grasps[0]', "'center'", shown, f'at most {MAX_GRASP_VALUE:g}')


def test_a_center_far_from_the_object_is_refused(tmp_path, capsys, monkeypatch):
  monkeypatch.setattr(quality_cli, 'load_object_model', lambda *_, **__: types.SimpleNamespace(bounds=CUBE_BOUNDS))
  monkeypatch.setattr(quality_cli, 'evaluate_report', _never)
  grasps = _grasp_file(tmp_path / 'far.json', _grasp(center=[500.0, 0.0, 0.0]))
  _quality_bad(capsys, tmp_path, grasps, 'grasps[0]', "'center'", 'within 10 m')


def test_the_quality_report_is_strict_json(tmp_path, capsys, monkeypatch):
  """A NaN or infinity among the results (which Python's json would write as NaN / Infinity) is written as null."""
  monkeypatch.setattr(quality_cli, 'load_object_model', lambda *_, **__: types.SimpleNamespace(bounds=CUBE_BOUNDS))
  monkeypatch.setattr(quality_cli, 'object_summary', lambda model, mesh: {'mesh': mesh, 'extent': float('inf')})
  monkeypatch.setattr(quality_cli, 'evaluate_report', lambda key, model, grasps, settings: [
      {**_grasp(), 'probability': float('nan'), 'robust': False} for _ in grasps])
  grasps = _grasp_file(tmp_path / 'ok.json', _grasp(width=0.05))  # the largest valid opening is accepted
  out = tmp_path / 'out.json'
  assert quality_cli.main(['builtin:cube', '--grasps', str(grasps), '--out', str(out)]) == cli.OK_EXIT
  report = _strict_json(out.read_text())
  assert report['grasps'][0]['probability'] is None and report['object']['extent'] is None
  capsys.readouterr()


# --- missing paths, folders and devices ------------------------------------------------------------------------------


def test_missing_folder_and_device_paths_are_named_for_quality(tmp_path, capsys, monkeypatch):
  monkeypatch.setattr(quality_cli, 'load_object_model', _never)
  (tmp_path / 'meshes').mkdir()
  for mesh, words in ((tmp_path / 'no_such.obj', 'does not exist'), (tmp_path / 'no_such', 'does not exist'),
                      (tmp_path / 'meshes', 'is a folder, expected a mesh file'),
                      ('/dev/null', 'is not a regular file')):
    line = _bad(capsys, quality_cli.main, [mesh, '--gripper', 'suction', '--out', tmp_path / 'out.json'],
                mesh, words)
    assert 'unsupported' not in line, line


def test_missing_and_device_paths_are_named_for_sim_settle(tmp_path, capsys, monkeypatch):
  monkeypatch.setattr(sim_cli, 'load_object_set', _never)
  for source, words in ((tmp_path / 'no_such', 'does not exist'), ('/dev/null', 'is not a regular file')):
    line = _bad(capsys, sim_cli.main, ['settle', 'builtin:all', source, '--heaps', '1'], source, words)
    assert 'unsupported' not in line, line


def test_missing_and_device_paths_are_named_for_benchmark(tmp_path, capsys):
  for source, words in ((tmp_path / 'no_such', 'does not exist'), ('/dev/null', 'is not a regular file')):
    line = _bad(capsys, benchmark_main, ['--policy', 'random', '--objects', source, '--out', tmp_path / 'bench'],
                source, words)
    assert 'unsupported' not in line, line
  assert not (tmp_path / 'bench').exists()


# --- unknown built-in names -------------------------------------------------------------------------------------------


def test_unknown_builtin_names_list_the_valid_ones(tmp_path, capsys, monkeypatch):
  monkeypatch.setattr(quality_cli, 'load_object_model', _never)
  valid = [f'builtin:{name}' for name in BUILTIN_OBJECTS]
  line = _bad(capsys, quality_cli.main, ['builtin:nosuch', '--gripper', 'suction', '--out', tmp_path / 'o.json'],
              'nosuch', *valid)
  assert 'builtin.py' not in line, line
  (rejection,) = load_object_set(['builtin:nosuch']).rejected
  assert rejection.file == 'builtin:nosuch' and 'builtin.py' not in rejection.reason
  assert all(name in rejection.reason for name in (*valid, 'builtin:all', 'builtin:level2')), rejection.reason
  line = _bad(capsys, benchmark_main, ['--policy', 'random', '--objects', 'builtin:nosuch', '--out',
                                       tmp_path / 'bench'], 'nosuch', *valid)
  assert 'builtin.py' not in line, line


# --- H1: procedural ranges too large to list --------------------------------------------------------------------------


def test_a_huge_procedural_range_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
  monkeypatch.setattr(sets_module, 'procedural_spec', _never)  # no spec listed, so no mesh built either
  monkeypatch.setattr(sets_module, 'resolve_mesh', _never)
  monkeypatch.setattr(sim_cli, 'load_object_set', _never)
  for main, argv in ((sim_cli.main, ['settle', HUGE_RANGE, '--heaps', '1']),
                     (benchmark_main, ['--policy', 'random', '--objects', HUGE_RANGE, '--out', tmp_path / 'bench'])):
    start = time.perf_counter()
    _bad(capsys, main, argv, HUGE_RANGE, 'names 99999999999 objects', f'at most {MAX_RANGE_COUNT}')
    assert time.perf_counter() - start < 5.0
  assert not (tmp_path / 'bench').exists()


def test_range_limits_hold_per_range_per_set_and_for_long_digits(monkeypatch):
  half = f'procedural:L2/0:{MAX_RANGE_COUNT // 2 + 1}'
  with pytest.raises(ValueError, match=f'brings the set to {MAX_RANGE_COUNT + 2} objects'):
    expand_object_sources([half, half])  # the first half is listed, the second refused before listing
  monkeypatch.setattr(sets_module, 'procedural_spec', _never)
  with pytest.raises(ValueError, match=r'names about 10\^3999 objects'):
    expand_object_sources(['procedural:L1/0:1' + '0' * 3999])
  with pytest.raises(ValueError, match=f'MAX_RANGE_COUNT = {MAX_RANGE_COUNT}'):
    procedural_specs(1, MAX_RANGE_COUNT + 1)
  with pytest.raises(ValueError, match=r'\(5015 characters\)'):  # too long for int(): named, not a bare ValueError
    parse_procedural_spec('procedural:L1/' + '1' * 5001)


def test_sizes_that_would_exhaust_memory_are_refused_before_any_work(tmp_path, capsys, monkeypatch):
  """--grid-size, --num-grasps and --samples have documented upper bounds (a 1e5 grid asked for 7 PiB, 1e8 grasps
  for 80 GB, 1e9 samples overflowed an int32), checked before the mesh is loaded."""
  monkeypatch.setattr(quality_cli, 'load_object_model', _never, raising=False)
  out = tmp_path / 'q.json'
  base = ['builtin:box', '--gripper', 'suction', '--out', out]
  _bad(capsys, quality_cli.main, [*base, '--grid-size', 100_000], '--grid-size', str(quality_cli.MAX_GRID_SIZE))
  _bad(capsys, quality_cli.main, [*base, '--num-grasps', 100_000_000], '--num-grasps',
       str(quality_cli.MAX_NUM_GRASPS))
  _bad(capsys, quality_cli.main, [*base, '--samples', 1_000_000_000], '--samples', str(quality_cli.MAX_SAMPLES))
  _bad(capsys, quality_cli.main, [*base, '--samples', 10_000, '--num-grasps', 10_000], '--samples',
       'grasp samples')
  assert not out.exists()


def test_a_json_grasp_file_with_a_key_given_twice_is_refused(tmp_path, capsys):
  """JSON would keep the last value of a duplicated key silently (the sweep's centre [5, 5, 5]); like YAML
  configs, the grasp file is refused, naming the key."""
  path = tmp_path / 'dup.json'
  path.write_text('{"grasps": [{"gripper": "parallel_jaw", "center": [0, 0, 0.02], "center": [5, 5, 5], '
                  '"axis": [1, 0, 0], "approach": [0, 0, -1], "width": 0.05}]}')
  _bad(capsys, quality_cli.main, ['builtin:box', '--grasps', path, '--out', tmp_path / 'q.json'], 'dup.json',
       "duplicate key 'center'")
