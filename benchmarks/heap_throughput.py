"""Heap settling throughput, MuJoCo C engine (`rollout`) vs. MJX, one JSON object on stdout.

  python benchmarks/heap_throughput.py [--quick] [--rollout-heaps 64] [--repeats 3] [--mjx-timeout-5 600]
                                       [--mjx-timeout-10 2700]

Heaps of 5 and 10 objects are drawn from the Dex-Net 4.0 distribution with a fixed object set per count (so
MJX compiles once per count and batch size, and both backends settle the very same heaps): the built-in cube,
box, box with hole (its convex hull), L (two boxes) and cylinder (a 16-sided hull), plus the same five at 0.75
scale for 10 objects. ``heaps_per_s`` counts settled-or-stopped heaps (500 steps at most, dt 4 ms) per second:

* ``rollout``: one `dexjax.sim.settle(backend='rollout')` call over ``--rollout-heaps`` heaps with
  ``os.cpu_count()`` threads, model building included; median of ``--repeats`` calls.
* ``mjx``: batch sizes 1, 16 and 64 (4, 16 and 64 heaps), one compiled ``jit(vmap)`` call per batch, timed
  after compilation (``compile_s`` is reported separately). Each object count runs in its own child process
  pinned to one CPU core (the deadlock guard; the two children side by side on different cores, after the
  rollout runs) with a timeout; a timeout is reported as ``"status": "timeout"``.

``rollout_procedural``: ``--rollout-heaps`` heaps per difficulty level drawn from the level's first 30
procedural objects (cached convex decompositions, prepared before timing) with the seed's object count
(Poisson(5) truncated to [3, 10]), the C engine only.

``ratio_rollout_over_mjx`` divides rollout heaps/s by the best MJX heaps/s at the same object count. The machine
is shared and noisy: compare ratios, not absolute figures. ``--quick``: 5 objects only for MJX (batches 1 and
16), rollout at both counts.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import platform
import subprocess
import sys
import time

import jax
import numpy as np
import trimesh

import dexjax.sim as sim
from dexjax.objects import builtin_mesh, load_object_set, prepare_object_set
from dexjax.sim import mjx_backend
from dexjax.sim.settling import finish

_BASE = ('cube', 'box', 'box_with_hole', 'l_shape', 'cylinder')
_MJX_HEAPS = {1: 4, 16: 16, 64: 64}


def _box_corners(lo, hi) -> np.ndarray:
  return np.array(list(itertools.product(*zip(lo, hi))), float)


def _hulls(name: str, mesh: trimesh.Trimesh) -> tuple[np.ndarray, ...]:
  if name == 'l_shape':  # the L's foot and upright
    lo, hi = mesh.bounds
    return (_box_corners(lo, [lo[0] + 0.08, hi[1], lo[2] + 0.02]), _box_corners([hi[0] - 0.02, lo[1], lo[2]], hi))
  if name == 'cylinder':  # a 16-sided hull keeps MJX's per-face work small
    return (np.asarray(trimesh.creation.cylinder(radius=0.025, height=0.08, sections=16).vertices),)
  return (np.asarray(mesh.convex_hull.vertices),)


def objects(count: int) -> list[sim.HeapObject]:
  """The benchmark's ``count`` (5 or 10) objects."""
  out = []
  for scale in (1.0, 0.75):
    for name in _BASE:
      mesh = builtin_mesh(name)
      hulls = _hulls(name, mesh)
      mesh.apply_scale(scale)
      out.append(sim.heap_object(mesh, [h * scale for h in hulls], name=f'{name}@{scale}'))
  return out[:count]


def states(count: int, num_heaps: int):
  dist = sim.HeapDistribution(min_count=count, max_count=count)
  keys = jax.random.split(jax.random.key(0), num_heaps)
  return jax.tree.map(np.asarray, jax.jit(jax.vmap(lambda k: sim.sample_heap_state(k, count, dist)))(keys))


def _summary(result: sim.SettleResult) -> dict:
  return {'settled_fraction': float(result.settled.mean()), 'mean_steps': float(result.steps.mean()),
          'left_bin': int(result.left_bin.sum()), 'diverged': int(result.diverged.sum())}


def _time_rollout(objs: list[sim.HeapObject], st: sim.HeapState, repeats: int) -> tuple[float, sim.SettleResult]:
  """(median seconds, last result) of ``repeats`` C-engine settles of the same heaps."""
  times, result = [], None
  for _ in range(repeats):
    t = time.perf_counter()
    result = sim.settle(objs, st, backend='rollout')
    times.append(time.perf_counter() - t)
  return float(np.median(times)), result


def bench_rollout(count: int, num_heaps: int, repeats: int) -> dict:
  seconds, result = _time_rollout(objects(count), states(count, num_heaps), repeats)
  return {'heaps': num_heaps, 'threads': os.cpu_count(), 'seconds_median': seconds,
          'heaps_per_s': num_heaps / seconds, **_summary(result)}


def bench_procedural(level: int, num_heaps: int, repeats: int) -> dict:
  prepared, rejected = prepare_object_set(load_object_set([f'procedural:L{level}/0:30']), model=False)
  objs = sim.heap_objects(prepared)
  st = jax.tree.map(np.asarray, sim.sample_heap_states(jax.random.key(level), num_heaps, len(objs)))
  seconds, result = _time_rollout(objs, st, repeats)
  return {'heaps': num_heaps, 'objects': int(result.mask.sum()), 'rejected_objects': len(rejected),
          'seconds_median': seconds, 'heaps_per_s': num_heaps / seconds,
          'never_settled_objects': int(result.never_settled.sum()), **_summary(result)}


def mjx_child(count: int, batches: list[int]) -> None:
  """Runs in the pinned child: one JSON line per batch size, flushed as soon as it is measured."""
  objs = objects(count)
  for batch in batches:
    num_heaps = _MJX_HEAPS.get(batch, batch)
    st = states(count, num_heaps)
    settings = sim.SettleSettings(mjx_batch_size=batch)
    raw = mjx_backend.settle_in_process(objs, st, settings)
    result = finish(objs, st, raw['qpos'], raw['qvel'], raw['steps'], raw['diverged'], settings, 'mjx')
    print(json.dumps({'batch': batch, 'heaps': num_heaps, 'compile_s': raw['compile_seconds'],
                      'run_s': raw['run_seconds'], 'heaps_per_s': num_heaps / raw['run_seconds'],
                      **_summary(result)}), flush=True)


def start_mjx(count: int, batches: list[int], core: int) -> tuple[subprocess.Popen, float]:
  """Starts the MJX child for ``count`` objects pinned to ``core``; returns (process, start time)."""
  cmd = mjx_backend.pinned_python_command(['--mjx-child', str(count), '--batches', ','.join(map(str, batches))],
                                          script=os.path.abspath(__file__), core=core)
  return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True), time.perf_counter()


def collect_mjx(proc: subprocess.Popen, started: float, batches: list[int], timeout: float) -> dict:
  """Waits for an MJX child until ``timeout`` seconds after its start; rows per batch size (timeouts marked)."""
  timed_out = False
  try:
    out, err = proc.communicate(timeout=max(1.0, timeout - (time.perf_counter() - started)))
  except subprocess.TimeoutExpired:
    proc.kill()
    out, err = proc.communicate()
    timed_out = True
  rows = {}
  for line in out.splitlines():
    if line.startswith('{'):
      row = json.loads(line)
      batch = row.pop('batch')
      rows[str(batch)] = {'status': 'ok', **row}
  for batch in batches:
    if str(batch) not in rows:
      if timed_out:
        rows[str(batch)] = {'status': 'timeout', 'timeout_s': timeout}
        timed_out = False  # later batch sizes never started
      else:
        rows[str(batch)] = {'status': 'not_run' if proc.returncode == 0 or rows else 'failed',
                            'stderr_tail': err[-500:]}
  rows['child_wall_s'] = time.perf_counter() - started
  return rows


def main() -> None:
  ap = argparse.ArgumentParser()
  ap.add_argument('--quick', action='store_true')
  ap.add_argument('--rollout-heaps', type=int, default=64)
  ap.add_argument('--repeats', type=int, default=3)
  ap.add_argument('--mjx-timeout-5', type=float, default=600.0)
  ap.add_argument('--mjx-timeout-10', type=float, default=2700.0)
  ap.add_argument('--mjx-child', type=int, default=None, help=argparse.SUPPRESS)
  ap.add_argument('--batches', default='1,16,64', help=argparse.SUPPRESS)
  args = ap.parse_args()
  if args.mjx_child is not None:
    mjx_child(args.mjx_child, [int(b) for b in args.batches.split(',')])
    return

  counts = (5, 10)
  report: dict = {
      'benchmark': 'heap_throughput', 'quick': args.quick,
      'machine': {'cpus': os.cpu_count(), 'platform': platform.platform(), 'python': platform.python_version()},
      'versions': {'jax': jax.__version__, 'mujoco': __import__('mujoco').__version__},
      'settings': {k: getattr(sim.SettleSettings(), k) for k in (
          'timestep', 'max_steps', 'linear_speed_tol', 'angular_speed_tol', 'impratio', 'rolling_friction',
          'contact_timeconst')},
      'rollout': {}, 'rollout_procedural': {}, 'mjx': {},
  }
  for count in counts:
    report['rollout'][str(count)] = bench_rollout(count, args.rollout_heaps, args.repeats)
  for level in (1, 2, 3):
    report['rollout_procedural'][f'L{level}'] = bench_procedural(level, args.rollout_heaps, args.repeats)
  mjx_plan = {5: [1, 16]} if args.quick else {5: [1, 16, 64], 10: [1, 16, 64]}
  timeouts = {5: args.mjx_timeout_5, 10: args.mjx_timeout_10}
  # One child per object count, each pinned to its own core, run side by side after the rollout runs.
  children = {count: start_mjx(count, batches, core) for core, (count, batches) in enumerate(mjx_plan.items())}
  for count, (proc, started) in children.items():
    report['mjx'][str(count)] = collect_mjx(proc, started, mjx_plan[count], timeouts[count])
  ratios = {}
  for count in counts:
    rates = [row['heaps_per_s'] for key, row in report['mjx'].get(str(count), {}).items()
             if isinstance(row, dict) and row.get('status') == 'ok']
    ratios[str(count)] = report['rollout'][str(count)]['heaps_per_s'] / max(rates) if rates else None
  report['ratio_rollout_over_mjx'] = ratios
  report['notes'] = ('heaps_per_s: settled-or-stopped heaps per second; mjx run time excludes compile_s; MJX '
                     'child processes pinned to one core (deadlock guard); ratio uses the best MJX batch size')
  print(json.dumps(report))


if __name__ == '__main__':
  main()
