"""Heap settling throughput: MuJoCo C engine (`rollout`) vs. pybullet (the seed's engine) and MJX, one JSON object.

  python benchmarks/heap_throughput.py [--quick] [--no-mjx] [--rollout-heaps 64] [--repeats 3] [--mjx-timeout-5 600]
                                       [--mjx-timeout-10 2700] [--pybullet-processes 2]

Heaps of 5 and 10 objects are drawn from the Dex-Net 4.0 distribution with a fixed object set per count (so
MJX compiles once per count and batch size, and every engine settles the very same heaps): the built-in cube,
box, box with hole (its convex hull), L (two boxes) and cylinder (a 16-sided hull), plus the same five at 0.75
scale for 10 objects. ``heaps_per_s`` counts settled-or-stopped heaps (every object slower than 0.005 m/s and
0.1 rad/s, or 500 steps) per second:

* ``rollout``: one `dexjax.sim.settle(backend='rollout')` call over ``--rollout-heaps`` heaps with
  ``os.cpu_count()`` threads (dt 4 ms, the physics of ``settings``), model building included; median of
  ``--repeats`` calls.
* ``pybullet`` (the baseline; `_pybullet_baseline.py`): the seed settled its heaps with pybullet, so the same
  heaps are settled in pybullet 3.2 DIRECT mode with pybullet's own engine defaults (time step 1/240 s, 50
  solver iterations, no sub-steps; see ``pybullet.engine_defaults``): the same convex collision hulls, mass,
  centre of mass and inertia, the same drop poses (`dexjax.sim.drop_poses`, what dexjax simulates), the same
  bin (ground plane and four wall boxes), the heap state's per-object friction (bin at 1.0; Bullet multiplies
  the two bodies' coefficients), gravity 9.81 m/s^2, the seed's thresholds checked after every step and the
  500-step cap. Run on ``--pybullet-processes`` worker processes (default ``os.cpu_count()``, one DIRECT
  client each, heaps handed out one at a time), as dexjax uses both cores with two threads; world building
  per heap included, process start-up not. Timed repeats alternate with the ``rollout`` ones;
  ``ratio_rollout_over_pybullet`` is the median of the per-repeat ratios.
  ``pybullet_rolling_friction`` (a sensitivity run, not the baseline): the same, plus dexjax's rolling (2 mm)
  and spinning (5 mm) friction on every object (``changeDynamics``), to show how much of pybullet's time goes
  to round objects that never stop rolling without it.
* ``mjx``: batch sizes 1, 16 and 64 (4, 16 and 64 heaps), one compiled ``jit(vmap)`` call per batch, timed
  after compilation (``compile_s`` is reported separately). Each object count runs in its own child process
  pinned to one CPU core (the deadlock guard; the two children side by side on different cores, after the
  rollout runs) with a timeout; a timeout is reported as ``"status": "timeout"``.

Both ``rollout`` and ``pybullet`` report ``settled_fraction`` (heaps at rest before the cap), ``mean_steps``,
``mean_settle_time_s`` (simulated seconds), ``left_bin_fraction`` (objects whose centre of mass ended
outside the bin's inner box or below its floor) and ``mean_final_com_height_m`` (a cross-check that both
engines build comparable heaps).

``rollout_procedural``: ``--rollout-heaps`` heaps per difficulty level drawn from the level's first 30
procedural objects (cached convex decompositions, prepared before timing) with the seed's object count
(Poisson(5) truncated to [3, 10]), the C engine only.

``ratio_rollout_over_mjx`` divides rollout heaps/s by the best MJX heaps/s at the same object count. The machine
is shared and noisy: compare ratios, not absolute figures. ``--no-mjx``: no MJX part. ``--quick``: 5 objects only for MJX (batches 1 and
16); rollout and pybullet at both counts.

Baseline install: ``pip install "pybullet>=3.2"`` (a manylinux wheel for CPython 3.11), or ``pip install
-e ".[bench]"``. Without pybullet, ``rollout`` is timed alone (same heaps, warm-up and repeats), the ``pybullet``
entries say ``"status": "missing"`` with the reason and ``ratio_rollout_over_pybullet`` is null.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import os
import subprocess
import sys
import time

import jax
import numpy as np
import trimesh

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from _machine import describe  # noqa: E402
from _optional import import_optional, missing, version  # noqa: E402
import _pybullet_baseline as pybullet_baseline  # pylint: disable=g-import-not-at-top,wrong-import-position

import dexjax.sim as sim  # pylint: disable=wrong-import-position
from dexjax.objects import builtin_mesh, load_object_set, prepare_object_set
from dexjax.sim import mjx_backend  # pylint: disable=wrong-import-position
from dexjax.sim.settling import finish  # pylint: disable=wrong-import-position

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


def _summary(result: sim.SettleResult, timestep: float = sim.SettleSettings().timestep) -> dict:
  return {'settled_fraction': float(result.settled.mean()), 'mean_steps': float(result.steps.mean()),
          'mean_settle_time_s': float(result.steps.mean()) * timestep,
          'left_bin': int(result.left_bin.sum()), 'left_bin_fraction': float(result.left_bin.sum() / result.mask.sum()),
          'diverged': int(result.diverged.sum()),
          'mean_final_com_height_m': float(result.centers[..., 2][result.mask].mean())}


def _time_rollout(objs: list[sim.HeapObject], st: sim.HeapState, repeats: int) -> tuple[float, sim.SettleResult]:
  """(median seconds, last result) of ``repeats`` C-engine settles of the same heaps."""
  times, result = [], None
  for _ in range(repeats):
    t = time.perf_counter()
    result = sim.settle(objs, st, backend='rollout')
    times.append(time.perf_counter() - t)
  return float(np.median(times)), result


def bullet_heaps(objs: list[sim.HeapObject], st: sim.HeapState) -> tuple[list, list]:
  """(pybullet objects, pybullet heaps) of the same heaps, from the drop poses dexjax simulates."""
  settings = sim.SettleSettings()
  poses = [sim.drop_poses(objs, sim.select_heap(st, b), settings) for b in range(st.mask.shape[0])]
  bodies = pybullet_baseline.bullet_objects(objs)
  heaps = pybullet_baseline.bullet_heaps(bodies, np.array([p for p, _ in poses]), np.array([q for _, q in poses]),
                                         np.asarray(st.object_ids), np.asarray(st.friction), np.asarray(st.mask))
  return bodies, heaps


def bench_rollout_and_pybullet(count: int, num_heaps: int, repeats: int, processes: int
                               ) -> tuple[dict, dict, dict, float]:
  """C-engine and pybullet settling of the same heaps, repeats interleaved.

  Returns:
    (rollout, pybullet, pybullet with dexjax's rolling and torsional friction, median per-repeat ratio of
    rollout heaps/s over pybullet heaps/s).
  """
  objs, st = objects(count), states(count, num_heaps)
  bodies, heaps = bullet_heaps(objs, st)
  settings = sim.SettleSettings()
  rolling = [dataclasses.replace(h, rolling_friction=settings.rolling_friction,
                                 spinning_friction=settings.torsional_friction) for h in heaps]
  pool = pybullet_baseline.BulletPool(bodies, sim.bin_boxes(settings.bin)[1:], processes)
  try:
    pool.settle(heaps[:processes])  # warm-up: workers started and initialised
    sim.settle(objs, jax.tree.map(lambda x: x[:processes], st), backend='rollout')
    times = {'rollout': [], 'pybullet': [], 'rolling': []}
    results = {}
    for _ in range(repeats):
      t = time.perf_counter()
      results['rollout'] = sim.settle(objs, st, backend='rollout')
      times['rollout'].append(time.perf_counter() - t)
      for key, work in (('pybullet', heaps), ('rolling', rolling)):
        t = time.perf_counter()
        results[key] = pool.settle(work)
        times[key].append(time.perf_counter() - t)
  finally:
    pool.close()
  mj_result = results['rollout']
  rollout = _rollout_entry(num_heaps, float(np.median(times['rollout'])), mj_result)
  bullet = {}
  for key in ('pybullet', 'rolling'):
    summary = pybullet_baseline.summary(results[key], settings.bin.inner_size)
    bullet[key] = {'heaps': num_heaps, 'processes': processes, 'seconds_median': float(np.median(times[key])),
                   'heaps_per_s': num_heaps / float(np.median(times[key])), **summary,
                   'mean_settle_time_s': summary['mean_steps'] * pybullet_baseline.TIME_STEP,
                   'heaps_settled_by_both_engines': int(sum(r['settled'] for r, ok in zip(results[key],
                                                                                         mj_result.settled) if ok)),
                   'rollout_over_this_median_ratio': float(np.median(np.array(times[key]) / np.array(times['rollout'])))}
  return rollout, bullet['pybullet'], bullet['rolling'], bullet['pybullet']['rollout_over_this_median_ratio']


def bench_rollout(count: int, num_heaps: int, repeats: int) -> dict:
  """C-engine settling alone (no pybullet): the ``rollout`` entry of `bench_rollout_and_pybullet`."""
  objs, st = objects(count), states(count, num_heaps)
  sim.settle(objs, jax.tree.map(lambda x: x[:2], st), backend='rollout')  # warm-up, as beside pybullet
  seconds, result = _time_rollout(objs, st, repeats)
  return _rollout_entry(num_heaps, seconds, result)


def _rollout_entry(num_heaps: int, seconds: float, result: sim.SettleResult) -> dict:
  return {'heaps': num_heaps, 'threads': os.cpu_count(), 'seconds_median': seconds,
          'heaps_per_s': num_heaps / seconds, **_summary(result)}


def _pybullet_settings(processes: int) -> dict:
  """pybullet's engine settings for the report."""
  return {
      'mode': 'DIRECT', 'engine_defaults': pybullet_baseline.engine_parameters(),
      'time_step_s': pybullet_baseline.TIME_STEP, 'max_steps': pybullet_baseline.MAX_STEPS,
      'linear_speed_tol': pybullet_baseline.LINEAR_TOL, 'angular_speed_tol': pybullet_baseline.ANGULAR_TOL,
      'gravity': -pybullet_baseline.GRAVITY, 'processes': processes,
      'chosen': 'gravity; per-object lateralFriction from the heap state, bin and ground 1.0 (Bullet multiplies '
                'the pair); explicit mass and inertia (principal frame at the centre of mass); everything else '
                "pybullet's defaults (no rolling/spinning friction, restitution 0)"}


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
  ap.add_argument('--pybullet-processes', type=int, default=os.cpu_count() or 1)
  ap.add_argument('--no-mjx', action='store_true', help='skip the MJX part (its compiles take 5-45 minutes)')
  ap.add_argument('--mjx-child', type=int, default=None, help=argparse.SUPPRESS)
  ap.add_argument('--batches', default='1,16,64', help=argparse.SUPPRESS)
  args = ap.parse_args()
  if args.mjx_child is not None:
    mjx_child(args.mjx_child, [int(b) for b in args.batches.split(',')])
    return

  counts = (5, 10)
  _, no_pybullet = import_optional('pybullet')
  report: dict = {
      'benchmark': 'heap_throughput', 'quick': args.quick,
      'machine': describe(),
      'versions': {'jax': jax.__version__, 'mujoco': __import__('mujoco').__version__,
                   'pybullet': version('pybullet')},
      'settings': {k: getattr(sim.SettleSettings(), k) for k in (
          'timestep', 'max_steps', 'linear_speed_tol', 'angular_speed_tol', 'impratio', 'rolling_friction',
          'contact_timeconst', 'sleep', 'sleep_tolerance', 'chunk_steps')},
      'pybullet_settings': missing(no_pybullet) if no_pybullet else _pybullet_settings(args.pybullet_processes),
      'rollout': {}, 'pybullet': {}, 'pybullet_rolling_friction': {}, 'ratio_rollout_over_pybullet': {},
      'rollout_procedural': {}, 'mjx': {},
  }
  for count in counts:
    if no_pybullet:
      rollout, bullet, rolling, ratio = (bench_rollout(count, args.rollout_heaps, args.repeats), missing(no_pybullet),
                                         missing(no_pybullet), None)
    else:
      rollout, bullet, rolling, ratio = bench_rollout_and_pybullet(count, args.rollout_heaps, args.repeats,
                                                                   args.pybullet_processes)
    report['rollout'][str(count)] = rollout
    report['pybullet'][str(count)] = bullet
    report['pybullet_rolling_friction'][str(count)] = rolling
    report['ratio_rollout_over_pybullet'][str(count)] = ratio
  for level in (1, 2, 3):
    report['rollout_procedural'][f'L{level}'] = bench_procedural(level, args.rollout_heaps, args.repeats)
  mjx_plan = {} if args.no_mjx else {5: [1, 16]} if args.quick else {5: [1, 16, 64], 10: [1, 16, 64]}
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
  report['notes'] = ('heaps_per_s: settled-or-stopped heaps per second; pybullet on the same heaps with its default '
                     f'engine settings (dt 1/240 s) on {args.pybullet_processes} worker processes (dexjax rollout: '
                     f'{os.cpu_count()} threads), repeats interleaved with rollout, ratio = median per-repeat '
                     'ratio; mjx run time excludes compile_s; MJX child processes pinned to one core (deadlock '
                     'guard); ratio_rollout_over_mjx uses the best MJX batch size')
  print(json.dumps(report))


if __name__ == '__main__':
  main()
