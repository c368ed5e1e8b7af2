"""Bad input and faults as a user meets them, one test per failure class (docs/errors.md): every CLI reports
through one helper (exit 2, ``error:`` naming file and field, no traceback); outputs are checked before any
computing and never clobber files the command did not write; configs are checked across fields; implausible
mesh scales warn; a camera that cannot see the bin is an error; training that cannot learn fails before writing
a "best" model; ``--resume`` needs a run; disk-full errors name the file and lose nothing; workers die with their
parent.

The CLIs run in-process through ``main(argv)`` (shared imports, no compile: every case here fails before the
numerical work); subprocesses only where the behaviour needs one (no traceback at the interpreter's exit, SIGKILL).
"""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh

from dexjax import cli
from dexjax.config import ConfigError, validate_heap_distribution, validate_perturbations
from dexjax.evaluate import main as evaluate_main
from dexjax.rounds import main as rounds_main
from dexjax.replay import main as replay_main
from dexjax.generate.__main__ import main as generate_main
from dexjax.objects.__main__ import main as objects_main
from dexjax.quality.__main__ import main as quality_main
from dexjax.render.__main__ import main as render_main
from dexjax.sim.__main__ import main as sim_main
from dexjax.train.__main__ import main as train_main

sys.path.insert(0, os.path.dirname(__file__))
from cli_checks import digests, never, one_error_line  # pylint: disable=g-import-not-at-top,wrong-import-position
from test_train_loop import _write_dataset  # pylint: disable=g-import-not-at-top,wrong-import-position

BINARY = bytes(range(256)) * 8  # not UTF-8, not a zip, not a mesh


@pytest.fixture(autouse=True)
def _cache(cache_dir, monkeypatch):
  monkeypatch.setenv('DEXJAX_CACHE', str(cache_dir))


@pytest.fixture
def files(tmp_path) -> dict[str, Path]:
  """Hostile input files, and a user's own files that no command may change."""
  f = {'binary': tmp_path / 'binary.bin', 'user_json': tmp_path / 'mine.json', 'user_png': tmp_path / 'mine.png',
       'user_npz': tmp_path / 'mine.npz', 'dir': tmp_path / 'a_dir'}
  f['binary'].write_bytes(BINARY)
  for key in ('user_json', 'user_png', 'user_npz'):
    f[key].write_text('my own precious file\n')
  f['dir'].mkdir()
  return f


def _bad(capsys, main, argv: list[str], *needles: str, code: int = cli.BAD_INPUT_EXIT) -> str:
  """Runs a CLI in-process on bad input: asserts the exit code, one ``error:`` line naming ``needles``, no
  traceback; returns stderr."""
  assert main([str(a) for a in argv]) == code
  err = capsys.readouterr().err
  assert 'Traceback' not in err and 'error: ' in err, err
  for needle in needles:
    assert str(needle) in err, (needle, err)
  return err


def _never(*_, **__):
  raise AssertionError('computed before the inputs were checked')


# --- one helper, one set of exit codes ------------------------------------------------------------------------------


@pytest.mark.parametrize('main', [quality_main, objects_main, sim_main, render_main, generate_main, train_main,
                                  evaluate_main, rounds_main, replay_main])
def test_every_cli_reports_through_the_shared_helper(main):
  assert getattr(main, '__wrapped__', None) is not None  # dexjax.cli.command


def test_command_maps_error_classes_to_exit_codes(capsys, monkeypatch):
  from dexjax.data.shards import ShardError
  from dexjax.geometry.mesh_io import MeshError
  for error, needle in [(ConfigError('c.yaml', 'a.b', 'expected 1, got 2'), 'c.yaml: a.b: expected 1'),
                        (MeshError('m.obj', 'empty file'), "mesh 'm.obj': empty file"),
                        (ShardError("shard 's.npz': corrupt"), 's.npz'),
                        (OSError(errno.ENOSPC, 'No space left on device', 'out/x.npz'), 'out/x.npz: No space left'),
                        (PermissionError(errno.EACCES, 'Permission denied', '/ro/x'), '/ro/x: Permission denied'),
                        (ValueError('--heaps: expected an integer >= 1, got 0'), '--heaps')]:

    @cli.command
    def main(argv, error=error):
      raise error

    assert main([]) == 2
    err = capsys.readouterr().err
    assert err.startswith('error: ') and needle in err and 'Traceback' not in err, err

  @cli.command
  def interrupted(argv):
    raise KeyboardInterrupt

  assert interrupted([]) == cli.INTERRUPTED_EXIT
  assert capsys.readouterr().err == 'error: interrupted\n'

  @cli.command
  def bug(argv):
    raise KeyError('a bug keeps its traceback')

  with pytest.raises(KeyError):
    bug([])
  monkeypatch.setenv(cli.DEBUG_ENV_VAR, '1')

  @cli.command
  def debug(argv):
    raise ValueError('shown with a traceback')

  with pytest.raises(ValueError):
    debug([])


def test_module_entry_point_exits_2_without_traceback(tmp_path, cache_dir):
  """The issue's first command, as a user runs it: one ``error:`` line, exit 2, before any computing (the other
  CLIs share the helper; they are run in-process below)."""
  argv = ['-m', 'dexjax.quality', 'builtin:box', '--gripper', 'suction', '--num-grasps', '2', '--out',
          'missing_dir/o.json']
  start = time.perf_counter()
  r = subprocess.run([sys.executable, *argv], capture_output=True, text=True, cwd=tmp_path, timeout=300,
                     env={**os.environ, 'DEXJAX_CACHE': str(cache_dir)})
  assert r.returncode == 2, r.stderr
  assert 'Traceback' not in r.stderr and 'missing_dir' in r.stderr and 'does not exist' in r.stderr
  assert time.perf_counter() - start < 120  # no labelling or settling ran


# --- outputs: checked before computing, never clobbering ------------------------------------------------------------


def test_output_file_rules(tmp_path, monkeypatch):
  own = tmp_path / 'report.json'
  own.write_text(json.dumps({'object': {}, 'parameters': {}, 'grasps': []}))
  owned = cli.owned_json('object', 'parameters', 'grasps')
  assert cli.check_output_file(own, owned=owned) == own  # the command's own earlier output
  user = tmp_path / 'user.json'
  user.write_text('{"mine": 1}')
  with pytest.raises(cli.OutputError, match=r"--out: '.*user.json': exists and was not written.*--overwrite"):
    cli.check_output_file(user, owned=owned)
  assert cli.check_output_file(user, owned=owned, overwrite=True) == user
  with pytest.raises(cli.OutputError, match='is a directory'):
    cli.check_output_file(tmp_path)
  with pytest.raises(cli.OutputError, match=r"the directory '.*missing' does not exist"):
    cli.check_output_file(tmp_path / 'missing' / 'o.json')
  with pytest.raises(cli.OutputError, match='is also the OUT.png output'):
    cli.check_distinct(('OUT.png', tmp_path / 'a.png'), ('--npz', tmp_path / 'a.png'))

  def read_only(**kw):
    raise PermissionError(errno.EACCES, 'Permission denied', kw.get('dir'))

  monkeypatch.setattr(cli.tempfile, 'TemporaryFile', read_only)  # as a read-only directory looks (even to root)
  with pytest.raises(cli.OutputError, match=r"cannot write in the directory .*Permission denied.*writable"):
    cli.check_output_file(tmp_path / 'new.json')
  with pytest.raises(cli.OutputError, match='writable directory'):
    cli.check_output_dir(tmp_path / 'new_dir' / 'deeper')


def test_pngs_dexjax_writes_are_recognised_as_its_own(tmp_path):
  import matplotlib
  matplotlib.use('Agg')
  from matplotlib.figure import Figure
  from dexjax.render.preview import save_depth_png
  from dexjax.render.rendering import DepthImage
  mine = tmp_path / 'depth.png'
  save_depth_png(mine, DepthImage(depth=np.ones((8, 8), np.float32), mask=np.zeros((8, 8), np.int32), backend='x'))
  assert cli.is_dexjax_png(mine)
  plain = tmp_path / 'plot.png'
  Figure().savefig(plain)
  before = plain.read_bytes()
  assert not cli.is_dexjax_png(plain)
  cli.stamp_png(plain, 'test')
  assert cli.is_dexjax_png(plain) and plain.read_bytes().startswith(before[:33])  # signature and IHDR kept
  from PIL import Image
  with Image.open(plain) as image:
    image.load()
    assert image.text['dexjax'] == 'test'


def test_file_outputs_are_checked_before_computing(files, tmp_path, capsys, monkeypatch):
  import dexjax.quality.__main__ as quality_cli
  import dexjax.render.__main__ as render_cli
  import dexjax.sim.__main__ as sim_cli
  monkeypatch.setattr(quality_cli, 'load_object_model', _never)
  monkeypatch.setattr(sim_cli, 'load_object_set', _never)
  monkeypatch.setattr(render_cli, 'load_object_set', _never)
  monkeypatch.setattr(render_cli, 'sample_camera', _never)
  before = digests(tmp_path)
  q = ['builtin:cube', '--gripper', 'suction', '--num-grasps', '2', '--out']
  for main, argv, option in [
      (quality_main, q, '--out'),
      (sim_main, ['settle', 'builtin:all', '--heaps', '1', '--out'], '--out'),
      (render_main, ['heap', '--objects', 'builtin:all', '--npz', tmp_path / 'd.npz', '--'], 'OUT.png'),
      (objects_main, ['--per-level', '1', '--preview'], '--preview')]:
    target = {quality_main: files['user_json'], sim_main: files['user_npz']}.get(main, files['user_png'])
    _bad(capsys, main, [*argv, tmp_path / 'missing_dir' / 'out.x'], option, 'missing_dir', 'does not exist')
    _bad(capsys, main, [*argv, files['dir']], option, 'is a directory')
    _bad(capsys, main, [*argv, target], option, target.name, 'was not written by this command', '--overwrite')
  _bad(capsys, sim_main, ['preview', files['user_png']], 'OUT.png', 'mine.png', 'not written by this command')
  _bad(capsys, render_main, ['heap', tmp_path / 'd.png', '--npz', files['user_npz']], '--npz', 'mine.npz')
  _bad(capsys, render_main, ['heap', tmp_path / 'd.png', '--npz', tmp_path / 'd.png'], 'expected distinct files')
  assert digests(tmp_path) == before  # nothing written, nothing changed


def test_generate_never_clobbers_a_users_files(files, tmp_path, capsys, monkeypatch):
  import dexjax.generate.config as generate_config
  monkeypatch.setattr(generate_config, 'load_generate_config', _never)
  mine = tmp_path / 'my_data'
  mine.mkdir()
  (mine / 'config.json').write_text('{"my": "experiment settings"}')
  (mine / 'preview.png').write_bytes(b'\x89PNG\r\n\x1a\n my picture')
  before = digests(tmp_path)
  _bad(capsys, generate_main, ['--out', mine, '--num-images', '1'], '--out', 'my_data', "'config.json'",
       'did not write')
  (mine / 'config.json').unlink()
  before.pop(str(mine / 'config.json'))
  _bad(capsys, generate_main, ['--out', mine, '--num-images', '1'], "'preview.png'", 'did not write')
  notes = tmp_path / 'notes'
  notes.mkdir()
  (notes / 'notes.txt').write_text('mine')
  before[str(notes / 'notes.txt')] = b'mine'
  _bad(capsys, generate_main, ['--out', notes, '--num-images', '1'], 'is not empty', 'notes.txt',
       'holds no dataset run')
  _bad(capsys, generate_main, ['--out', files['user_json'], '--num-images', '1'], 'is not a directory')
  assert digests(tmp_path) == before


def test_generate_accepts_its_own_run_directory(tmp_path):
  from dexjax.data import MANIFEST_NAME, Manifest
  from dexjax.generate.run import check_run_dir
  assert check_run_dir(tmp_path / 'new' / 'run') == tmp_path / 'new' / 'run'
  run = tmp_path / 'run'
  run.mkdir()
  (run / MANIFEST_NAME).write_text(Manifest('abc', 0, 1).to_json())  # a run's manifest (a '{}' is refused)
  (run / 'config.json').write_text(json.dumps({'fingerprint': 'abc', 'config': {}}))
  (run / 'notes.txt').write_text('a user may keep notes in a run directory: never written')
  (run / 'manifest.lock').touch()
  from matplotlib.figure import Figure
  Figure().savefig(run / 'preview.png', metadata={cli.PNG_MARK: 'test'})  # as save_generation_png marks it
  assert check_run_dir(run) == run
  (run / 'preview.png').write_bytes(b'\x89PNG\r\n\x1a\n')  # not dexjax's
  with pytest.raises(cli.OutputError, match="preview.png"):
    check_run_dir(run)
  assert check_run_dir(run, overwrite=True) == run


# --- files that are not what they claim -----------------------------------------------------------------------------


def test_binary_empty_and_directory_inputs_name_the_file(files, tmp_path, capsys, monkeypatch):
  import dexjax.quality.__main__ as quality_cli
  monkeypatch.setattr(quality_cli, 'load_object_model', _never)
  binary, folder = files['binary'], files['dir']
  out = tmp_path / 'o.json'
  empty = tmp_path / 'empty.json'
  empty.write_text('')
  no_grasps = tmp_path / 'none.json'
  no_grasps.write_text('{"grasps": []}')
  for argv, needles in [
      (['builtin:cube', '--gripper', 'suction', '--config', binary, '--out', out], ('binary.bin', 'not a text file')),
      (['builtin:cube', '--gripper', 'suction', '--config', folder, '--out', out], ('a_dir', 'Is a directory')),
      (['builtin:cube', '--grasps', binary, '--out', out], ('binary.bin', 'not a text file')),
      (['builtin:cube', '--grasps', empty, '--out', out], ('empty.json', 'not valid JSON')),
      (['builtin:cube', '--grasps', no_grasps, '--out', out], ('none.json', 'expected at least one grasp')),
      (['builtin:cube', '--grasps', folder, '--out', out], ('a_dir', 'Is a directory')),
      (['builtin:cube', '--gripper', 'suction', '--threshold', 'nan', '--out', out], ('--threshold', '[0, 1]')),
      (['builtin:cube', '--gripper', 'suction', '--scale', '-1', '--out', out], ('--scale', '> 0'))]:
    _bad(capsys, quality_main, argv, *needles)
  _bad(capsys, generate_main, ['--config', binary, '--out', tmp_path / 'gen', '--num-images', '1'], 'binary.bin',
       'not a text file')
  _bad(capsys, generate_main, ['--camera-config', binary, '--out', tmp_path / 'gen', '--num-images', '1'],
       'binary.bin')
  _bad(capsys, render_main, ['heap', tmp_path / 'd.png', '--camera', binary], 'binary.bin', 'not a text file')
  _bad(capsys, train_main, ['--config', binary, '--data', tmp_path, '--out', tmp_path / 'run'], 'binary.bin')
  _bad(capsys, train_main, ['--data', binary, '--out', tmp_path / 'run', '--no-progress'], 'binary.bin',
       'no dataset shards')
  _bad(capsys, evaluate_main, ['--checkpoint', tmp_path / 'nothing', '--data', binary], 'no dataset shards')
  _bad(capsys, evaluate_main, ['--checkpoint', 'pretrained', '--data', tmp_path, '--resamples', '0'], '--resamples',
       '>= 1')
  _bad(capsys, objects_main, ['hulls', files['binary']], 'binary.bin', code=2)
  _bad(capsys, rounds_main, ['--out', tmp_path / 'rounds', '--rounds', '0', '--images', '4'], '--rounds', '>= 1')
  _bad(capsys, rounds_main, ['--generate-config', binary, '--out', tmp_path / 'rounds', '--rounds', '1', '--images',
                             '4'], 'binary.bin', 'not a text file')
  _bad(capsys, rounds_main, ['--out', tmp_path / 'rounds', '--rounds', '1', '--images', '4', '--base-data',
                             tmp_path / 'no_data'], 'no_data', 'no dataset shards', '--base-data')
  _bad(capsys, generate_main, ['--out', tmp_path / 'gen', '--num-images', '1', '--collection-policy', 'on_policy'],
       'collection.model', "learned policy's GQ-CNNs")
  _bad(capsys, generate_main, ['--out', tmp_path / 'gen', '--num-images', '1', '--model', tmp_path / 'no_run'],
       'no_run')
  assert not (tmp_path / 'rounds').exists()
  assert not (tmp_path / 'gen').exists() and not (tmp_path / 'run').exists() and not out.exists()


def test_binary_data_in_a_text_mesh_format_is_named(files, tmp_path, capsys):
  """A binary file named ``.obj`` (or ``.off``) said "contains no triangle faces"; it is now named as not text."""
  import dexjax.quality.__main__ as quality_cli
  for name in ('garbage.obj', 'garbage.off'):
    mesh = tmp_path / name
    mesh.write_bytes(BINARY[5:])  # starts with 0x05, a control character
    kind = name[-3:].upper()
    needles = (name, f'not a text {kind} file (byte 0 is 0x05: binary data)', 'expected a')
    one_error_line(capsys, quality_cli.main, [mesh, '--gripper', 'suction', '--out', tmp_path / 'q.json'], *needles)
    one_error_line(capsys, objects_main, ['hulls', mesh], *needles)
  latin1 = tmp_path / 'latin1.obj'  # text in an 8-bit encoding is still text
  latin1.write_bytes('# caf\xe9\n'.encode('latin-1') + b'v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n')
  from dexjax.geometry.mesh_io import MeshError, load_mesh
  with pytest.raises(MeshError, match='zero volume'):  # read, then refused for its geometry: not for its bytes
    load_mesh(latin1)
  assert not (tmp_path / 'q.json').exists()


def test_plan_names_the_depth_dtype_and_reads_only_the_pose_of_a_pose_file(tmp_path, capsys, monkeypatch):
  """An int64 depth image went on to "no object pixels" without naming the file; a bad ``--camera-pose`` was blamed
  for a missing ``fx`` (it was read as a whole camera)."""
  import dexjax.policy.preprocess as preprocess
  from dexjax.plan import main as plan_main
  monkeypatch.setattr(preprocess, 'prepare_observation', never)
  intrinsics = tmp_path / 'k.json'
  intrinsics.write_text(json.dumps({'fx': 200.0, 'fy': 200.0, 'cx': 32.0, 'cy': 24.0, 'width': 64, 'height': 48}))
  depth, wide = tmp_path / 'depth.npy', tmp_path / 'wide.npy'
  np.save(depth, np.full((48, 64), 0.7, np.float32))
  np.save(wide, np.full((48, 64), 800, np.int64))  # millimetres, but as np.array of Python ints makes them
  plan = [depth, '--intrinsics', intrinsics, '--policy', 'suction_heuristic', '--out', tmp_path / 'p.json']
  one_error_line(capsys, plan_main, [wide, *plan[1:]], 'wide.npy', 'dtype int64', 'expected a float array of metres',
                 'uint16')
  pose = tmp_path / 'pose.json'
  for data, field in (({'rotation': [[1, 0, 0], [0, 1, 0]], 'position': [0, 0, 1]}, 'rotation'),
                      ({'rotation': np.eye(3).tolist(), 'position': [0, 0, 'x']}, 'position[2]'),
                      ({'position': [0, 0, 1]}, 'rotation: missing field')):
    pose.write_text(json.dumps(data))
    line = one_error_line(capsys, plan_main, [*plan, '--camera-pose', pose], 'pose.json', field)
    assert 'fx' not in line, line
  from dexjax.render.intrinsics_io import load_pose
  pose.write_text(json.dumps({'rotation': np.eye(3).tolist(), 'position': [0.1, 0, 0.7]}))  # no intrinsics needed
  rotation, position = load_pose(pose)
  assert np.allclose(rotation, np.eye(3)) and np.allclose(position, [0.1, 0, 0.7])
  assert not (tmp_path / 'p.json').exists()


# --- configs whose fields contradict each other ---------------------------------------------------------------------


@pytest.mark.parametrize('text, field, expected', [
    ('grippers: {parallel_jaw: {min_width: 0.1, max_width: 0.05}}', 'grippers.parallel_jaw.min_width',
     '[0, max_width = 0.05)'),
    ('perturbations: {suction: {friction_range: [0.9, 0.1]}}', 'perturbations.suction.friction_range[1]',
     'low <= high'),
    ('perturbations: {parallel_jaw: {mass_variance: 0.0}}', 'perturbations.parallel_jaw.mass_variance', '> 0'),
    ('grippers: {suction: {max_strain: 1.5}}', 'grippers.suction.max_strain', '(0, 1)'),
    ('grippers: {suction: {cup_radius: 0.0}}', 'grippers.suction.cup_radius', '> 0'),
    ('perturbations: {suction: {friction_mean: 5.0}}', 'perturbations.suction.friction_mean',
     'in friction_range = [0, 1]'),
])
def test_contradictory_gripper_configs_are_refused(tmp_path, capsys, text, field, expected):
  path = tmp_path / 'gripper.yaml'
  path.write_text(text + '\n')
  _bad(capsys, quality_main, ['builtin:cube', '--gripper', 'suction', '--config', path, '--out', tmp_path / 'o.json'],
       'gripper.yaml', field, expected)
  _bad(capsys, generate_main, ['--gripper-config', path, '--out', tmp_path / 'gen', '--num-images', '1'],
       'gripper.yaml', field, expected)
  assert not (tmp_path / 'o.json').exists() and not (tmp_path / 'gen').exists()


def test_cross_field_rules_of_heaps_perturbations_and_training(tmp_path, capsys):
  from dexjax.quality.robust import parallel_jaw_perturbations
  from dexjax.sim.heap import HeapDistribution
  with pytest.raises(ConfigError, match=r'x.yaml: heap.max_count: expected an integer in \[min_count = 5, 100\]'):
    validate_heap_distribution(HeapDistribution(min_count=5, max_count=3), source='x.yaml')
  with pytest.raises(ConfigError, match=r'heap.friction_range'):
    validate_heap_distribution(HeapDistribution(friction_range=(0.5, 0.5)), source='x.yaml')
  with pytest.raises(ConfigError, match=r'gravity_cone_angle'):
    validate_perturbations(parallel_jaw_perturbations().replace(gravity_cone_angle=4.0))
  validate_heap_distribution(HeapDistribution())
  config = tmp_path / 'heap.yaml'
  config.write_text('heap: {min_count: 6, max_count: 4}\n')
  from dexjax.generate import load_generate_config
  with pytest.raises(ConfigError, match=r'heap.yaml: heap.max_count'):  # the library's loader checks it too
    load_generate_config(config)
  _bad(capsys, generate_main, ['--config', config, '--out', tmp_path / 'gen', '--num-images', '1'], 'heap.yaml',
       'heap.max_count')
  config.write_text('optimizer: {momentum: 1.5}\n')
  _bad(capsys, train_main, ['--config', config, '--data', tmp_path, '--out', tmp_path / 'run'], 'heap.yaml',
       'optimizer.momentum', '[0, 1)')


# --- implausible mesh scales ----------------------------------------------------------------------------------------


def test_implausible_mesh_scale_warns_with_the_hint(tmp_path, capsys):
  from dexjax.geometry.mesh_io import PLAUSIBLE_EXTENT, ScaleWarning, check_scale, load_mesh
  from dexjax.objects import load_object_set
  assert PLAUSIBLE_EXTENT == (0.005, 1.0)
  mm = tmp_path / 'mm' / 'mug.stl'
  mm.parent.mkdir()
  trimesh.creation.box((80.0, 60.0, 100.0)).export(mm)  # a 10 cm box written in millimetres
  # the CLI: a warning line naming file, extent and hint; the object still loads (exit 0)
  assert objects_main(['check', str(mm.parent), '--json']) == 0
  captured = capsys.readouterr()
  assert json.loads(captured.out)['loaded'] == ['mug']
  assert "warning: mesh '" in captured.err and 'mug.stl' in captured.err and '--scale 0.001' in captured.err
  with pytest.warns(ScaleWarning, match=r"mug.stl'.*largest extent 100 m.*--scale 0.001 if the file is in "
                                        r"millimetres"):
    load_mesh(mm)
  with warnings.catch_warnings():
    warnings.simplefilter('error', ScaleWarning)
    assert load_mesh(mm, scale=0.001).extents.max() == pytest.approx(0.1)  # the hint fixes it: no warning
  tiny = tmp_path / 'tiny.stl'
  trimesh.creation.box((0.002, 0.002, 0.002)).export(tiny)
  with pytest.warns(ScaleWarning, match=r'2 mm'):
    load_mesh(tiny)
  # built-in and procedural objects are in metres: never a warning
  report = load_object_set(['builtin:all', 'procedural:L1/0:2', 'procedural:L2/0:2', 'procedural:L3/0:2'])
  assert not report.rejected
  with warnings.catch_warnings():
    warnings.simplefilter('error', ScaleWarning)
    for o in report.loaded:
      check_scale(o.mesh, o.name)


# --- cameras that cannot see the bin --------------------------------------------------------------------------------


def _camera_file(path: Path, rotation, position) -> Path:
  path.write_text(json.dumps({'fx': 60.0, 'fy': 60.0, 'cx': 31.5, 'cy': 23.5, 'width': 64, 'height': 48,
                              'rotation': rotation, 'position': position}))
  return path


def test_camera_below_the_floor_or_looking_away_is_an_error(tmp_path, capsys, monkeypatch):
  import dexjax.render.__main__ as render_cli
  from dexjax.render.rendering import DepthImage
  monkeypatch.setattr(render_cli, 'load_object_set', _never)
  down = [[1, 0, 0], [0, -1, 0], [0, 0, -1]]
  below = _camera_file(tmp_path / 'below.json', down, [0, 0, -0.5])
  away = _camera_file(tmp_path / 'away.json', [[1, 0, 0], [0, 1, 0], [0, 0, 1]], [0, 0, 0.8])
  far = _camera_file(tmp_path / 'far.json', down, [0, 0, 30.0])
  out = tmp_path / 'd.png'
  _bad(capsys, render_main, ['heap', out, '--camera', below], 'below.json', 'position', 'above the floor')
  _bad(capsys, render_main, ['heap', out, '--camera', away], 'away.json', 'rotation', 'looking down')
  _bad(capsys, render_main, ['heap', out, '--camera', far], 'far.json', 'position', 'far depth')
  for camera, field in ((below, 'position'), (away, 'rotation')):
    _bad(capsys, generate_main, ['--camera-config', camera, '--out', tmp_path / 'gen', '--num-images', '1'],
         camera.name, field)
  assert not out.exists() and not (tmp_path / 'gen').exists()
  # whatever else makes a rendered image empty is an error too, not exit 0
  with pytest.raises(ValueError, match=r'cam.json: position, rotation: no pixel'):
    render_cli._check_image(DepthImage(depth=np.full((4, 4), np.nan, np.float32),  # pylint: disable=protected-access
                                       mask=np.full((4, 4), -2, np.int32), backend='x'), 'cam.json')


# --- training that cannot learn, and --resume of something that is not a run ---------------------------------------


def _no_positives(data: Path) -> None:
  from dexjax.data import list_shards, read_shard, write_shard
  for path in list_shards(data):
    shard = read_shard(path)
    rows = dict(shard.rows, reward=np.zeros_like(shard.rows['reward']))
    meta = {k: v for k, v in shard.meta.items() if k not in ('num_images', 'num_rows', 'format_version')}
    write_shard(path, shard.images, rows, meta)


def test_training_that_cannot_learn_fails_before_writing_a_model(tmp_path, capsys):
  config = tmp_path / 'tiny.yaml'
  config.write_text('crop_window: 32\ngrippers: [parallel_jaw]\nsplit: {val_fraction: 0.25}\n'
                    'loop: {epochs: 1, batch_size: 64, normalization_rows: 200}\n')
  small, one_label = tmp_path / 'small', tmp_path / 'one_label'
  _write_dataset(small, num_shards=2, images_per_shard=1)  # 16 parallel-jaw rows: less than a batch of 64
  _write_dataset(one_label, num_shards=4, images_per_shard=8)
  _no_positives(one_label)
  run = tmp_path / 'run'
  _bad(capsys, train_main, ['--config', config, '--data', small, '--out', run, '--no-progress'], 'parallel_jaw',
       'fewer than one batch', 'loop.batch_size = 64')
  assert not run.exists()  # no config, no checkpoints, no "best" model
  _bad(capsys, train_main, ['--config', config, '--data', one_label, '--out', run, '--no-progress'], 'parallel_jaw',
       'no positive (reward 1)')
  assert not run.exists()
  # --resume of a mistyped directory fails instead of starting afresh; a new run needs a new or empty directory
  _bad(capsys, train_main, ['--config', config, '--data', small, '--out', tmp_path / 'runn', '--resume',
                            '--no-progress'], '--out', 'runn', 'not a training run to resume')
  assert not (tmp_path / 'runn').exists()
  _bad(capsys, train_main, ['--config', config, '--data', small, '--out', small, '--no-progress'], '--out',
       'is not empty and holds no training run')
  (run / 'parallel_jaw').mkdir(parents=True)
  (run / 'config.yaml').write_text('grippers: [parallel_jaw]\n')
  _bad(capsys, train_main, ['--config', config, '--data', small, '--out', run, '--no-progress'], 'earlier run',
       '--resume')


# --- disk full ------------------------------------------------------------------------------------------------------


def _disk_full(*_, **__):
  raise OSError(errno.ENOSPC, 'No space left on device')


def test_disk_full_names_the_file_and_keeps_what_was_written(tmp_path, capsys, monkeypatch):
  from dexjax.data.shards import shard_path, write_shard
  import dexjax.data.shards as shards
  from dexjax.geometry.cache import atomic_write_npz, atomic_write_text
  data = tmp_path / 'data'
  _write_dataset(data, num_shards=1, images_per_shard=1)
  shard = shards.read_shard(shard_path(data, 0))
  manifest = tmp_path / 'manifest.json'
  manifest.write_text('{"old": "complete"}')
  before = digests(tmp_path)
  with monkeypatch.context() as m:
    m.setattr(os, 'fsync', _disk_full)
    for write, path in ((lambda p: atomic_write_text(p, 'new'), manifest),
                        (lambda p: atomic_write_npz(p, {'a': np.zeros(3)}), tmp_path / 'model.npz'),
                        (lambda p: cli.atomic_write(p, lambda f: f.write(b'new')), manifest)):
      with pytest.raises(OSError) as e:
        write(path)
      assert e.value.errno == errno.ENOSPC and e.value.filename == os.fspath(path)
  with monkeypatch.context() as m:
    m.setattr(shards, '_write_npz', _disk_full)
    meta = {k: v for k, v in shard.meta.items() if k not in ('num_images', 'num_rows', 'format_version')}
    with pytest.raises(OSError) as e:
      write_shard(shard_path(data, 0), shard.images, shard.rows, meta)
    assert e.value.filename == os.fspath(shard_path(data, 0))
  assert digests(tmp_path) == before  # old files complete, no temporary files left
  assert cli.report_bad_input(e.value) == 2
  err = capsys.readouterr().err
  assert 'shard-000000.npz: No space left on device' in err and 'free some space' in err


def test_disk_full_in_a_cli_keeps_the_earlier_output(tmp_path, capsys, monkeypatch):
  """``sim settle --out``: the earlier (own) output survives a write that fails for lack of space."""
  from dexjax.objects import load_object_set, prepare_object_set
  from dexjax.sim.__main__ import SETTLE_ARRAYS
  prepare_object_set(load_object_set(['builtin:all']), model=False)  # hulls cached before the disk fills up
  out = tmp_path / 'heaps.npz'
  np.savez(out, **{name: np.zeros(1) for name in SETTLE_ARRAYS})  # an earlier output of the command
  earlier = out.read_bytes()
  monkeypatch.setattr(os, 'fsync', _disk_full)
  _bad(capsys, sim_main, ['settle', 'builtin:all', '--heaps', '1', '--json', '--out', out], 'heaps.npz',
       'No space left on device')
  assert out.read_bytes() == earlier and sorted(p.name for p in tmp_path.iterdir()) == ['heaps.npz']


# --- workers die with their parent ----------------------------------------------------------------------------------

_PARENT = '''
import sys
sys.path.insert(0, {here!r})
from slow_task import task
from dexjax.generate.parallel import run_tasks
run_tasks(task, [0, 1], backend='process', workers=2, progress=False)
'''

_TASK = '''
import os, time
def task(index):
  open(os.path.join({here!r}, f'busy-{{os.getpid()}}'), 'w').close()
  time.sleep(600)
  return {{}}
'''


def _alive(pid: int) -> bool:
  try:
    with open(f'/proc/{pid}/stat') as f:
      return f.read().split(')')[-1].split()[0] != 'Z'
  except FileNotFoundError:
    return False


@pytest.mark.heavy
@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='reads /proc')
def test_workers_die_with_their_parent(tmp_path):
  """``--workers 2`` whose parent is killed with SIGKILL mid-run: no worker (~1.6 GB each in a real run) is left."""
  (tmp_path / 'slow_task.py').write_text(_TASK.format(here=str(tmp_path)))
  parent = subprocess.Popen([sys.executable, '-c', _PARENT.format(here=str(tmp_path))],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
  try:
    deadline = time.time() + 240
    while len(list(tmp_path.glob('busy-*'))) < 2 and time.time() < deadline and parent.poll() is None:
      time.sleep(0.2)
    workers = [int(p.name.split('-')[1]) for p in tmp_path.glob('busy-*')]
    assert len(workers) == 2, 'the workers did not start'
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    gone_by = time.time() + 5
    while any(_alive(pid) for pid in workers) and time.time() < gone_by:
      time.sleep(0.1)
    assert not any(_alive(pid) for pid in workers), 'orphaned workers'
  finally:
    for pid in [int(p.name.split('-')[1]) for p in tmp_path.glob('busy-*')]:
      if _alive(pid):
        os.kill(pid, signal.SIGKILL)
