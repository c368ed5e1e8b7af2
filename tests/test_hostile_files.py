"""Hostile structured input files (issue 44): configs, grasp files and camera / intrinsics files that are deeply
nested, hold duplicate YAML keys, are malformed, write numbers YAML reads as strings, ask for images larger than
the renderer can make or put the principal point outside the image. Every reader refuses them through
`dexjax.config.parse_yaml` / `parse_json` with one ``error:`` line naming the file (and the line, field and
expected value), exit code 2, never a traceback.

The CLIs run in-process through ``main(argv)``; every case fails before any rendering or model compilation.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cli_checks import never, one_error_line
from dexjax import cli
from dexjax.benchmark import main as benchmark_main
from dexjax.config import MAX_NESTING, ConfigError, load_yaml, number_hint, parse_json, parse_yaml
from dexjax.generate.__main__ import main as generate_main
from dexjax.plan import main as plan_main
from dexjax.quality.__main__ import main as quality_main
from dexjax.quality.grasp_json import GraspFileError, load_grasp_json
from dexjax.render.__main__ import main as render_main
from dexjax.render.camera import MAX_IMAGE_SIDE
from dexjax.render.intrinsics_io import load_intrinsics
from dexjax.train.__main__ import main as train_main

DEEP = 5000  # 15 kB of brackets: past Python's recursion limit in every recursive parser
DEEP_TEXT = '[' * DEEP + ']' * DEEP


@pytest.fixture(autouse=True)
def _cache(cache_dir, monkeypatch):
  monkeypatch.setenv('DEXJAX_CACHE', str(cache_dir))


_never, _bad = never, one_error_line  # tests/cli_checks.py


def _write(path: Path, text: str) -> Path:
  path.write_text(text)
  return path


def _intrinsics(path: Path, **fields) -> Path:
  data = {'fx': 500.0, 'fy': 500.0, 'cx': 250.0, 'cy': 250.0, 'width': 500, 'height': 500, **fields}
  return _write(path, json.dumps(data))


# --- T1: deep nesting ------------------------------------------------------------------------------------------------


def test_deeply_nested_files_are_refused_by_every_cli(tmp_path, capsys, monkeypatch):
  import dexjax.quality.__main__ as quality_cli
  import dexjax.render.__main__ as render_cli
  monkeypatch.setattr(quality_cli, 'load_object_model', _never)
  monkeypatch.setattr(render_cli, 'load_object_set', _never)
  deep_yaml = _write(tmp_path / 'deep.yaml', f'grippers: {DEEP_TEXT}\n')
  deep_grasps = _write(tmp_path / 'grasps.json', f'{{"grasps": {DEEP_TEXT}}}')
  deep_camera = _write(tmp_path / 'camera.json', f'{{"fx": {DEEP_TEXT}}}')
  deep_camera_yaml = _write(tmp_path / 'camera.yaml', f'fx: {DEEP_TEXT}\n')
  deep_pose = _write(tmp_path / 'pose.json', DEEP_TEXT)
  _intrinsics(tmp_path / 'K.json')
  np.save(tmp_path / 'depth.npy', np.full((500, 500), 0.7, np.float32))
  out, gen, run = tmp_path / 'o.json', tmp_path / 'gen', tmp_path / 'run'
  too_deep = f'nested deeper than {MAX_NESTING} levels'
  cases = [
      (quality_main, ['builtin:cube', '--gripper', 'suction', '--config', deep_yaml, '--out', out], deep_yaml),
      (quality_main, ['builtin:cube', '--grasps', deep_grasps, '--out', out], deep_grasps),
      (generate_main, ['--config', deep_yaml, '--out', gen, '--num-images', '1'], deep_yaml),
      (generate_main, ['--camera-config', deep_camera, '--out', gen, '--num-images', '1'], deep_camera),
      (generate_main, ['--camera-config', deep_camera_yaml, '--out', gen, '--num-images', '1'], deep_camera_yaml),
      (train_main, ['--config', deep_yaml, '--data', tmp_path, '--out', run], deep_yaml),
      (plan_main, [tmp_path / 'depth.npy', '--intrinsics', deep_camera, '--model', 'pretrained', '--out', out],
       deep_camera),
      (plan_main, [tmp_path / 'depth.npy', '--intrinsics', tmp_path / 'K.json', '--camera-pose', deep_pose,
                   '--model', 'pretrained', '--out', out], deep_pose),
      (render_main, ['heap', tmp_path / 'd.png', '--camera', deep_camera], deep_camera),
      (benchmark_main, ['--policy', 'random', '--objects', 'builtin:cube', '--out', tmp_path / 'bench', '--config',
                        deep_yaml], deep_yaml),
  ]
  for main, argv, path in cases:
    _bad(capsys, main, argv, path.name, too_deep, 'line 1, column')
  assert not out.exists() and not gen.exists() and not run.exists() and not (tmp_path / 'bench').exists()


def test_a_json_integer_too_long_to_convert_names_the_file():
  """Python refuses to convert integers of more than 4300 digits; the reader names the file instead of raising a
  bare ValueError."""
  with pytest.raises(ConfigError, match='grasps.json.*not usable JSON'):
    parse_json('{"width": ' + '9' * 5000 + '}', 'grasps.json')


def test_deeply_nested_files_are_refused_by_the_library_readers(tmp_path):
  deep_json = _write(tmp_path / 'deep.json', DEEP_TEXT)
  with pytest.raises(GraspFileError, match=rf'deep.json: line 1, column {MAX_NESTING + 1}: lists or mappings nested'):
    load_grasp_json(deep_json)
  with pytest.raises(ConfigError, match=r'deep.yaml: line 1, column \d+: lists or mappings nested deeper'):
    load_yaml(_write(tmp_path / 'deep.yaml', f'a: {DEEP_TEXT}'))
  with pytest.raises(ValueError, match=r'k.json: expected a JSON mapping of camera fields, could not parse it: line 1, '
                                       r'column 193: lists or mappings nested deeper'):
    load_intrinsics(_write(tmp_path / 'k.json', '{"K": ' + '{"a": ' * DEEP + '1' + '}' * DEEP + '}'))
  # brackets inside strings do not count; the limit itself is accepted
  assert parse_json('{"a": "' + '[' * 100 + '"}', 'x.json') == {'a': '[' * 100}
  assert json.dumps(parse_json('[' * MAX_NESTING + ']' * MAX_NESTING, 'x.json')) == DEEP_TEXT[DEEP - MAX_NESTING:
                                                                                             DEEP + MAX_NESTING]
  with pytest.raises(ConfigError, match=rf'x.json: line 1, column {MAX_NESTING + 1}: lists or mappings nested'):
    parse_json('[' * (MAX_NESTING + 1) + ']' * (MAX_NESTING + 1), 'x.json')
  parse_yaml('a: ' + '[' * (MAX_NESTING - 1) + ']' * (MAX_NESTING - 1), 'x.yaml')
  with pytest.raises(ConfigError, match='nested deeper'):
    parse_yaml('a: ' + '[' * MAX_NESTING + ']' * MAX_NESTING, 'x.yaml')
  # YAML aliases: a list containing itself, and a few lines expanding to 9^9 values ("billion laughs")
  with pytest.raises(ConfigError, match=r'r.yaml: line 1, column 11: the alias \*x refers to a list'):
    parse_yaml('a: &x [1, *x]\n', 'r.yaml')
  laughs = 'a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]\n' + ''.join(
      f'a{i}: &a{i} [{", ".join([f"*a{i - 1}"] * 9)}]\n' for i in range(1, 9))
  with pytest.raises(ConfigError, match=r'expands to more than 1,000,000 values through aliases'):
    parse_yaml(laughs, 'lol.yaml')
  # an existing output file that is deeply nested JSON is not the command's own: refused, no RecursionError
  with pytest.raises(cli.OutputError, match='was not written by this command'):
    cli.check_output_file(deep_json, owned=cli.owned_json('grasps'))


def test_deeply_nested_run_records_and_shard_meta_are_unreadable(tmp_path):
  """A generation run's ``config.json`` and a shard's JSON meta are read by `dexjax.config.parse_json`: nested
  thousands deep, they are not the run's own (no RecursionError)."""
  from dexjax.data.shards import ShardError, read_shard  # pylint: disable=import-outside-toplevel
  from dexjax.generate.run import load_run_config  # pylint: disable=import-outside-toplevel
  _write(tmp_path / 'config.json', DEEP_TEXT)
  with pytest.raises(FileNotFoundError, match='config.json: no run config record'):
    load_run_config(tmp_path)
  np.savez(tmp_path / 'shard.npz', __meta__=np.array(DEEP_TEXT))
  with pytest.raises(ShardError, match=r"field '__meta__': expected JSON, got line 1, column \d+: lists or mappings "
                                       'nested deeper'):
    read_shard(tmp_path / 'shard.npz')
  np.savez(tmp_path / 'list.npz', __meta__=np.array('[1, 2]'))  # JSON, but not an object
  with pytest.raises(ShardError, match=r"field '__meta__': expected a JSON object, got a list"):
    read_shard(tmp_path / 'list.npz')


def test_a_resumed_run_with_a_deeply_nested_config_record_is_refused(tmp_path):
  from dexjax.train.config import TrainConfig
  from dexjax.train.run import CONFIG_FILE, _check_resume_config  # pylint: disable=protected-access
  _write(tmp_path / CONFIG_FILE, f'loop: {DEEP_TEXT}\n')
  with pytest.raises(ConfigError, match=r'config.yaml: line 1, column \d+: not a readable run config \(lists or '
                                        r'mappings nested deeper'):
    _check_resume_config(tmp_path, TrainConfig())


# --- W4: duplicate keys; one-line YAML errors; numbers YAML reads as strings -----------------------------------------


def test_duplicate_yaml_keys_are_refused_naming_key_and_line(tmp_path, capsys):
  config = _write(tmp_path / 'gripper.yaml', 'grippers:\n  suction:\n    cup_radius: 0.01\n    cup_radius: 0.02\n')
  _bad(capsys, quality_main, ['builtin:cube', '--gripper', 'suction', '--config', config, '--out', tmp_path / 'o.json'],
       'gripper.yaml', 'line 4, column 5', "duplicate key 'cup_radius' (first at line 3)")
  camera = _write(tmp_path / 'camera.yaml', 'fx: 500.0\nfy: 500.0\ncx: 250.0\ncy: 250.0\nwidth: 500\nheight: 500\n'
                                            'fx: 600.0\n')
  _bad(capsys, generate_main, ['--camera-config', camera, '--out', tmp_path / 'gen', '--num-images', '1'],
       'camera.yaml', "duplicate key 'fx'", 'line 7')
  # the same key in different mappings, and a merge key overridden, are fine
  assert parse_yaml('a: {x: 1}\nb: {x: 2}\nc: &c {y: 1}\nd: {<<: *c, y: 2}\n', 'ok.yaml')['d'] == {'y': 2}


def test_malformed_yaml_is_one_line_with_line_and_column(tmp_path, capsys):
  config = _write(tmp_path / 'broken.yaml', 'grippers: {suction: {cup_radius: 0.01}\nperturbations: 3\n')
  line = _bad(capsys, quality_main, ['builtin:cube', '--gripper', 'suction', '--config', config, '--out',
                                     tmp_path / 'o.json'], 'broken.yaml: line 2, column', 'not valid YAML')
  assert 'while parsing a flow mapping at line 1, column 11' in line
  with pytest.raises(ConfigError, match=r'^nul.yaml: character 4: not valid YAML: unacceptable character #x0000'):
    parse_yaml('a: \0', 'nul.yaml')


def test_numbers_yaml_reads_as_strings_get_the_hint(tmp_path, capsys):
  config = _write(tmp_path / 'wide.yaml', 'grippers:\n  parallel_jaw:\n    max_width: 1e9\n')
  _bad(capsys, quality_main, ['builtin:cube', '--gripper', 'parallel_jaw', '--config', config, '--out',
                              tmp_path / 'o.json'],
       'wide.yaml', 'grippers.parallel_jaw.max_width', "got '1e9'", 'write 1.0e+9')
  assert 'write 2.5e-3' in number_hint('2.5E-3') and 'write -1.0e+5' in number_hint('-1e5')
  assert number_hint('abc') == number_hint('1e999') == number_hint(3.0) == ''
  assert parse_yaml('x: 1.0e+9', 'x.yaml') == {'x': 1e9}  # the hint's spelling is a number
  camera = _intrinsics(tmp_path / 'k.yaml')
  camera.write_text('fx: 5.75e2\nfy: 575.0\ncx: 250.0\ncy: 250.0\nwidth: 500\nheight: 500\n')
  with pytest.raises(ValueError, match=r"k.yaml: fx: .*got '5.75e2' \(YAML 1.1 reads 5.75e2 as a string; write "
                                       r"5.75e\+2\)"):
    load_intrinsics(camera)


# --- T2: image size; the principal point --------------------------------------------------------------------------


def test_image_size_is_limited_when_the_camera_file_is_read(tmp_path, capsys, monkeypatch):
  import dexjax.render.__main__ as render_cli
  monkeypatch.setattr(render_cli, 'load_object_set', _never)
  monkeypatch.setattr(render_cli, 'DepthRenderer', _never)
  huge = _intrinsics(tmp_path / 'huge.json', width=50_000, height=50_000, cx=25_000.0, cy=25_000.0)
  _bad(capsys, render_main, ['heap', tmp_path / 'd.png', '--camera', huge], 'huge.json', 'width',
       f'at most {MAX_IMAGE_SIDE}', '50000')
  _bad(capsys, generate_main, ['--camera-config', huge, '--out', tmp_path / 'gen', '--num-images', '1'],
       'huge.json', 'width', f'at most {MAX_IMAGE_SIDE}')
  ranges = _write(tmp_path / 'ranges.yaml', 'width: 500\nheight: 50000\n')
  _bad(capsys, generate_main, ['--camera-config', ranges, '--out', tmp_path / 'gen', '--num-images', '1'],
       'ranges.yaml', 'height', f'at most {MAX_IMAGE_SIDE}')
  np.save(tmp_path / 'depth.npy', np.full((8, 8), 0.7, np.float32))
  _bad(capsys, plan_main, [tmp_path / 'depth.npy', '--intrinsics', huge, '--model', 'pretrained', '--out',
                           tmp_path / 'p.json'], 'huge.json', 'width', f'at most {MAX_IMAGE_SIDE}')
  config = _write(tmp_path / 'big.yaml', 'camera:\n  width: 50000\n')  # a generate config's camera section
  _bad(capsys, generate_main, ['--config', config, '--out', tmp_path / 'gen', '--num-images', '1'],
       'big.yaml', 'width', f'at most {MAX_IMAGE_SIDE}')
  assert load_intrinsics(_intrinsics(tmp_path / 'max.json', width=MAX_IMAGE_SIDE)).width == MAX_IMAGE_SIDE
  assert not (tmp_path / 'gen').exists() and not (tmp_path / 'd.png').exists()


def test_principal_point_outside_the_image_names_the_field(tmp_path, capsys, monkeypatch):
  import dexjax.render.__main__ as render_cli
  monkeypatch.setattr(render_cli, 'load_object_set', _never)
  far_cx = _intrinsics(tmp_path / 'cx.json', cx=99999)
  line = _bad(capsys, render_main, ['heap', tmp_path / 'd.png', '--camera', far_cx], 'cx.json: cx:',
              '[0, width = 500]', '99999')
  assert 'position' not in line and 'rotation' not in line
  ros = _write(tmp_path / 'ros.yaml', 'width: 640\nheight: 480\nK: [500.0, 0.0, 320.0, 0.0, 500.0, -7.0, 0.0, 0.0, '
                                      '1.0]\n')
  with pytest.raises(ValueError, match=r'ros.yaml: K\[5\] \(cy\): expected a number in \[0, height = 480\]'):
    load_intrinsics(ros)
