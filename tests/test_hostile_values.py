"""Hostile values (issue 44): grasp files with a width in the wrong unit, booleans for numbers, non-finite or
absurd magnitudes; object paths that do not exist, are folders or devices; unknown ``builtin:`` names; procedural
ranges too large to list; config numbers beyond their documented limits (counts that size arrays or loops,
physical sizes, forces, friction); options and camera fields named as the user wrote them. Every case is one
``error:`` line naming the file or source, the field and the expected value, exit code 2, never a traceback
(docs/errors.md), and is refused before any object is built or any grasp rated.

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


# --- second sweep: every config number has a documented upper limit ---------------------------------------------------


def _config(tmp_path: Path, text: str, name: str = 'c.yaml') -> Path:
  path = tmp_path / name
  path.write_text(text)
  return path


@pytest.mark.parametrize('text, field, expected', [
    ('grippers:\n  suction:\n    num_ring_vertices: 1000000000\n', 'grippers.suction.num_ring_vertices',
     'an integer in [3, 1024]'),
    ('grippers:\n  suction:\n    num_ray_steps: 100000\n', 'grippers.suction.num_ray_steps', '[1, 1024]'),
    ('grippers:\n  parallel_jaw:\n    num_cone_edges: 100000\n', 'grippers.parallel_jaw.num_cone_edges', '[3, 1024]'),
    ('grippers:\n  suction:\n    vacuum_force: 1.0e+308\n', 'grippers.suction.vacuum_force',
     '> 0 and <= 100,000 (newtons)'),
    ('grippers:\n  suction:\n    cup_radius: 1.0e+9\n', 'grippers.suction.cup_radius', '> 0 and <= 1 (metres)'),
    ('grippers:\n  parallel_jaw:\n    force_limit: 1.0e+9\n', 'grippers.parallel_jaw.force_limit', '<= 100,000'),
    ('grippers:\n  parallel_jaw:\n    finger_length: 50.0\n', 'grippers.parallel_jaw.finger_length',
     '<= 1 (metres)'),
    ('perturbations:\n  suction:\n    friction_mean: 5.0\n', 'perturbations.suction.friction_mean',
     'friction_range = [0, 1]'),
    ('perturbations:\n  suction:\n    friction_range: [0.0, 5.0]\n', 'perturbations.suction.friction_range[1]',
     '<= 2 (MAX_FRICTION'),
    ('perturbations:\n  parallel_jaw:\n    mass_mean: 1.0e+6\n', 'perturbations.parallel_jaw.mass_mean',
     '<= 1000 (kg)'),
    ('num_samples: 100000000\n', 'num_samples', '[1, 10,000]'),
    ('quality:\n  gravity_acceleration: 1.0e+30\n', 'quality.gravity_acceleration', '<= 1000'),
    ('quality:\n  geometry:\n    disc_rings: 100000\n', 'quality.geometry.disc_rings', '[1, 64]'),
    ('grippers:\n  parallel_jaw:\n    palm_width: 0.9\n    palm_height: 0.9\n    palm_depth: 0.9\n',
     'quality.geometry.spacing', 'collision samples at a spacing of 0.005 m; expected at most 2,000,000'),
])
def test_quality_config_values_have_upper_limits(tmp_path, capsys, monkeypatch, text, field, expected):
  """A count that sizes arrays (1e9 ring vertices: a traceback after 35 s), an absurd force or size (a 1e308 N
  vacuum, a 1e9 m cup: rated as if plausible) or a friction outside its range is refused, naming the file, the
  field and the limit, before the object is even loaded."""
  monkeypatch.setattr(quality_cli, 'load_object_model', _never)
  out = tmp_path / 'q.json'
  _bad(capsys, quality_cli.main, ['builtin:box', '--gripper', 'suction', '--config', _config(tmp_path, text), '--out',
                                  out], f'c.yaml: {field}: ', expected)
  assert not out.exists()


@pytest.mark.parametrize('text, field, expected', [
    ('settle:\n  max_steps: 1000000000000\n', 'settle.max_steps', 'an integer in [1, 100,000] (physics steps'),
    ('bin:\n  wall_height: 1.0e+9\n', 'bin.wall_height', '> 0 and <= 10 (metres)'),
    ('bin:\n  inner_size: [1.0e+9, 0.4]\n', 'bin.inner_size[0]', '<= 10 (metres)'),
    ('objects:\n  grid_size: 100000\n', 'objects.grid_size', 'an integer in [8, 512]'),
    ('heap:\n  max_count: 100000\n', 'heap.max_count', '[min_count = 3, 100]'),
    ('heap:\n  friction_mean: 5.0\n', 'heap.friction_mean', 'friction_range = [0, 1]'),
    ('heap:\n  count_law: binomial\n', 'heap.count_law', "'poisson' or 'uniform'"),
    ('dataset:\n  inpaint_holes: 1\n', 'dataset.inpaint_holes', 'true or false'),
    ('dataset:\n  images_per_shard: 100000000\n', 'dataset.images_per_shard', '[1, 10,000]'),
    ('samplers:\n  suction:\n    num_grasps: 100000000\n', 'samplers.suction.num_grasps', '[1, 10,000]'),
    ('reward:\n  num_samples: 100000000\n', 'reward.num_samples', '[1, 10,000]'),
])
def test_generation_config_values_have_upper_limits(tmp_path, capsys, monkeypatch, text, field, expected):
  """``settle.max_steps: 1e12`` ran for ever (and left a run directory behind), ``bin.wall_height: 1e9`` generated
  a dataset, ``objects.grid_size: 100000`` was blamed on the object sources: each is now refused before any work,
  naming the field and its limit."""
  import dexjax.generate.run as generate_run
  from dexjax.generate.__main__ import main as generate_main
  monkeypatch.setattr(generate_run, 'generate_dataset', _never)
  out = tmp_path / 'gen'
  line = _bad(capsys, generate_main, ['--config', _config(tmp_path, text), '--out', out, '--num-images', '1',
                                      '--no-preview'], f'c.yaml: {field}: expected', expected)
  assert 'objects.sources' not in line and not out.exists()


@pytest.mark.parametrize('given_as', ['file', 'option'])
def test_training_epochs_follow_one_rule_from_file_and_command_line(tmp_path, capsys, given_as):
  """``loop.epochs: -3`` in a file said ">= 0" while ``0`` (and ``--epochs -3``) said ">= 1": one rule now."""
  from dexjax.train.__main__ import main as train_main
  for epochs in (-3, 0, 10**6):
    config = _config(tmp_path, f'loop:\n  epochs: {epochs}\n', 'train.yaml')
    given, where = (['--config', config], 'train.yaml') if given_as == 'file' else (['--epochs', epochs], '--epochs')
    _bad(capsys, train_main, [*given, '--data', tmp_path, '--out', tmp_path / 'run', '--no-progress'],
         f'{where}: loop.epochs: expected an integer in [1, 10,000]', f'got {epochs}')
  assert not (tmp_path / 'run').exists()


# --- second sweep: messages name the option and the file, not library internals ---------------------------------------


def test_objects_options_are_named_as_options(tmp_path, capsys, monkeypatch):
  """``--max-hulls 0`` said ``collision_hulls: max_hulls``, ``--scale -1`` ``load_object_set: scale``."""
  import dexjax.objects.__main__ as objects_cli
  monkeypatch.setattr(objects_cli, 'resolve_mesh', _never)
  monkeypatch.setattr(sets_module, 'load_object_set', _never)
  for argv, option, expected in [(['hulls', 'builtin:box', '--max-hulls', 0], '--max-hulls', '[1, 1024]'),
                                 (['hulls', 'builtin:box', '--max-vertices', 10**9], '--max-vertices', '[4, 1024]'),
                                 (['hulls', 'builtin:box', '--scale', 'nan'], '--scale', '> 0'),
                                 (['masses', 'builtin:box', '--scale', -1], '--scale', '> 0'),
                                 (['pickable', 'builtin:box', '--drops', 0], '--drops', '[1, 1024]'),
                                 (['pickable', 'builtin:box', '--attempts', 76], '--attempts', '[1, 75]'),
                                 (['pickable', 'builtin:box', '--seed', -1], '--seed', '>= 0')]:
    line = _bad(capsys, objects_cli.main, argv, f'error: {option}: expected', expected)
    assert 'collision_hulls' not in line and 'load_object_set' not in line, line


def test_camera_file_focal_lengths_are_bounded_before_rendering(tmp_path, capsys, monkeypatch):
  """``fx: 1e300`` overflowed to ``inf`` and was reported after 9 s of work without the file name; it is now refused
  when the file is read, naming the file and the field (render, plan and generate read it alike)."""
  import dexjax.render.__main__ as render_cli
  from dexjax.generate.__main__ import main as generate_main
  from dexjax.plan import main as plan_main
  monkeypatch.setattr(render_cli, 'load_object_set', _never)
  depth = tmp_path / 'd.npy'
  np.save(depth, np.full((200, 200), 0.7, np.float32))
  for fields, shown in (({'fx': 1e300, 'fy': 500.0}, 'fx'), ({'fx': 500.0, 'fy': 2e6}, 'fy')):
    camera = tmp_path / 'k.json'
    camera.write_text(json.dumps({**fields, 'cx': 100, 'cy': 100, 'width': 200, 'height': 200}))
    needles = ('k.json', f'{shown}: expected a finite number > 0 and <= 1e+06 (pixels')
    _bad(capsys, render_cli.main, ['heap', tmp_path / 'r.png', '--camera', camera], *needles)
    _bad(capsys, plan_main, [depth, '--intrinsics', camera, '--policy', 'suction_heuristic', '--out',
                             tmp_path / 'p.json'], *needles)
    _bad(capsys, generate_main, ['--camera-config', camera, '--out', tmp_path / 'gen', '--num-images', '1'], *needles)
  assert sorted(p.name for p in tmp_path.iterdir()) == ['d.npy', 'k.json']


def test_sim_options_are_bounded_and_named_before_any_work(tmp_path, capsys, monkeypatch):
  """``settle --heaps 1000000000`` ran for minutes, ``settle --scale -1`` said ``load_object_set: scale`` and
  ``preview --levels 7`` blamed the internal source ``procedural:L7/0:12@0``: each names its option now."""
  monkeypatch.setattr(sim_cli, 'load_object_set', _never)
  monkeypatch.setattr(sim_cli, 'check_object_sources', _never)
  _bad(capsys, sim_cli.main, ['settle', 'procedural:L1/0:3', '--heaps', 10**9], '--heaps', '[1, 100,000]')
  _bad(capsys, sim_cli.main, ['settle', 'procedural:L1/0:3', '--scale', -1], '--scale', '> 0')
  line = _bad(capsys, sim_cli.main, ['preview', tmp_path / 'p.png', '--levels', 7], '--levels', '1, 2 and 3', 'got 7')
  assert 'procedural:' not in line and not (tmp_path / 'p.png').exists()
