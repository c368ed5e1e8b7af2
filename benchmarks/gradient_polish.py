"""Does polishing the CEM's best grasps by gradient ascent on the GQ-CNN beat more CEM samples in the same time?
One JSON object on stdout.

  python benchmarks/gradient_polish.py [--quick] [--heaps 6] [--plans 3] [--per-heap 8] [--judge-keys 5]
                                       [--steps 8] [--objects procedural:L1/95000:95005 ...]

Heaps: ``--heaps`` bins of ``--per-heap`` objects drawn from ``--objects`` (default: five procedural objects of
each level, indices 95000-95004, which no training set used), dropped and settled, each seen by a camera of the
generation distribution with the benchmark's sensor noise and made into an `Observation` as a picking cell would
(`prepare_observation` against the empty-bin image), exactly as a trial of the Universal Picking benchmark.

Policies, per gripper, with the shipped GQ-CNNs (`dexjax.models.pretrained`):

* ``cem``: the seed's CEM (m 3, n 250, c 50, k 5, gamma 0.25), the baseline of the original's policy;
* ``cem_polish``: the same CEM, then `PolishParams(steps=--steps)` (the 8 best grasps of its last set, Adam on the
  logit of the network's probability, each iterate judged by the network; `dexjax.policy.polish`);
* ``cem_equal_time``: the CEM with n and c scaled by f, so that its plan takes as long as ``cem_polish``'s: f is
  the ratio of their median plan seconds on the first heap (measured here, after compilation), rounded up to a
  multiple of 1/4.

Every policy plans ``--plans`` times per heap (the same keys for all three; ``cem`` and ``cem_polish`` then run
the same CEM). Reported per gripper and policy: ``predicted`` (mean p of the chosen grasps), ``reward`` (the
analytic reward of the chosen grasp on the true heap, `dexjax.bench.analytic_verdict`, averaged over
``--judge-keys`` independent draws of its M = 10 Monte-Carlo samples; "no grasp" counts 0), ``robust_probability``
(the reward's robust probability on the grasped object), ``plan_s`` (median wall seconds after compilation) and
``compile_s``; ``polish_vs_equal_time``: the mean paired differences (polish minus equal time, same heap and key)
of predicted p and reward, with the fraction of plans in which polishing predicted higher.

The machine is shared and noisy: only the ratios of plan times measured in the same run mean anything.
``--quick``: 2 heaps, 2 plans, 3 judge keys.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time

import jax
import numpy as np

from dexjax.bench.analytic_judge import analytic_verdict
from dexjax.bench.runner import benchmark_config
from dexjax.bench.world import PickingWorld
from dexjax.generate.cameras import run_camera
from dexjax.models.shipped import PRETRAINED, load_models
from dexjax.policy import CEMParams, PolishParams, make_policy, plan_grasp, prepare_observation
from dexjax.policy.scorers import GRIPPERS

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from _machine import describe  # noqa: E402

OBJECTS = ['procedural:L1/95000:95005', 'procedural:L2/95000:95005', 'procedural:L3/95000:95005']
POLICIES = ('cem', 'cem_polish', 'cem_equal_time')


def make_heaps(world: PickingWorld, count: int, per_heap: int, seed: int) -> list[tuple]:
  """[(observation, camera, true scene)] of ``count`` settled, noisy heaps (as a benchmark trial's first look)."""
  heaps = []
  for i in range(count):
    key = jax.random.fold_in(jax.random.key(seed), i)
    camera = run_camera(jax.random.fold_in(key, 1), world.config)
    state = world.fill(jax.random.fold_in(key, 0), per_heap)
    depth, _ = world.observe(jax.random.fold_in(key, 2), state, camera)
    obs, _ = prepare_observation(depth, camera, background=world.empty_bin(camera))
    heaps.append((obs, camera, world.scene(state)))
  return heaps


def gripper_policy(gripper: str, models, scale: float = 1.0, polish: PolishParams | None = None):
  """The CEM policy of one gripper with the seed's n and c scaled by ``scale`` (and ``polish``)."""
  base = CEMParams()
  cem = base.replace(num_seed=int(round(base.num_seed * scale)), num_resample=int(round(base.num_resample * scale)))
  policy = make_policy(gripper, {gripper: models[gripper]}, polish=polish)
  return policy.replace(policies=tuple(p.replace(cem=cem) for p in policy.policies))


def compiled_plan(policy, obs) -> tuple[object, float]:
  start = time.perf_counter()
  compiled = jax.jit(plan_grasp).lower(jax.random.key(0), obs, policy).compile()
  return compiled, time.perf_counter() - start


def median_seconds(compiled, policy, obs, repeats: int = 5) -> float:
  jax.block_until_ready(compiled(jax.random.key(99), obs, policy))
  times = []
  for i in range(repeats):
    start = time.perf_counter()
    jax.block_until_ready(compiled(jax.random.key(100 + i), obs, policy))
    times.append(time.perf_counter() - start)
  return statistics.median(times)


def judged(action, camera, scene, judge_keys: int) -> tuple[float, float]:
  """(mean reward, mean robust probability) of a planned action over ``judge_keys`` reward draws (0 if none)."""
  if not bool(action.valid):
    return 0.0, 0.0
  records = [analytic_verdict(jax.random.key(1000 + j), action, camera, scene) for j in range(judge_keys)]
  return (statistics.fmean(float(r.reward) for r in records),
          statistics.fmean(float(r.robust_probability) for r in records))


def run_gripper(gripper: str, models, heaps, args) -> dict:
  polish = PolishParams(steps=args.steps)
  obs0 = heaps[0][0]
  policies = {'cem': gripper_policy(gripper, models), 'cem_polish': gripper_policy(gripper, models, polish=polish)}
  compiled, compile_s = {}, {}
  for name, policy in policies.items():
    compiled[name], compile_s[name] = compiled_plan(policy, obs0)
  t_cem = median_seconds(compiled['cem'], policies['cem'], obs0)
  t_polish = median_seconds(compiled['cem_polish'], policies['cem_polish'], obs0)
  scale = max(1.0, math.ceil(4.0 * t_polish / t_cem) / 4.0)
  policies['cem_equal_time'] = gripper_policy(gripper, models, scale)
  compiled['cem_equal_time'], compile_s['cem_equal_time'] = compiled_plan(policies['cem_equal_time'], obs0)
  rows = {name: {'predicted': [], 'reward': [], 'robust_probability': [], 'plan_s': [], 'valid': []}
          for name in POLICIES}
  for h, (obs, camera, scene) in enumerate(heaps):
    for p in range(args.plans):
      key = jax.random.fold_in(jax.random.key(args.seed), 1000 * h + p)
      for name in POLICIES:
        start = time.perf_counter()
        action = jax.device_get(jax.block_until_ready(compiled[name](key, obs, policies[name])))
        seconds = time.perf_counter() - start
        reward, robust = judged(action, camera, scene, args.judge_keys)
        row = rows[name]
        row['predicted'].append(float(action.probability) if bool(action.valid) else 0.0)
        row['reward'].append(reward)
        row['robust_probability'].append(robust)
        row['plan_s'].append(seconds)
        row['valid'].append(bool(action.valid))
  out = {'equal_time_scale': scale, 'n_c_equal_time': [int(round(250 * scale)), int(round(50 * scale))],
         'first_heap_plan_s': {'cem': round(t_cem, 4), 'cem_polish': round(t_polish, 4)}}
  for name in POLICIES:
    row = rows[name]
    out[name] = {'predicted': round(statistics.fmean(row['predicted']), 4),
                 'reward': round(statistics.fmean(row['reward']), 4),
                 'robust_probability': round(statistics.fmean(row['robust_probability']), 4),
                 'valid_fraction': round(statistics.fmean(row['valid']), 4),
                 'plan_s': round(statistics.median(row['plan_s']), 4), 'compile_s': round(compile_s[name], 2)}
  diff = lambda field: np.asarray(rows['cem_polish'][field]) - np.asarray(rows['cem_equal_time'][field])
  out['polish_vs_equal_time'] = {
      'predicted_mean_difference': round(float(diff('predicted').mean()), 4),
      'reward_mean_difference': round(float(diff('reward').mean()), 4),
      'robust_probability_mean_difference': round(float(diff('robust_probability').mean()), 4),
      'predicted_higher_fraction': round(float((diff('predicted') > 1e-6).mean()), 4),
      'plan_time_ratio': round(statistics.median(rows['cem_polish']['plan_s'])
                               / statistics.median(rows['cem_equal_time']['plan_s']), 3)}
  out['polish_vs_cem_predicted_gain'] = round(float(np.mean(np.asarray(rows['cem_polish']['predicted'])
                                                            - np.asarray(rows['cem']['predicted']))), 4)
  return out


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
  p.add_argument('--objects', nargs='+', default=OBJECTS)
  p.add_argument('--heaps', type=int, default=6)
  p.add_argument('--per-heap', type=int, default=8)
  p.add_argument('--plans', type=int, default=3)
  p.add_argument('--judge-keys', type=int, default=5)
  p.add_argument('--steps', type=int, default=PolishParams().steps)
  p.add_argument('--grippers', nargs='+', choices=GRIPPERS, default=list(GRIPPERS))
  p.add_argument('--model', default=PRETRAINED, help='a training run (default: the shipped models)')
  p.add_argument('--seed', type=int, default=0)
  p.add_argument('--quick', action='store_true')
  args = p.parse_args()
  if args.quick:
    args.heaps, args.plans, args.judge_keys = 2, 2, 3
  start = time.perf_counter()
  models = load_models(args.model, tuple(args.grippers))
  with PickingWorld(benchmark_config(args.objects)) as world:
    heaps = make_heaps(world, args.heaps, args.per_heap, args.seed)
  heaps_s = time.perf_counter() - start
  results = {g: run_gripper(g, models, heaps, args) for g in args.grippers}
  print(json.dumps({
      'benchmark': 'gradient_polish', 'objects': args.objects, 'heaps': args.heaps, 'per_heap': args.per_heap,
      'plans_per_heap': args.plans, 'judge_keys': args.judge_keys, 'polish_steps': args.steps,
      'polish': {k: v for k, v in PolishParams(steps=args.steps).__dict__.items()},
      'model': args.model, 'heaps_s': round(heaps_s, 1), 'grippers': results,
      'baseline': 'cem_equal_time: the seed CEM with n and c scaled to the polished plan time, same run',
      'machine': describe(),
      'total_s': round(time.perf_counter() - start, 1),
  }, indent=1))


if __name__ == '__main__':
  main()
