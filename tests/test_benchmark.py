"""``python -m dexjax.benchmark``: a small physics-judged run end to end (results, figures, both judges), bad
input, and a run killed with SIGKILL that resumes to the same results."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from dexjax.bench.attempt_log import read_attempts
from dexjax.benchmark import main

OBJECTS = ['builtin:cube', 'builtin:box', 'builtin:cylinder']
ARGS = ['--policy', 'suction_heuristic', '--policy', 'random', '--objects', *OBJECTS, '--per-trial', '2',
        '--trials', '2', '--max-attempts', '4', '--max-failures', '3', '--no-figures']
TIMING = ('plan_seconds', 'mpph', 'seconds_per_attempt', 'stage_seconds')


def _strip(value):
  """results.json without the measured planning times (and what derives from them)."""
  if isinstance(value, dict):
    return {k: _strip(v) for k, v in value.items() if k not in TIMING}
  if isinstance(value, list):
    return [_strip(v) for v in value]
  return value


@pytest.fixture(scope='module')
def reference(tmp_path_factory):
  """One uninterrupted run in this process (serial)."""
  out = tmp_path_factory.mktemp('bench') / 'reference'
  assert main([*ARGS, '--out', str(out)]) == 0
  return out


def test_a_run_writes_results_log_and_both_verdicts(reference, tmp_path, capsys):
  results = json.loads((reference / 'results.json').read_text())
  records = read_attempts(reference / 'attempts.jsonl')
  assert set(results['policies']) == {'suction_heuristic', 'random'}
  for name, entry in results['policies'].items():
    rows = [r for r in records if r['policy'] == name]
    assert entry['attempts'] == len(rows) and entry['successes'] == sum(r['success'] for r in rows)
    assert entry['trials_finished'] == 2 and sum(entry['trial_ends'].values()) == 2
    assert 0.0 <= entry['judge_agreement'] <= 1.0 and entry['judged_by_both'] == len(rows)
    assert entry['mpph'] >= 0.0 and set(entry['per_level']) == {'None'}  # builtin objects have no level
  for r in records:  # every attempt judged twice; the physics verdict advanced the trial
    assert set(r['verdicts']) == {'analytic', 'physics'} and r['judge'] == 'physics'
    assert r['success'] == r['physics'] and r['analytic'] == r['verdicts']['analytic']['success']
    assert r['stop'] is None or r['stop'] in ('empty', 'max_attempts', 'consecutive_failures')
  assert results['config']['policies'] == ['suction_heuristic', 'random']
  assert results['config']['objects'] == OBJECTS and results['failed_trials'] == {}
  # Figures from the same results.
  from dexjax.bench.figures import save_figures
  figures = ['reliability.png', 'per_object.png', 'difficulty.png', 'calibration.png']
  assert save_figures(results, tmp_path) == figures
  assert all((tmp_path / n).stat().st_size > 1000 for n in figures)
  # A finished run reruns as a no-op with the same results; other settings in the same directory are refused.
  assert main([*ARGS, '--out', str(reference)]) == 0
  assert _strip(json.loads((reference / 'results.json').read_text())) == _strip(results)
  capsys.readouterr()
  assert main([*ARGS[:-1], '--judge', 'analytic', '--no-figures', '--out', str(reference)]) == 2
  assert 'holds a benchmark run with other settings (judge)' in capsys.readouterr().err


def test_bad_input_is_one_error_line(tmp_path, capsys):
  assert main(['--policy', 'random', '--objects', 'builtin:cube', '--per-trial', '2', '--out', str(tmp_path)]) == 2
  assert 'objects per trial (--per-trial): expected at most 1' in capsys.readouterr().err
  assert main(['--policy', 'random', '--objects', 'procedural:L1/5:2', '--out', str(tmp_path)]) == 2
  assert "object source 'procedural:L1/5:2'" in capsys.readouterr().err
  assert main(['--policy', 'random', '--policy', 'random', '--objects', 'builtin:cube', '--out', str(tmp_path)]) == 2
  assert '--policy: each policy once' in capsys.readouterr().err
  (tmp_path / 'file').write_text('x')
  assert main(['--policy', 'random', '--objects', 'builtin:cube', '--out', str(tmp_path / 'file')]) == 2
  assert 'exists and is not a directory' in capsys.readouterr().err


def test_a_run_killed_with_sigkill_resumes_to_the_same_results(reference, tmp_path):
  out = tmp_path / 'killed'
  argv = [sys.executable, '-m', 'dexjax.benchmark', *ARGS, '--workers', '2', '--out', str(out)]
  process = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
  deadline = time.time() + 600
  while time.time() < deadline and process.poll() is None:
    if len(read_attempts(out / 'attempts.jsonl')) >= 3:
      break
    time.sleep(0.05)
  os.kill(process.pid, signal.SIGKILL)  # its workers die with it (dexjax.generate.die_with_parent)
  process.wait()
  done = read_attempts(out / 'attempts.jsonl')
  total = len(read_attempts(reference / 'attempts.jsonl'))
  assert 3 <= len(done) < total and not (out / 'results.json').exists()
  assert subprocess.run(argv, stdout=subprocess.DEVNULL, timeout=900).returncode == 0
  assert _strip(json.loads((out / 'results.json').read_text())) == _strip(
      json.loads((reference / 'results.json').read_text()))
  key = lambda r: (r['policy'], r['trial'], r['attempt'])
  resumed = sorted(read_attempts(out / 'attempts.jsonl'), key=key)
  assert [_strip(r) for r in resumed] == [_strip(r) for r in sorted(read_attempts(reference / 'attempts.jsonl'),
                                                                      key=key)]


def test_ray_workers_hand_their_trials_to_the_driver(reference, tmp_path):
  """--ray: trials run as Ray tasks (a local instance) that return their records; the driver appends them. Same
  results as the serial run."""
  out = tmp_path / 'ray'
  assert main([*ARGS, '--ray', '--out', str(out)]) == 0
  assert _strip(json.loads((out / 'results.json').read_text())) == _strip(
      json.loads((reference / 'results.json').read_text()))
  assert len(read_attempts(out / 'attempts.jsonl')) == len(read_attempts(reference / 'attempts.jsonl'))


def test_the_benchmark_config_takes_one_source_or_a_sequence():
  from dexjax.bench.runner import benchmark_config
  assert benchmark_config('procedural:L1/0:3').objects.sources == ('procedural:L1/0:3',)
  assert benchmark_config(['a.obj', 'b.obj'], noise=False).objects.sources == ('a.obj', 'b.obj')


def test_every_recorded_attempt_replays_to_its_verdicts(reference, tmp_path, capsys):
  """``python -m dexjax.replay``: each attempt judged again from the bin it started from gives the recorded
  verdicts (the fill for attempt 0, the logged state after); a log whose verdict was altered is caught."""
  from dexjax.replay import main as replay
  records = read_attempts(reference / 'attempts.jsonl')
  assert all(r['width'] == 0.0 for r in records if r['gripper'] == 'suction')
  assert any(r['gripper'] == 'parallel_jaw' and r['width'] > 0.0 for r in records)  # the jaws' opening is kept
  for policy in ('suction_heuristic', 'random'):
    capsys.readouterr()
    assert replay([str(reference), '--trial', '1', '--policy', policy, '--json']) == 0
    rows = json.loads(capsys.readouterr().out)
    mine = [r for r in records if r['policy'] == policy and r['trial'] == 1]
    assert [row['attempt'] for row in rows] == sorted(r['attempt'] for r in mine) and rows[0]['attempt'] == 0
    assert all(row['reproduced'] and set(row['replayed']) == {'analytic', 'physics'} for row in rows)
  # An altered verdict is not reproduced (exit 1), and says so.
  altered = tmp_path / 'altered'
  altered.mkdir()
  (altered / 'benchmark.json').write_text((reference / 'benchmark.json').read_text())
  lines = (reference / 'attempts.jsonl').read_text().splitlines()
  first = json.loads(lines[0])
  first['verdicts']['physics']['success'] = not first['verdicts']['physics']['success']
  (altered / 'attempts.jsonl').write_text('\n'.join([json.dumps(first), *lines[1:]]) + '\n')
  capsys.readouterr()
  assert replay([str(altered), '--trial', str(first['trial']), '--attempt', str(first['attempt']),
                 '--policy', first['policy']]) == 1
  assert 'DIFFERS' in capsys.readouterr().out
  # Bad input: one line naming what is wrong.
  for argv, message in (([str(tmp_path), '--trial', '0'], 'expected a benchmark run directory (no benchmark.json)'),
                        ([str(reference), '--trial', '0'], '--policy: expected one of suction_heuristic, random'),
                        ([str(reference), '--trial', '7', '--policy', 'random'], '--policy random --trial 7: not in'),
                        ([str(reference), '--trial', '0', '--policy', 'random', '--attempt', '99'],
                         '--attempt: expected 0-'),
                        ([str(reference), '--trial', '0', '--policy', 'random', '--no-noise'],
                         'config_fingerprint: the run')):
    capsys.readouterr()
    assert replay(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith('error: ') and message in err and len(err.strip().splitlines()) == 1


def test_a_runs_settings_come_back_or_are_refused_by_name(reference):
  """`spec_from_settings` rebuilds the run's spec (nested physics settings included) exactly, and names a setting
  this version does not know or a value that does not come back."""
  from dexjax.bench.attempt_replay import spec_from_settings
  from dexjax.bench.runner import load_benchmark_config
  settings = json.loads((reference / 'benchmark.json').read_text())
  config = load_benchmark_config(settings['objects'])
  spec = spec_from_settings(settings, config)
  assert json.loads(json.dumps(spec.settings_json())) == settings
  assert spec.physics.path.motion.lift_height == settings['physics']['path']['motion']['lift_height']
  unknown = json.loads(json.dumps(settings))
  unknown['physics']['path']['retreat'] = 0.05
  with pytest.raises(ValueError, match=r'physics\.path\.retreat: not a setting of this version'):
    spec_from_settings(unknown, config)
  with pytest.raises(ValueError, match=r'^config_fingerprint: the run has "0000", these settings give'):
    spec_from_settings({**settings, 'config_fingerprint': '0000'}, config)
  with pytest.raises(ValueError, match=r'^config_fingerprint: .*another --config'):
    spec_from_settings(settings, load_benchmark_config(settings['objects'], noise=False))
  with pytest.raises(ValueError, match='memory: expected an object of settings, got list'):
    spec_from_settings({**settings, 'memory': [0.0, 5]}, config)
  missing = {k: v for k, v in settings.items() if k != 'cem'}
  with pytest.raises(ValueError, match="cem: missing from the run's settings"):
    spec_from_settings(missing, config)
