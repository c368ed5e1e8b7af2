"""``python -m dexjax.replay``: judge recorded benchmark attempts again, from the bin each started from.

  python -m dexjax.replay RUN --trial T [--attempt K] [--policy NAME] [--config FILE] [--camera-config FILE]
                          [--no-noise] [--cache-dir DIR] [--json]

RUN is a benchmark run (``python -m dexjax.benchmark --out RUN``). Attempt K of the policy's trial T (default: every
attempt of the trial; ``--policy`` may be left out when the run has one policy) is judged again by both judges on
the bin it started from (the state recorded with attempt K - 1, or the trial's fill), with the trial's camera, the
recorded grasp and the attempt's keys: a run is deterministic, so the verdicts must be the recorded ones.
``--config``, ``--camera-config`` and ``--no-noise`` must be those the run was made with (its settings are checked).
Prints one line per attempt (recorded and replayed verdict and reason per judge), or with ``--json`` a list of
``{"trial", "attempt", "gripper", "q", "recorded": {judge: {"success", "reason"}}, "replayed": {...},
"reproduced"}``. To trace a failure, `dexjax.bench.recorded_attempt` gives the bin, camera, grasp and key
of an attempt in Python. Exit code 0 when every verdict is reproduced, 1 when one is not, 2 for bad input
(docs/errors.md), 130 when interrupted.
"""

from __future__ import annotations

import argparse
import json
import sys

from dexjax.cli import FAILURE_EXIT, OK_EXIT, command


def _parser() -> argparse.ArgumentParser:
  p = argparse.ArgumentParser(prog='python -m dexjax.replay', description=__doc__.split('\n\n')[0],
                              formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument('run', metavar='RUN', help='a benchmark run directory (its benchmark.json and attempts.jsonl)')
  p.add_argument('--trial', type=int, required=True, help='the trial')
  p.add_argument('--attempt', type=int, help='the attempt (default: every attempt of the trial)')
  p.add_argument('--policy', help="the policy (default: the run's one policy)")
  p.add_argument('--config', help='the generation config the run was made with')
  p.add_argument('--camera-config', help='the camera file the run was made with')
  p.add_argument('--no-noise', action='store_true', help='the run was made with --no-noise')
  p.add_argument('--cache-dir', metavar='DIR', help='object cache (as the benchmark)')
  p.add_argument('--json', action='store_true', help='print JSON')
  return p


def _verdicts(verdicts) -> dict:
  return {name: {'success': bool(v['success'] if isinstance(v, dict) else v.success),
                 'reason': v['reason'] if isinstance(v, dict) else v.reason} for name, v in verdicts.items()}


@command
def main(argv: list[str] | None = None) -> int:
  args = _parser().parse_args(argv)
  from pathlib import Path  # pylint: disable=g-import-not-at-top
  from dexjax.bench.attempt_log import RECORD_FIELDS, read_attempts  # pylint: disable=g-import-not-at-top
  from dexjax.bench.runner import (  # pylint: disable=g-import-not-at-top
      LOG_FILE, SETTINGS_FILE, load_benchmark_config)
  from dexjax.config import parse_json  # pylint: disable=g-import-not-at-top
  run = Path(args.run)
  for name in (SETTINGS_FILE, LOG_FILE):
    if not (run / name).is_file():
      raise ValueError(f"RUN: '{run}': expected a benchmark run directory (no {name})")
  settings = parse_json((run / SETTINGS_FILE).read_text(), str(run / SETTINGS_FILE))
  if not isinstance(settings, dict) or 'objects' not in settings or 'policies' not in settings:
    raise ValueError(f"'{run / SETTINGS_FILE}': expected a benchmark run's settings (objects, policies, ...)")
  policy = args.policy
  if policy is None:
    if len(settings['policies']) != 1:
      raise ValueError(f'--policy: expected one of {", ".join(settings["policies"])} (the run has several)')
    policy = settings['policies'][0]
  records = read_attempts(run / LOG_FILE, fields=RECORD_FIELDS)
  config = load_benchmark_config(settings['objects'], args.config, args.camera_config, noise=not args.no_noise)
  from dexjax.bench.attempt_replay import (  # pylint: disable=g-import-not-at-top
      recorded_attempt, replay_attempt, spec_from_settings)
  from dexjax.bench.runner import benchmark_judges  # pylint: disable=g-import-not-at-top
  from dexjax.bench.world import PickingWorld  # pylint: disable=g-import-not-at-top
  spec = spec_from_settings(settings, config)
  attempts = [args.attempt] if args.attempt is not None else sorted(
      r['attempt'] for r in records if r['policy'] == policy and r['trial'] == args.trial)
  rows = []
  with PickingWorld(spec.config, cache_dir=args.cache_dir, grip_decomposition=spec.grip_decomposition) as world:
    judges = benchmark_judges(world, spec)
    for k in attempts or [0]:
      attempt = recorded_attempt(world, spec, records, policy, args.trial, k)
      recorded = _verdicts(attempt.record['verdicts'])
      replayed = _verdicts(replay_attempt(world, spec, attempt, judges)) if attempt.action is not None else recorded
      rows.append({'trial': args.trial, 'attempt': k, 'gripper': attempt.record.get('gripper'),
                   'q': attempt.record.get('q'), 'recorded': recorded, 'replayed': replayed,
                   'reproduced': recorded == replayed})
      if not args.json:
        said = lambda v: ', '.join(f"{n} {'ok' if x['success'] else x['reason']}" for n, x in v.items())
        print(f"trial {args.trial} attempt {k:3d} {rows[-1]['gripper'] or 'no grasp':12s} recorded: "
              f"{said(recorded):40s} replayed: {said(replayed):40s} {'' if rows[-1]['reproduced'] else 'DIFFERS'}")
  if args.json:
    print(json.dumps(rows, indent=1))
  return OK_EXIT if all(r['reproduced'] for r in rows) else FAILURE_EXIT


if __name__ == '__main__':
  sys.exit(main())
