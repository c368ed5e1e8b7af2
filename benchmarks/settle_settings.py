"""What each physics setting of heap settling costs and buys, against the defaults in the same run; one JSON object.

  python benchmarks/settle_settings.py [--objects procedural:L2/0:20] [--heaps 64] [--repeats 2] [--variants ...]

``--heaps`` heap states are drawn once from the Dex-Net 4.0 distribution over ``--objects`` (the generation
benchmark's objects by default) and settled with the C engine (`settle(backend='rollout')`, ``os.cpu_count()``
threads, model building included) under the defaults and under each variant, which changes one group of
`SettleSettings` fields. Per variant: ``heaps_per_s`` (median of ``--repeats`` calls, after one untimed call),
``speed_ratio`` (over the defaults' rate), and what the resting states are worth: ``settled`` (fraction of heaps
at rest before ``max_steps``), ``mean_steps``, ``left_bin`` and ``never_settled`` (objects), ``diverged`` (heaps),
and the penetration of each heap's final state (its deepest contact, MuJoCo's contact distance after
``mj_forward`` at the final poses): max and median over heaps, millimetres; ``com_shift_from_defaults_mm``: how far
the variant's resting centres of mass lie from the defaults' (median, 90th percentile, max). A variant MuJoCo aborts on is reported
with its error.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time

import jax
import mujoco
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from _machine import describe  # noqa: E402

from dexjax.generate import GenerateConfig  # noqa: E402
from dexjax.objects.sets import usable_objects  # noqa: E402
from dexjax.sim.bodies import heap_objects  # noqa: E402
from dexjax.sim.heap import sample_heap_states, select_heap  # noqa: E402
from dexjax.sim.scene import build_heap_model, heap_slots  # noqa: E402
from dexjax.sim.settling import settle  # noqa: E402

VARIANTS = {
    'no_sleep': {'sleep': False},
    'chunk_steps_25': {'chunk_steps': 25},
    'timestep_6ms': {'timestep': 0.006, 'contact_timeconst': 0.012},
    'timestep_8ms': {'timestep': 0.008, 'contact_timeconst': 0.016},
    'no_rolling_friction': {'rolling_friction': 0.0},
    'impratio_1': {'impratio': 1.0},
    'solver_10_ls_5': {'solver_iterations': 10, 'ls_iterations': 5},
    'solver_5_ls_3': {'solver_iterations': 5, 'ls_iterations': 3},
}


def _penetration(objects, states, settings, result) -> np.ndarray:
  """(B,) deepest contact penetration (metres, >= 0) of each heap's final poses."""
  depths = []
  for b in range(states.mask.shape[0]):
    state = select_heap(states, b)
    model = build_heap_model(objects, state, settings)
    data = mujoco.MjData(model)
    data.qpos[:] = result.poses[b, heap_slots(state)].reshape(-1)
    mujoco.mj_forward(model, data)
    depths.append(-min([data.contact[i].dist for i in range(data.ncon)] + [0.0]))
  return np.asarray(depths)


def _measure(objects, states, settings, repeats: int, reference=None) -> tuple[dict, object]:
  """The variant's figures and its result; with ``reference`` (the defaults' result) also how far its resting
  centres of mass lie from the defaults' (objects at rest in both)."""
  settle(objects, states, backend='rollout', settings=settings)
  seconds = []
  for _ in range(repeats):
    start = time.perf_counter()
    result = settle(objects, states, backend='rollout', settings=settings)
    seconds.append(time.perf_counter() - start)
  depth = _penetration(objects, states, settings, result)
  entry = {'heaps_per_s': round(len(result.settled) / float(np.median(seconds)), 1),
          'settled': round(float(result.settled.mean()), 4), 'mean_steps': round(float(result.steps.mean()), 1),
          'left_bin': int(result.left_bin.sum()), 'never_settled': int(result.never_settled.sum()),
          'diverged': int(result.diverged.sum()), 'max_penetration_mm': round(1e3 * float(depth.max()), 2),
          'median_penetration_mm': round(1e3 * float(np.median(depth)), 2)}
  if reference is not None:
    both = result.mask & ~result.never_settled & ~reference.never_settled
    shift = 1e3 * np.linalg.norm(result.centers - reference.centers, axis=-1)[both]
    entry['com_shift_from_defaults_mm'] = {'median': round(float(np.median(shift)), 3),
                                           'p90': round(float(np.quantile(shift, 0.9)), 3),
                                           'max': round(float(shift.max()), 2)}
  return entry, result


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
  p.add_argument('--objects', nargs='+', default=['procedural:L2/0:20'])
  p.add_argument('--heaps', type=int, default=64)
  p.add_argument('--repeats', type=int, default=2)
  p.add_argument('--seed', type=int, default=3)
  p.add_argument('--cache-dir', help='object cache (default: $DEXJAX_CACHE or ~/.cache/dexjax/objects)')
  p.add_argument('--variants', nargs='+', choices=sorted(VARIANTS), default=list(VARIANTS),
                 help='the variants to run (default: all)')
  args = p.parse_args()
  config = GenerateConfig()
  config = dataclasses.replace(config, objects=dataclasses.replace(config.objects, sources=tuple(args.objects)))
  prepared, _ = usable_objects(config, args.cache_dir)
  objects = heap_objects(prepared)
  states = sample_heap_states(jax.random.key(args.seed), args.heaps, len(objects), config.heap)
  defaults, reference = _measure(objects, states, config.settle, args.repeats)
  result = {'machine': describe(), 'objects': args.objects, 'heaps': args.heaps,
            'mean_objects': round(float(np.asarray(states.mask).sum(axis=1).mean()), 2), 'defaults': defaults,
            'variants': {}}
  for name in args.variants:
    fields = VARIANTS[name]
    try:
      entry, _ = _measure(objects, states, config.settle.replace(**fields), args.repeats, reference)
      entry['speed_ratio'] = round(entry['heaps_per_s'] / defaults['heaps_per_s'], 2)
    except Exception as e:  # pylint: disable=broad-except  (MuJoCo aborts some cheap solvers: report it)
      entry = {'error': f'{type(e).__name__}: {e}'.splitlines()[0]}
    result['variants'][name] = {'changes': fields, **entry}
  print(json.dumps(result, indent=1))


if __name__ == '__main__':
  main()
