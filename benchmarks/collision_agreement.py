"""How often the two judges' one collision rule decides differently because of the objects' geometry, one JSON object
on stdout.

  python benchmarks/collision_agreement.py [--levels 1 2 3] [--objects 25] [--bins 3] [--seed 77] [--object-seed 77]

The labels' reward and the physics judge apply the same collision rule (`dexjax.bench.collision_rule`): the
reward's gripper samples (fingers and palm, or cup and shaft, swept back by the pre-grasp standoff) may not lie
deeper than the collision tolerance (1 mm) inside an object or the bin. The reward tests them against each
object's signed distance grid (the mesh), the judge against the convex hulls the simulation collides with
(a convex decomposition of the mesh; the mesh's own hull for convex objects). This measures what that difference
does on the grasps policies propose: for every difficulty level, ``--bins`` bins of ``--objects`` procedural
objects (the benchmark's bins: `PickingWorld.fill`, 25 objects dropped and settled), one camera of the seed's
distribution each, and every candidate of the generation's image samplers (antipodal pairs, suction points) as a
3-D grasp, judged by both tests. Reported per level and gripper: candidates, ``agreement`` (same verdict),
``grid_only`` (the grid sees an object collision the hulls do not) and ``hulls_only`` (the reverse), the bin
verdicts' agreement, and seconds per grasp of each test.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time

import jax
import numpy as np

from dexjax.bench.collision_rule import collision_samples, gripper_collision
from dexjax.bench.world import PickingWorld
from dexjax.generate import GenerateConfig, pickable_mask
from dexjax.generate.cameras import run_camera
from dexjax.quality.heap_reward import parallel_jaw_collisions, suction_collisions
from dexjax.sampling import (parallel_jaw_grasp_3d, sample_antipodal_image_grasps, sample_suction_image_grasps,
                             suction_grasp_3d)

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from _machine import describe  # noqa: E402


@jax.jit
def _candidates(key, depth, camera, params):
  """The image's candidate 3-D grasps of both grippers and their validity (generation's samplers)."""
  k_pj, k_su = jax.random.split(key)
  pick = pickable_mask(depth, camera, params.bin, params.policy.floor_clearance)
  pj, pj_ok = sample_antipodal_image_grasps(k_pj, depth, camera, params.parallel_jaw_sampler, mask=pick)
  su, su_ok = sample_suction_image_grasps(k_su, depth, camera, params.suction_sampler, mask=pick)
  return (jax.vmap(lambda g: parallel_jaw_grasp_3d(camera, g))(pj), pj_ok,
          jax.vmap(lambda g: suction_grasp_3d(camera, g))(su), su_ok)


@jax.jit
def _grid_tests(pj, su, scene, params):
  """(object, bin) collision verdicts of the reward (signed distance grids) for both grippers' grasps."""
  reward = params.reward
  pj_hits = jax.vmap(lambda g: parallel_jaw_collisions(g, scene, params.bin, params.parallel_jaw, reward))(pj)
  su_hits = jax.vmap(lambda g: suction_collisions(g, scene, params.bin, params.suction, reward))(su)
  return pj_hits, su_hits


def _hull_tests(world: PickingWorld, state, grasps, valid, gripper) -> tuple[np.ndarray, np.ndarray, float]:
  """(object hits, bin hits, seconds) of the judge's hull test on the valid grasps."""
  params = world.params
  obj, bin_ = [], []
  start = time.perf_counter()
  for i in np.flatnonzero(valid):
    grasp = jax.tree.map(lambda a, i=i: np.asarray(a[i]), grasps)
    reason, _ = gripper_collision(world.bodies, state.object_ids, state.mask, state.poses,
                                  collision_samples(grasp, gripper, params.reward.quality.geometry), params.bin,
                                  params.reward.quality.collision_tolerance)
    obj.append(reason == 'collision_object')
    bin_.append(reason == 'collision_bin')
  return np.array(obj, bool), np.array(bin_, bool), time.perf_counter() - start


def _compare(grid, hulls) -> dict:
  """Agreement of the object-collision verdicts (the bin's only where neither saw an object collision, since
  the hull test stops at the first object it enters)."""
  (g_obj, g_bin), (h_obj, h_bin) = grid, hulls
  n = len(g_obj)
  free = ~g_obj & ~h_obj
  return {'candidates': n, 'agreement': float(np.mean(g_obj == h_obj)) if n else None,
          'grid_only': int(np.sum(g_obj & ~h_obj)), 'hulls_only': int(np.sum(h_obj & ~g_obj)),
          'object_collisions_grid': int(g_obj.sum()),
          'bin_agreement': float(np.mean(g_bin[free] == h_bin[free])) if free.any() else None}


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
  p.add_argument('--levels', type=int, nargs='+', default=[1, 2, 3])
  p.add_argument('--objects', type=int, default=25)
  p.add_argument('--bins', type=int, default=3)
  p.add_argument('--seed', type=int, default=77, help='bins and cameras')
  p.add_argument('--object-seed', type=int, default=77, help='procedural object set')
  args = p.parse_args()
  out = {'machine': describe(), 'settings': vars(args), 'levels': {}}
  for level in args.levels:
    sources = (f'procedural:L{level}/0:{args.objects}@{args.object_seed}',)
    config = GenerateConfig()
    config = dataclasses.replace(config, objects=dataclasses.replace(config.objects, sources=sources))
    grid_s = hull_s = 0.0
    timed = 0  # candidates of the bins after the first (which compiles)
    totals = {'parallel_jaw': ([], [], [], []), 'suction': ([], [], [], [])}
    with PickingWorld(config) as world:
      params = world.params
      for b in range(args.bins):
        key = jax.random.fold_in(jax.random.key(args.seed), b)
        state = world.fill(jax.random.fold_in(key, 0), args.objects)
        camera = run_camera(jax.random.fold_in(key, 1), world.config)
        depth, _ = world.observe(jax.random.fold_in(key, 2), state, camera)
        clean = np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)
        pj, pj_ok, su, su_ok = jax.device_get(_candidates(jax.random.fold_in(key, 3), clean, camera, params))
        scene = world.scene(state)
        start = time.perf_counter()
        (pj_obj, pj_bin), (su_obj, su_bin) = jax.device_get(_grid_tests(pj, su, scene, params))
        grid_s += (time.perf_counter() - start) if b else 0.0  # the first bin compiles
        tests = (('parallel_jaw', pj, pj_ok, pj_obj, pj_bin, params.parallel_jaw),
                 ('suction', su, su_ok, su_obj, su_bin, params.suction))
        for name, grasps, ok, g_obj, g_bin, gripper in tests:
          h_obj, h_bin, seconds = _hull_tests(world, state, grasps, ok, gripper)
          hull_s += seconds if b else 0.0
          timed += int(np.sum(ok)) if b else 0
          lists = totals[name]
          lists[0].append(np.asarray(g_obj)[ok]), lists[1].append(np.asarray(g_bin)[ok])
          lists[2].append(h_obj), lists[3].append(h_bin)
    entry = {}
    for name, (g_obj, g_bin, h_obj, h_bin) in totals.items():
      entry[name] = _compare((np.concatenate(g_obj), np.concatenate(g_bin)),
                             (np.concatenate(h_obj), np.concatenate(h_bin)))
    entry['grid_seconds_per_grasp'] = grid_s / timed if timed else None
    entry['hull_seconds_per_grasp'] = hull_s / timed if timed else None
    out['levels'][str(level)] = entry
  print(json.dumps(out, indent=1))


if __name__ == '__main__':
  main()
