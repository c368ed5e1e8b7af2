"""Gradient ascent on the smooth robust quality from sampled grasps on unseen objects: one JSON object on stdout.

  python benchmarks/gradient_ascent.py [--objects procedural:L1/95000@0 ...] [--grasps 24] [--steps 20]
                                       [--draws 100] [--grid 64] [--reach 2048] [--quick]

For each object (default: procedural objects 95000 and 95001 of each level, which no dataset used) and gripper,
``--grasps`` grasps drawn by the object's sampler (`dexjax.sample_antipodal_grasps` / `sample_suction_grasps`,
key 1) are climbed by `dexjax.quality.optimize_grasp` (``--steps`` steps, key 2, `jax.vmap` over the grasps, one
compiled program per gripper) and judged, before and after, by the *hard* robust probability with ``--draws``
independent Monte-Carlo draws (key 99). The baseline is the sampled grasps themselves, judged in the same run.

Reported per object and gripper: the mean probability before and after (the final iterate), how many grasps were
raised, lowered or unchanged, and the seconds of one ascent batch (the first call of each gripper includes its
compilation: ``compile_and_run_s``); totals per gripper. ``--quick``: the first two objects, 8 grasps.

Which starts *could* be raised (``--reach`` candidates, 0 skips it): ``--reach`` more grasps from the same sampler
(key 3) are judged by the same hard probability; a start is ``improvable`` when some candidate scores higher and lies
within the ascent's trust region of it (centre within ``AscentSettings.max_translation``, orientation within
``max_rotation``: the angle between approaches for suction, the rotation between gripper frames, either jaw
order, for the parallel jaw). ``raised_improvable`` counts the improvable starts the ascent raised. This is a lower
bound on what the trust region holds (the sampler's grasps only: surface normals as suction approaches), but an
object on which no candidate anywhere scores above 0 (``candidates_above_zero``) cannot be helped by a local
search.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import time

import jax
import numpy as np

import dexjax as dj
from dexjax.grasps import ParallelJawGrasp, parallel_jaw_pose
from dexjax.quality import AscentSettings, optimize_grasp

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from _machine import describe  # noqa: E402

OBJECTS = [f'procedural:L{level}/{index}@0' for index in (95000, 95001) for level in (1, 2, 3)]


def _judges(draws: int):
  """Per gripper: its sampler and the hard judge ``judge(model, grasps)`` -> (N,) robust probability with ``draws``
  draws (key 99), jitted once (the object is an argument: one program serves every object)."""
  def judge(quality, perturbations):
    return jax.jit(jax.vmap(lambda model, g: quality(jax.random.key(99), model, g, perturbations=perturbations)
                            .probability, in_axes=(None, 0)))
  return {
      'parallel_jaw': (dj.sample_antipodal_grasps,
                       judge(dj.robust_parallel_jaw_quality, dj.parallel_jaw_perturbations(draws))),
      'suction': (dj.sample_suction_grasps, judge(dj.robust_suction_quality, dj.suction_perturbations(draws))),
  }


def _rotation_angles(starts, candidates) -> np.ndarray:
  """(S, C) angle, radians, between each start's orientation and each candidate's (see the module docstring)."""
  if not isinstance(starts, ParallelJawGrasp):
    cosine = np.asarray(starts.approach) @ np.asarray(candidates.approach).T
    return np.arccos(np.clip(cosine, -1.0, 1.0))
  frames = [np.asarray(jax.vmap(parallel_jaw_pose)(g))[:, :3, :3] for g in (starts, candidates)]
  traces = np.einsum('sij,cij->sc', *frames)  # trace(R_s^T R_c)
  flipped = np.einsum('sij,cij->sc', frames[0], frames[1] * np.array([1.0, -1.0, -1.0]))  # jaws swapped
  cosine = (np.maximum(traces, flipped) - 1.0) / 2.0
  return np.arccos(np.clip(cosine, -1.0, 1.0))


def _judge_in_chunks(judge, model, grasps, count: int, chunk: int = 64) -> np.ndarray:
  """(count,) ``judge(model, .)`` of ``count`` grasps in fixed chunks (the last padded with the first grasps: one
  program for starts, final grasps and candidates alike)."""
  index = np.arange(-(-count // chunk) * chunk) % max(count, 1)
  scores = [np.asarray(judge(model, jax.tree.map(lambda x: x[index[i:i + chunk]], grasps)))
            for i in range(0, index.size, chunk)]
  return np.concatenate(scores)[:count] if count else np.zeros(0)


def _improvable(starts, before, candidates, scores, settings: AscentSettings) -> np.ndarray:
  """(S,) bool: a candidate scores above the start within the trust region."""
  distance = np.linalg.norm(np.asarray(starts.center)[:, None] - np.asarray(candidates.center)[None], axis=-1)
  near = (distance <= settings.max_translation) & (_rotation_angles(starts, candidates) <= settings.max_rotation)
  return np.any(near & (scores[None] > before[:, None]), axis=1)


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
  p.add_argument('--objects', nargs='+', default=OBJECTS)
  p.add_argument('--grasps', type=int, default=24)
  p.add_argument('--steps', type=int, default=20)
  p.add_argument('--draws', type=int, default=100)
  p.add_argument('--grid', type=int, default=64)
  p.add_argument('--reach', type=int, default=2048, help='candidates for the improvable count (0: skip)')
  p.add_argument('--quick', action='store_true')
  args = p.parse_args()
  if args.quick:
    args.objects, args.grasps = args.objects[:2], 8
  ascend = jax.jit(jax.vmap(functools.partial(optimize_grasp, steps=args.steps), in_axes=(None, None, 0)))
  rows, totals, compiled = [], {}, set()
  judges = _judges(args.draws)
  for name in args.objects:
    model = dj.load_object_model(name, grid_size=args.grid)
    for gripper, (sample, judge) in judges.items():
      grasps, valid = sample(jax.random.key(1), model, 4 * args.grasps)
      index = np.flatnonzero(np.asarray(valid))[:args.grasps]
      row = {'object': name, 'gripper': gripper, 'grasps': int(index.size)}
      if index.size:
        starts = jax.tree.map(lambda x: x[index], grasps)
        start = time.perf_counter()
        result = jax.block_until_ready(ascend(jax.random.key(2), model, starts))
        seconds = time.perf_counter() - start
        before = _judge_in_chunks(judge, model, starts, int(index.size))
        after = _judge_in_chunks(judge, model, result.grasp, int(index.size))
        row.update(before=round(float(before.mean()), 4), after=round(float(after.mean()), 4),
                   raised=int((after > before).sum()), lowered=int((after < before).sum()),
                   unchanged=int((after == before).sum()))
        if args.reach:
          candidates, ok = sample(jax.random.key(3), model, args.reach)
          candidates = jax.tree.map(lambda x: x[np.asarray(ok)], candidates)
          scores = _judge_in_chunks(judge, model, candidates, int(np.sum(ok)))
          improvable = _improvable(starts, before, candidates, scores, AscentSettings())
          row.update(candidates=int(scores.size), candidates_above_zero=int((scores > 0).sum()),
                     improvable=int(improvable.sum()), raised_improvable=int((improvable & (after > before)).sum()))
        row['compile_and_run_s' if gripper not in compiled else 'run_s'] = round(seconds, 2)
        compiled.add(gripper)
        total = totals.setdefault(gripper, {'grasps': 0, 'raised': 0, 'lowered': 0, 'unchanged': 0,
                                            'before': [], 'after': []})
        for key in ('raised', 'lowered', 'unchanged', 'improvable', 'raised_improvable'):
          total[key] = total.get(key, 0) + row.get(key, 0)
        total['grasps'] += int(index.size)
        total['before'] += before.tolist()
        total['after'] += after.tolist()
      rows.append(row)
  for total in totals.values():
    total['before'] = round(float(np.mean(total['before'])), 4)
    total['after'] = round(float(np.mean(total['after'])), 4)
  print(json.dumps({
      'benchmark': 'gradient_ascent', 'steps': args.steps, 'draws': args.draws, 'grid': args.grid,
      'baseline': 'the sampled grasps, judged by the same hard robust probability in the same run',
      'objects': rows, 'totals': totals,
      'machine': describe(),
  }, indent=1))


if __name__ == '__main__':
  main()
