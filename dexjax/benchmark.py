"""``python -m dexjax.benchmark``: the Universal Picking benchmark in simulation (seed, Fig. S2, S3).

  python -m dexjax.benchmark --policy ambidextrous [--policy suction_heuristic ...] --objects SOURCE ...
      --out DIR [--per-trial 25] [--trials 5] [--judge physics|analytic] [--model pretrained|RUN_DIR]
      [--max-attempts 75] [--max-failures 10] [--config FILE] [--camera-config FILE] [--no-noise]
      [--known-mass] [--supervisor-without-loads] [--supervisor-without-fallback]
      [--supervisor-without-lift-first] [--cem seed|gqcnn] [--seed S]
      [--failure-memory R [--memory-attempts N]] [--shake]
      [--push] [--workers N | --ray [--ray-address ADDR]] [--cache-dir DIR] [--no-figures] [--json]

Each trial fills the bin with ``--per-trial`` objects of the set (dropped and settled in MuJoCo), then each policy
looks (a depth image from the run's camera, with 0.5 mm sensor noise and 1 % dropped pixels unless ``--no-noise``),
plans, and its grasp is judged twice: by the analytic reward of the training labels and by executing it in MuJoCo
(the labels' collision rule, then grip, lift 0.2 m, transport to a receptacle beside the bin, release; ``--shake``
adds a shake before the release, ``--push`` lets the gripper push objects aside instead of the collision rule).
``--judge`` (default physics) decides which verdict advances the trial: on success the object leaves the bin and
the rest settle. A trial ends when the bin is empty, after ``--max-attempts`` attempts or after ``--max-failures``
consecutive failures. Every policy meets the same bins (trial t of seed S). ``--policy supervisor`` is the dataset's
supervisor with the bin's true state (privileged: the ceiling of the table). ``--failure-memory R`` gives every
policy a memory: no grasp within R metres of a failed grasp of the last ``--memory-attempts`` attempts (default 5).

Writes DIR/attempts.jsonl (one line per attempt, appended as it ends: policy, gripper, predicted q, both
verdicts and failure reasons, object, times, bin state), DIR/results.json (``{"policies": {NAME: {"reliability",
"mpph", "attempts", "successes", "judge_agreement", "per_level", "per_object", ...}}, "object_difficulty", "config"}``),
DIR/benchmark.json (the settings) and the figures reliability.png, per_object.png, difficulty.png, calibration.png
(per judge, the predicted probability at the chosen grasps against their success). Rerun the same
command to resume a killed run at its next attempt, with the same results. DIR must be new, empty or a benchmark
run's (its benchmark.json): files the benchmark did not write are never overwritten or added to. The models are
loaded before the first trial. Exit code 0 on success, 1 when some trials failed (the others are summarised), 2
for bad input (docs/errors.md), 130 when interrupted.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

from dexjax.cli import FAILURE_EXIT, OK_EXIT, check_output_dir, command
from dexjax.policy.scorers import GRIPPERS

_POLICIES = ('ambidextrous', 'parallel_jaw', 'suction', 'ranking', 'random', 'suction_heuristic',
             'composite_heuristic', 'supervisor')


def _parser() -> argparse.ArgumentParser:
  p = argparse.ArgumentParser(prog='python -m dexjax.benchmark', description=__doc__.split('\n\n')[0],
                              formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument('--policy', action='append', choices=_POLICIES, required=True,
                 help='a policy to benchmark (repeat for several)')
  p.add_argument('--objects', nargs='+', required=True, metavar='SOURCE',
                 help='object sources: procedural:L2/5000:25, builtin:NAME, mesh files or folders')
  p.add_argument('--out', required=True, metavar='DIR',
                 help='output directory: new, empty, or a benchmark run to resume')
  p.add_argument('--per-trial', type=int, default=25, help='objects in the bin per trial (default 25)')
  p.add_argument('--trials', type=int, default=5, help='trials per policy (default 5)')
  p.add_argument('--judge', choices=('physics', 'analytic'), default='physics',
                 help='whose verdict advances a trial (default physics; both are recorded)')
  p.add_argument('--model', default='pretrained', metavar='RUN_DIR',
                 help='GQ-CNNs of the learned policies: pretrained (default) or a training run / model')
  p.add_argument('--max-attempts', type=int, default=75, help='attempts per trial at most (default 75)')
  p.add_argument('--max-failures', type=int, default=10, help='consecutive failures that end a trial (default 10)')
  p.add_argument('--config', help='generation config: bin, settling, camera, noise, grippers, reward '
                                  '(layout: configs/dexnet4.yaml; default: Dex-Net 4.0 values)')
  p.add_argument('--camera-config', help='camera file (as python -m dexjax.generate)')
  p.add_argument('--no-noise', action='store_true', help='noise-free depth images (default: 0.5 mm correlated noise '
                                                         'and 1 %% dropped pixels unless --config sets noise)')
  p.add_argument('--known-mass', action='store_true',
                 help="the analytic judge uses each object's simulated mass as it is instead of the labels' Gamma "
                      "draws about it")
  p.add_argument('--supervisor-without-loads', action='store_false', dest='supervisor_loads',
                 help="the supervisor scores grasps without the load its neighbours put on the grasped object "
                      "(default: with it; docs/benchmark.md)")
  p.add_argument('--supervisor-without-fallback', action='store_false', dest='supervisor_fallback',
                 help='the supervisor returns no grasp (the trial stops) when no grasp passes its test, instead of '
                      'executing its best effort (default: best effort; docs/benchmark.md)')
  p.add_argument('--supervisor-without-lift-first', action='store_false', dest='supervisor_lift_first',
                 help='the supervisor ranks the grasps that pass its test by their scores alone, instead of taking '
                      'those on objects that rise straight out of the heap first (default: first; docs/benchmark.md)')
  p.add_argument('--cem', choices=('seed', 'gqcnn'), default='seed', help='CEM preset of the learned policies')
  p.add_argument('--seed', type=int, default=0, help='benchmark seed: bins, cameras and keys (default 0)')
  p.add_argument('--failure-memory', type=float, default=0.0, metavar='R',
                 help='no grasp within R metres of a recent failed grasp (default 0: no memory, as the seed)')
  p.add_argument('--memory-attempts', type=int, default=5, metavar='N',
                 help='a failed grasp is remembered for the next N attempts (default 5)')
  p.add_argument('--shake', action='store_true', help='physics judge: shake the held object before the release '
                                                      '(a stress test; not in the seed\'s protocol)')
  p.add_argument('--push', action='store_true', help='physics judge: the gripper pushes objects in its way aside '
                                                     'instead of failing on the labels\' collision rule')
  p.add_argument('--workers', type=int, default=1, help='trials run in parallel on this many processes')
  p.add_argument('--ray', action='store_true', help='run trials on Ray (a local instance, or --ray-address)')
  p.add_argument('--ray-address', help='join this Ray cluster')
  p.add_argument('--cache-dir', help='object cache (default $DEXJAX_CACHE or ~/.cache/dexjax/objects)')
  p.add_argument('--no-figures', action='store_true', help='do not draw the PNG figures')
  p.add_argument('--json', action='store_true', help='print results.json instead of the table')
  return p


def _check_args(args: argparse.Namespace) -> None:
  for option, value in (('--per-trial', args.per_trial), ('--trials', args.trials), ('--workers', args.workers),
                        ('--max-attempts', args.max_attempts), ('--max-failures', args.max_failures)):
    if value < 1:
      raise ValueError(f'{option}: expected an integer >= 1, got {value}')
  if args.seed < 0:
    raise ValueError(f'--seed: expected an integer >= 0, got {args.seed}')
  if not (math.isfinite(args.failure_memory) and args.failure_memory >= 0):
    raise ValueError(f'--failure-memory: expected a number >= 0 (metres), got {args.failure_memory}')
  if args.memory_attempts < 1:
    raise ValueError(f'--memory-attempts: expected an integer >= 1, got {args.memory_attempts}')
  if len(set(args.policy)) != len(args.policy):
    raise ValueError(f'--policy: each policy once, got {args.policy}')
  if args.ray_address and not args.ray:
    raise ValueError('--ray-address: needs --ray')
  check_output_dir(args.out)


def _number(value, form: str) -> str:
  return 'n/a' if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, form)


def format_table(results: dict) -> str:
  """The results as a plain-text table: policy (``*``: privileged state), attempts, reliability per level, MPPH,
  judge agreement, fraction of objects cleared and repeated attempts; then, per judge, the precision of the chosen
  grasps per gripper, the policy's mean predicted probability and its expected calibration error."""
  rows = ['policy                 attempts  reliability  per level                      MPPH   agree  cleared  repeats']
  for name, e in results['policies'].items():
    levels = ', '.join(f"L{k}: {v['reliability']:.2f}" if k != 'None' else f"other: {v['reliability']:.2f}"
                       for k, v in e['per_level'].items())
    label = name + (' *' if e.get('privileged') else '')
    rows.append(f"{label:22s} {e['attempts']:8d}  {e['reliability']:11.3f}  {levels:29s} {e['mpph']:6.0f}   "
                f"{_number(e['judge_agreement'], '.3f'):5s}  {_number(e.get('cleared'), '.2f'):7s}  "
                f"{e.get('repeated_attempts', 0):7d}")
  if any(e.get('privileged') for e in results['policies'].values()):
    rows.append('* privileged: plans with the true state of the simulated bin (the ceiling, not a deployable policy)')
  rows += ['', 'at the chosen grasp    judge     precision: jaws (n)   suction (n)    all    mean q  ECE']
  for name, e in results['policies'].items():
    for judge, choice in e.get('at_choice', {}).items():
      p = choice['precision']
      grippers = [f"{_number(p[g]['precision'], '.2f'):4s} ({p[g]['chosen']:3d})" for g in GRIPPERS]
      rows.append(f"{name:22s} {judge:9s} {grippers[0]:>20s} {grippers[1]:>12s}   "
                  f"{_number(p['all']['precision'], '.2f'):5s}  {_number(p['all']['mean_q'], '.2f'):6s}  "
                  f"{_number(choice['calibration']['ece'], '.3f')}")
  return '\n'.join(rows)


@command
def main(argv: list[str] | None = None) -> int:
  args = _parser().parse_args(argv)
  _check_args(args)
  import dataclasses  # pylint: disable=g-import-not-at-top (slow imports after the checks)
  from dexjax.bench.protocol import Protocol  # pylint: disable=g-import-not-at-top
  from dexjax.bench.runner import (  # pylint: disable=g-import-not-at-top
      BenchmarkSpec, check_run_dir, load_benchmark_config, run_benchmark)
  check_run_dir(args.out)  # before the configs: a folder of the user's fails at once (the settings: run_benchmark)
  config = load_benchmark_config(args.objects, args.config, args.camera_config, noise=not args.no_noise)
  from dexjax.bench.execution import PhysicsSettings  # pylint: disable=g-import-not-at-top
  from dexjax.bench.failure_memory import FailureMemory  # pylint: disable=g-import-not-at-top
  physics = PhysicsSettings()
  if args.shake:
    physics = dataclasses.replace(physics, path=dataclasses.replace(physics.path, shake_cycles=2))
  if args.push:
    physics = dataclasses.replace(physics, collision_check=False)
  spec = BenchmarkSpec(policies=tuple(args.policy), config=config,
                       protocol=Protocol(objects_per_trial=args.per_trial, trials=args.trials,
                                         max_attempts=args.max_attempts, max_consecutive_failures=args.max_failures),
                       judge=args.judge, model=args.model, cem=args.cem, seed=args.seed, known_mass=args.known_mass,
                       supervisor_loads=args.supervisor_loads, supervisor_fallback=args.supervisor_fallback,
                       supervisor_lift_first=args.supervisor_lift_first,
                       physics=physics, memory=FailureMemory(args.failure_memory, args.memory_attempts))
  results = run_benchmark(spec, args.out, workers=args.workers, backend='ray' if args.ray else None,
                          ray_address=args.ray_address, cache_dir=args.cache_dir, progress=not args.json,
                          figures=not args.no_figures)
  if args.json:
    print(json.dumps(results, indent=1, default=str))
  else:
    print(format_table(results))
    print(f'results: {args.out}/results.json')
  for trial, reason in results['failed_trials'].items():
    print(f'trial {trial} failed: {reason}', file=sys.stderr)
  return FAILURE_EXIT if results['failed_trials'] else OK_EXIT


if __name__ == '__main__':
  sys.exit(main())
