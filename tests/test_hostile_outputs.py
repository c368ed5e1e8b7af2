"""Hostile outputs, checkpoints and interrupts (issue 44), one test per failure class: ``benchmark --out`` never
overwrites or adds to a folder of the user's and still resumes its own runs; a damaged saved model is reported
naming the file, before any trial, without orbax's absl ``ERROR`` line; a run lacking a gripper says which ones it
has; a full disk stops ``generate`` with one line naming the shard; Ctrl-C during a training checkpoint lets the
save finish and leaves no orbax temporary directory; ``generate --out`` refuses a ``manifest.json`` that is not a
run's without leaving anything behind.

The CLIs run in-process through ``main(argv)``; no test here computes a trial, a shard or a training step.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import signal
import sys
import threading
from pathlib import Path

import pytest

from dexjax import cli
from dexjax.benchmark import main as benchmark_main
from dexjax.evaluate import main as evaluate_main
from dexjax.generate.__main__ import main as generate_main

sys.path.insert(0, os.path.dirname(__file__))
from cli_checks import digests, never, one_error_line  # pylint: disable=g-import-not-at-top,wrong-import-position
from test_train_loop import _write_dataset  # pylint: disable=g-import-not-at-top,wrong-import-position

BENCH = ['--policy', 'random', '--objects', 'builtin:cube', '--per-trial', '1', '--trials', '1', '--max-attempts', '1']


@pytest.fixture(autouse=True)
def _cache(cache_dir, monkeypatch):
  monkeypatch.setenv('DEXJAX_CACHE', str(cache_dir))


def _bad(capsys, main, argv: list, *needles, code: int = cli.BAD_INPUT_EXIT) -> str:
  """Runs a CLI in-process: asserts the exit code, one ``error:`` line naming ``needles``, no traceback and no
  absl line; returns stderr."""
  assert main([str(a) for a in argv]) == code
  err = capsys.readouterr().err
  lines = [line for line in err.splitlines() if line.strip() and 'cpu_aot' not in line]
  assert len(lines) == 1 and lines[0].startswith('error: '), err
  assert 'Traceback' not in err and 'absl' not in err, err
  for needle in needles:
    assert str(needle) in err, (needle, err)
  return err


def _never(*_, **__):
  raise AssertionError('computed before the inputs were checked')


# --- benchmark --out: the user's folders ----------------------------------------------------------------------------


def test_benchmark_refuses_a_folder_of_the_users_before_computing(tmp_path, capsys, monkeypatch):
  import dexjax.bench.runner as runner
  monkeypatch.setattr(runner, 'check_objects', _never)
  monkeypatch.setattr(runner, 'check_models', _never)
  cases = {'figures': {'results.json': '{"mine": 1}\n', 'reliability.png': 'my own picture\n'},
           'log': {'results.json': '{"mine": 1}\n', 'attempts.jsonl': '{"mine": 1}\n'},
           'unrelated': {'notes.txt': 'my notes\n'},
           'settings': {'benchmark.json': '{"policies": "mine"}\n'}}
  for name, files in cases.items():
    folder = tmp_path / name
    folder.mkdir()
    for file, text in files.items():
      (folder / file).write_text(text)
    before = digests(folder)
    _bad(capsys, benchmark_main, [*BENCH, '--out', folder], "--out: '", name, 'did not write' if name == 'settings'
         else 'holds no benchmark run')
    assert digests(folder) == before  # byte-for-byte untouched, nothing added


def _fake_trials(task, indices, **kwargs):
  """`run_tasks` of the benchmark without computing: each trial ends at once with one finished attempt."""
  from dexjax.bench.attempt_log import append_attempt
  from dexjax.generate.parallel import RunResult
  spec, log = task.args[0], task.args[1]
  run = RunResult()
  for index in indices:
    policy, trial = spec.policies[index // spec.protocol.trials], index % spec.protocol.trials
    append_attempt(log, {
        'policy': policy, 'trial': trial, 'attempt': 0, 'success': False, 'analytic': False, 'physics': False,
        'verdicts': {'analytic': {'success': False, 'reason': 'not_robust'},
                     'physics': {'success': False, 'reason': 'no_object'}},
        'object': 'builtin:cube', 'level': None, 'objects_at_start': 1, 'objects_left': 1, 'plan_seconds': 0.1,
        'motion_seconds': 5.0, 'consecutive_failures': 1, 'stop': 'max_attempts', 'state': {}, 'gripper': 'suction',
        'q': 0.5, 'center': [1.0, 2.0], 'world_center': [0.0, 0.0, 0.05], 'judge': 'physics', 'reason': 'no_object'})
    run.results[index] = {'records': [], 'attempts': 1}
  return run


def test_benchmark_resumes_its_own_run_and_reports_a_damaged_log(tmp_path, capsys, monkeypatch):
  """A run's own folder (benchmark.json, attempts, results, PNGs it marked) is resumed; a damaged log there is one
  error line naming the file and line, never a KeyError."""
  import dexjax.generate.parallel as parallel
  out = tmp_path / 'run'
  with monkeypatch.context() as m:
    m.setattr(parallel, 'run_tasks', _fake_trials)
    assert benchmark_main([*BENCH, '--out', str(out)]) == 0
  written = sorted(p.name for p in out.iterdir())
  assert written == ['attempts.jsonl', 'benchmark.json', 'calibration.png', 'difficulty.png', 'per_object.png',
                     'reliability.png', 'results.json']
  assert all(cli.is_dexjax_png(out / n) for n in written if n.endswith('.png'))
  (out / 'my_notes.txt').write_text('mine\n')  # a user's other file in a run's folder is allowed, never written
  assert benchmark_main([*BENCH, '--out', str(out)]) == 0  # resumed: every trial had ended, nothing to compute
  assert json.loads((out / 'results.json').read_text())['policies']['random']['attempts'] == 1
  assert (out / 'my_notes.txt').read_text() == 'mine\n'
  capsys.readouterr()
  log = out / 'attempts.jsonl'
  log.write_text(json.dumps({'policy': 'random', 'trial': 0}) + '\n')  # no 'stop': was KeyError: 'stop'
  _bad(capsys, benchmark_main, [*BENCH, '--out', out], 'attempts.jsonl: line 1', "field 'attempt'")
  log.write_bytes(b'\x85\x00garbage\n')
  _bad(capsys, benchmark_main, [*BENCH, '--out', out], 'attempts.jsonl: line 1')


# --- damaged checkpoints --------------------------------------------------------------------------------------------


@pytest.fixture
def suction_run(tmp_path) -> Path:
  """A training run holding only a suction model (the shipped one, saved as ``RUN/suction/best``)."""
  from dexjax.models import save_model
  from dexjax.models.shipped import pretrained
  save_model(tmp_path / 'run' / 'suction' / 'best', 1, pretrained('suction'))
  return tmp_path / 'run'


def _damage(run: Path) -> Path:
  """Overwrites the saved model's JSON files with binary bytes; returns the first one orbax reads."""
  step = run / 'suction' / 'best' / '1'
  for name in ('_CHECKPOINT_METADATA', 'model/metadata'):
    (step / name).write_bytes(b'\x00\x01\x02\x85' + bytes(range(256)))
  return step / '_CHECKPOINT_METADATA'


def test_a_damaged_saved_model_names_its_file_without_absl_errors(suction_run, caplog):
  from dexjax.models import load
  damaged = _damage(suction_run)
  with caplog.at_level(logging.WARNING):
    with pytest.raises(ValueError, match=rf"{damaged}: damaged, not the JSON file orbax writes \(UnicodeDecodeError"):
      load(suction_run, 'suction')
  assert not [r for r in caplog.records if r.levelno >= logging.ERROR], caplog.text
  damaged.write_text((damaged.parent / 'commit_success.txt').read_text())  # text, but not JSON
  with pytest.raises(ValueError, match='_CHECKPOINT_METADATA: damaged'):
    load(suction_run, 'suction')


def test_a_damaged_model_is_refused_by_the_clis_before_any_trial(suction_run, tmp_path, capsys, monkeypatch):
  import dexjax.bench.runner as runner
  data = tmp_path / 'data'
  _write_dataset(data, num_shards=1, images_per_shard=1)
  damaged = _damage(suction_run)
  _bad(capsys, evaluate_main, ['--checkpoint', suction_run, '--data', data, '--no-progress'], damaged)
  monkeypatch.setattr(runner, 'check_objects', _never)
  out = tmp_path / 'bench'
  _bad(capsys, benchmark_main, ['--policy', 'suction', '--objects', 'builtin:cube', '--model', suction_run, '--out',
                                out], damaged)
  assert not out.exists() or not any(out.iterdir())  # no results.json of failed trials


def test_a_run_lacking_the_gripper_says_which_it_has(suction_run, tmp_path, capsys):
  import dataclasses
  from dexjax.train import TrainConfig
  from dexjax.train.run import apply_init
  data = tmp_path / 'data'
  _write_dataset(data, num_shards=1, images_per_shard=1)
  _bad(capsys, evaluate_main, ['--checkpoint', suction_run, '--data', data, '--gripper', 'parallel_jaw',
                               '--no-progress'], "no model of gripper 'parallel_jaw' (has ['suction'])")
  config = dataclasses.replace(TrainConfig(), init=str(suction_run), grippers=('parallel_jaw',))
  with pytest.raises(ValueError, match=r"no model of parallel_jaw there \(has \['suction'\]\).*--grippers suction$"):
    apply_init(config)


# --- generate --out: a manifest.json that is not a run's ------------------------------------------------------------


def test_generate_refuses_a_foreign_manifest_and_leaves_nothing_behind(tmp_path, capsys, monkeypatch):
  """A user's ``manifest.json`` (``{"hello": 1}``) said "unreadable (KeyError: 'shards')" and left a
  ``manifest.lock``: it is now refused before anything is written, naming the file as not a dexjax manifest;
  ``--overwrite`` (the library's ``replace_foreign``) replaces it with the run's own."""
  import dexjax.generate.run as run
  monkeypatch.setattr(run, 'process_generator', never)
  monkeypatch.setattr(run, 'warm_caches', never)
  for name, text, shown in (('foreign', '{"hello": 1}', "no field 'config_fingerprint', 'seed', 'num_shards'"),
                            ('damaged', '{"config_fingerprint": "abc", "seed": 0, "num', 'not valid JSON'),
                            ('listed', '[1, 2, 3]', 'a JSON list, not an object'),
                            ('records', '{"config_fingerprint": "a", "seed": 0, "num_shards": 1, "shards": [7]}',
                             "field 'shards' is not a list of shard records")):
    folder = tmp_path / name
    folder.mkdir()
    (folder / 'manifest.json').write_text(text)
    before = digests(folder)
    one_error_line(capsys, generate_main, ['--objects', 'builtin:cube', '--num-images', '1', '--out', folder,
                                           '--no-preview'], f"--out: '{folder / 'manifest.json'}'",
                   'not a dexjax run manifest', shown, '--overwrite')
    assert digests(folder) == before and sorted(os.listdir(folder)) == ['manifest.json']  # no manifest.lock
  from dexjax.data import ShardError, manifest_problem, open_manifest
  foreign = tmp_path / 'foreign'
  assert 'not a dexjax run manifest' in manifest_problem(foreign / 'manifest.json')
  with pytest.raises(ShardError, match=r"manifest '.*foreign/manifest.json': not a dexjax run manifest"):
    open_manifest(foreign, 'fingerprint', 0, 1)
  manifest = open_manifest(foreign, 'fingerprint', 0, 1, replace_foreign=True)
  assert manifest.config_fingerprint == 'fingerprint' and manifest_problem(foreign / 'manifest.json') is None


# --- disk full ------------------------------------------------------------------------------------------------------


def test_a_full_disk_stops_generate_with_one_line_naming_the_shard(tmp_path, capsys, monkeypatch):
  import dexjax.generate.run as run

  def disk_full(index, config, out_dir, cache_dir=None):  # the shard writer's error (dexjax.data.write_shard)
    raise OSError(errno.ENOSPC, 'No space left on device', os.path.join(out_dir, f'shard-{index:06d}.npz'))

  monkeypatch.setattr(run, 'process_generator', lambda *_, **__: None)
  monkeypatch.setattr(run, 'generate_shard', disk_full)
  out = tmp_path / 'data'
  err = _bad(capsys, generate_main, ['--objects', 'builtin:cube', '--num-images', '3', '--out', out, '--json',
                                     '--no-preview'], 'shard-000000.npz: No space left on device', 'free some space')
  assert 'shard 1' not in err


def test_a_full_disk_names_the_attempt_log(tmp_path, monkeypatch):
  from dexjax.bench.attempt_log import append_attempt

  def disk_full(*_):
    raise OSError(errno.ENOSPC, 'No space left on device')  # as os.fsync does: no file name

  monkeypatch.setattr(os, 'fsync', disk_full)
  with pytest.raises(OSError) as e:
    append_attempt(tmp_path / 'attempts.jsonl', {'attempt': 0})
  assert e.value.errno == errno.ENOSPC and e.value.filename == os.fspath(tmp_path / 'attempts.jsonl')


# --- Ctrl-C during a training checkpoint ----------------------------------------------------------------------------


@pytest.mark.skipif(threading.current_thread() is not threading.main_thread(), reason='signals reach the main thread')
def test_ctrl_c_during_a_checkpoint_lets_the_save_finish(tmp_path, monkeypatch):
  """A SIGINT that arrives while orbax saves is held until the step is whole (no ``*.orbax-checkpoint-tmp``, no
  orbax thread still writing), then raised as KeyboardInterrupt."""
  import jax
  import optax
  import orbax.checkpoint as ocp
  from dexjax.models import GQCNNConfig
  from dexjax.train.checkpoint import Checkpointer
  from dexjax.train.config import CheckpointConfig
  from dexjax.train.step import create_state
  state = create_state(jax.random.key(0), GQCNNConfig.small(), optax.sgd(0.1)).replace(step=3)
  save = ocp.CheckpointManager.save

  def interrupted_save(self, *args, **kwargs):
    os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C as the save starts
    return save(self, *args, **kwargs)

  monkeypatch.setattr(ocp.CheckpointManager, 'save', interrupted_save)
  with pytest.raises(KeyboardInterrupt):
    with Checkpointer(tmp_path / 'suction', CheckpointConfig()) as checkpointer:
      checkpointer.save(state, {'epoch': 0})
  monkeypatch.undo()
  directory = tmp_path / 'suction' / 'checkpoints'
  assert sorted(p.name for p in directory.iterdir()) == ['3']  # the step is whole, no temporary directory
  with Checkpointer(tmp_path / 'suction', CheckpointConfig()) as checkpointer:
    assert int(checkpointer.restore(state)[0].step) == 3
