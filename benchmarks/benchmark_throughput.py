"""Throughput of the Universal Picking benchmark loop: one JSON object on stdout.

  python benchmarks/benchmark_throughput.py [--policy ambidextrous] [--objects procedural:L2/95000:95025]
                                            [--per-trial 25] [--trials 5] [--workers 2] [--judge physics]

A ``--trials``-trial benchmark of one policy (`dexjax.bench.run_benchmark`, the shipped GQ-CNNs: the quick-start
architecture) on bins of ``--per-trial`` objects, on ``--workers`` processes, from a cold start (object preparation
cached on disk beforehand, not timed; compiling is timed: each worker compiles its planner and judges once).
Reported: ``wall_minutes`` of the whole run (the issue's target: 5 trials of 25 objects in under 15 minutes on a
2-core CPU), ``attempts_per_s`` end to end, and ``stage_seconds``, the mean seconds per attempt of each stage of the
loop (``render``: the depth image with sensor noise; ``plan``; ``judge_analytic``, ``judge_physics``; ``settle``:
the heap settling again after the attempt), and the fill (dropping and settling a bin) per trial.

Baseline (same run): Dex-Net released no benchmark loop, so the comparison is the same loop run the plain way,
serially in one process (``--workers 1``) on the first trial only: ``serial_attempts_per_s`` (after its compile)
and ``parallel_speedup`` = attempts/s of the parallel run over it.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time

from dexjax.bench.attempt_log import read_attempts
from dexjax.bench.protocol import Protocol
from dexjax.bench.runner import BenchmarkSpec, benchmark_config, check_objects, run_benchmark

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from _machine import describe  # noqa: E402


def _spec(args, trials: int) -> BenchmarkSpec:
  return BenchmarkSpec(policies=(args.policy,), config=benchmark_config(args.objects), judge=args.judge,
                       protocol=Protocol(objects_per_trial=args.per_trial, trials=trials))


def _stages(records) -> dict[str, float]:
  keys = sorted({k for r in records for k in r['stage_seconds']})
  return {k: round(statistics.fmean(r['stage_seconds'][k] for r in records if k in r['stage_seconds']), 4)
          for k in keys}


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
  p.add_argument('--policy', default='ambidextrous')
  p.add_argument('--objects', nargs='+', default=['procedural:L2/95000:95025'])
  p.add_argument('--per-trial', type=int, default=25)
  p.add_argument('--trials', type=int, default=5)
  p.add_argument('--workers', type=int, default=2)
  p.add_argument('--judge', default='physics')
  args = p.parse_args()
  spec = _spec(args, args.trials)
  start = time.perf_counter()
  check_objects(spec)  # prepares and caches the objects (not part of the loop's throughput)
  prepare_s = time.perf_counter() - start
  with tempfile.TemporaryDirectory() as tmp:
    start = time.perf_counter()
    results = run_benchmark(spec, os.path.join(tmp, 'parallel'), workers=args.workers, progress=False,
                            figures=False)
    wall = time.perf_counter() - start
    records = read_attempts(os.path.join(tmp, 'parallel', 'attempts.jsonl'))
    serial_spec = _spec(args, 1)
    start = time.perf_counter()
    run_benchmark(serial_spec, os.path.join(tmp, 'serial'), workers=1, progress=False, figures=False)
    serial_wall = time.perf_counter() - start
    serial = read_attempts(os.path.join(tmp, 'serial', 'attempts.jsonl'))
  entry = results['policies'][args.policy]
  # The serial run's steady rate: its attempts over their own stage times (the first attempt carries the compile).
  steady = [sum(r['stage_seconds'].values()) for r in serial[1:]]
  serial_rate = len(steady) / sum(steady) if steady else float('nan')
  parallel_rate = len(records) / wall
  print(json.dumps({
      'benchmark': 'benchmark_throughput', 'policy': args.policy, 'objects': args.objects,
      'per_trial': args.per_trial, 'trials': args.trials, 'workers': args.workers, 'judge': args.judge,
      'attempts': len(records), 'wall_minutes': round(wall / 60.0, 2), 'target_minutes': 15.0,
      'target_met': bool(wall / 60.0 < 15.0) if (args.trials, args.per_trial) == (5, 25) else None,
      'attempts_per_s': round(parallel_rate, 4), 'stage_seconds': _stages(records),
      'first_attempt_seconds': round(statistics.fmean(sum(r['stage_seconds'].values()) for r in records
                                                      if r['attempt'] == 0), 2),
      'reliability': round(entry['reliability'], 4), 'judge_agreement': entry['judge_agreement'],
      'mpph': round(entry['mpph'], 1), 'object_prepare_s': round(prepare_s, 1),
      'baseline': {'what': 'the same loop serially in one process, first trial', 'attempts': len(serial),
                   'wall_s': round(serial_wall, 1), 'serial_attempts_per_s': round(serial_rate, 4)},
      'parallel_speedup': round(parallel_rate / serial_rate, 3) if steady else None,
      'machine': describe(),
  }, indent=1))


if __name__ == '__main__':
  main()
