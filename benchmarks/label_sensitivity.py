"""How dataset labels change with two modelling choices, one JSON object on stdout: the signed-distance grid
resolution (64^3, 100^3, 128^3) and the supervisor's disturbance wrench eps_w.

  python benchmarks/label_sensitivity.py [--levels 1 2 3] [--objects 12] [--heaps 6] [--images-per-heap 2]
                                       [--supervisor-grasps 100] [--grids 64 100 128] [--seed 0]

The labels a dataset stores depend on each object's signed distance grid (contacts, normals, collisions).
For every difficulty level this measures how often coarser grids give the same label as the finest one, on
the two kinds of labels generation makes (`dexjax.generate` defaults, `GenerateConfig()`):

* **heap rewards** S(x, u): ``--heaps`` heaps of the level's first ``--objects`` procedural objects are
  drawn from the seed's state distribution and settled (MuJoCo C engine); each is rendered from
  ``--images-per-heap`` cameras of the seed's distribution (500 x 500), and every candidate of both image
  samplers (antipodal depth-edge pairs, suction points above the bin floor) is turned into its 3-D grasp once.
  The same grasps are then labelled with the heap reward (collisions, exactly one object, robust probability
  with M = 10 and the state's friction) on the heap's models built at each grid size, with the same keys, so the
  only difference between the labels is the grid.
* **supervisor grasps**: ``--supervisor-grasps`` grasps per object and gripper sampled on the finest grid's model
  (`sample_antipodal_grasps` / `sample_suction_grasps`), each labelled robust when its robust quality (M = 25,
  the supervisor's perturbations, same keys at every grid) exceeds 0.75.

* **the labels' own noise**: the finest grid's labels again with other Monte-Carlo keys (``other_key``), the
  scale against which a grid's disagreement is small or not;
* **the supervisor's eps_w**: the same supervisor grasps at the finest grid, labelled again with the
  disturbance wrench switched off (``disturbance_sigma = 0``; the seed lists pose, friction, mass and gravity
  for the supervisor, not eps_w): ``supervisor_without_disturbance``.

Reported per level, gripper and grid: ``agreement`` (fraction of grasps whose label equals the finest grid's),
``positive_rate``, ``flips_to_positive`` / ``flips_to_negative`` (counts relative to the finest grid),
``mean_abs_probability_difference`` and, for rewards, the agreement of the failure code; plus the seconds spent
labelling at each grid (``label_s``, compile excluded) and the time to build one object model (``build_s``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from dexjax.generate import GenerateConfig, label_params, pickable_mask
from dexjax.generate.cameras import image_size, run_camera
from dexjax.geometry import build_object_model
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.objects import load_object_set, prepare_object_set
from dexjax.quality import (HeapScene, parallel_jaw_heap_reward, robust_parallel_jaw_quality, robust_suction_quality,
                            suction_heap_reward)
from dexjax.quality.heap_reward import stack_models
from dexjax.quality.robust import SUPERVISOR_SAMPLES, SUPERVISOR_THRESHOLD
from dexjax.render import DepthRenderer, build_render_scene
from dexjax.sampling import (parallel_jaw_grasp_3d, sample_antipodal_grasps, sample_antipodal_image_grasps,
                             sample_suction_grasps, sample_suction_image_grasps, suction_grasp_3d)
from dexjax.sim import heap_objects, sample_heap_states, settle
import os

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from _machine import describe  # noqa: E402

CONFIG = GenerateConfig()
PARAMS = label_params(CONFIG)


def _stack(trees):
  return jax.tree.map(lambda *xs: np.stack(xs), *trees)


@jax.jit
def _candidates(key, depth, camera):
  """The image's candidate 3-D grasps of both grippers and their validity (generation's samplers)."""
  k_pj, k_su = jax.random.split(key)
  pick = pickable_mask(depth, camera, PARAMS.bin, PARAMS.policy.floor_clearance)
  pj, pj_ok = sample_antipodal_image_grasps(k_pj, depth, camera, PARAMS.parallel_jaw_sampler, mask=pick)
  su, su_ok = sample_suction_image_grasps(k_su, depth, camera, PARAMS.suction_sampler, mask=pick)
  pj3 = jax.vmap(lambda g: parallel_jaw_grasp_3d(camera, g))(pj)
  su3 = jax.vmap(lambda g: suction_grasp_3d(camera, g))(su)
  return pj3, pj_ok, su3, su_ok


def _reward_fn(heap_reward, gripper, perturbations):
  def one(key, grasp, scene):
    return heap_reward(key, grasp, scene, PARAMS.bin, gripper, PARAMS.reward, perturbations)
  return jax.jit(jax.vmap(one, in_axes=(0, 0, None)))


_PJ_REWARD = _reward_fn(parallel_jaw_heap_reward, PARAMS.parallel_jaw, PARAMS.parallel_jaw_perturbations)
_SU_REWARD = _reward_fn(suction_heap_reward, PARAMS.suction, PARAMS.suction_perturbations)


def _supervisor_fn(robust, gripper, perturbations, disturbance=True):
  pert = perturbations.replace(num_samples=SUPERVISOR_SAMPLES)
  if not disturbance:
    pert = pert.replace(disturbance_sigma=0.0)
  return jax.jit(jax.vmap(lambda k, m, g: robust(k, m, g, gripper, pert).probability, in_axes=(0, None, 0)))


_PJ_SUPERVISOR = _supervisor_fn(robust_parallel_jaw_quality, ParallelJawGripper(),
                                CONFIG.grippers.parallel_jaw_perturbations)
_SU_SUPERVISOR = _supervisor_fn(robust_suction_quality, SuctionGripper(), CONFIG.grippers.suction_perturbations)
_PJ_NO_DISTURBANCE = _supervisor_fn(robust_parallel_jaw_quality, ParallelJawGripper(),
                                    CONFIG.grippers.parallel_jaw_perturbations, disturbance=False)
_SU_NO_DISTURBANCE = _supervisor_fn(robust_suction_quality, SuctionGripper(), CONFIG.grippers.suction_perturbations,
                                    disturbance=False)


def _compare(labels: dict[int, np.ndarray], probs: dict[int, np.ndarray], reference: int, timings: dict[int, float],
             failures: dict[int, np.ndarray] | None = None) -> dict:
  ref = labels[reference]
  out = {'grasps': int(ref.size)}
  for grid, lab in labels.items():
    row = {'positive_rate': round(float(lab.mean()), 4), 'agreement': round(float((lab == ref).mean()), 5),
           'flips_to_positive': int(np.sum(lab & ~ref)), 'flips_to_negative': int(np.sum(~lab & ref)),
           'mean_abs_probability_difference': round(float(np.abs(probs[grid] - probs[reference]).mean()), 5),
           'label_s': round(timings[grid], 2)}
    if failures is not None:
      row['failure_agreement'] = round(float((failures[grid] == failures[reference]).mean()), 5)
    out[str(grid)] = row
  return out


def _heap_grasps(key, prepared, num_heaps, images_per_heap, renderer):
  """Settles heaps, renders them and samples candidates: per image (slot ids, mask, poses, friction, grasps)."""
  objects = heap_objects(prepared)
  k_heap, k_cam, k_cand = jax.random.split(key, 3)
  states = sample_heap_states(k_heap, num_heaps, len(objects), CONFIG.heap)
  result = settle(objects, states, backend='rollout', settings=CONFIG.settle)
  meshes = [p.mesh for p in prepared]
  images = []
  for h in range(num_heaps):
    if result.diverged[h]:
      continue
    mask = result.mask[h] & ~result.left_bin[h]
    if not mask.any():
      continue
    ids = np.where(mask, np.asarray(states.object_ids[h]), -1).astype(np.int32)
    friction = np.where(mask, np.asarray(states.friction[h]), 0.0).astype(np.float32)
    scene = build_render_scene(meshes, ids, result.poses[h], mask, bin=CONFIG.bin)
    for c in range(images_per_heap):
      j = h * images_per_heap + c
      camera = run_camera(jax.random.fold_in(k_cam, j), CONFIG)
      depth = renderer.render(scene, camera).depth
      pj, pj_ok, su, su_ok = _candidates(jax.random.fold_in(k_cand, j), jnp.asarray(depth), camera)
      images.append((ids, mask, result.poses[h], friction, pj, np.asarray(pj_ok), su, np.asarray(su_ok)))
  return images


def _scene(models, ids, mask, poses, friction):
  slot_ids = np.where(mask, ids, ids[np.argmax(mask)])
  return HeapScene(models=stack_models([models[int(i)] for i in slot_ids]),
                   object_ids=jnp.arange(len(ids), dtype=jnp.int32), mask=jnp.asarray(mask),
                   poses=jnp.asarray(poses, jnp.float32), friction=jnp.asarray(friction))


def _rewards(images, models_by_grid, reference, key):
  """Per gripper: {grid: labels}, {grid: probabilities}, {grid: failure codes}, {grid: seconds}; the key
  ``'other_key'`` holds the reference grid's labels with other Monte-Carlo draws (the label's own noise)."""
  out = {}
  runs = [(grid, models, key) for grid, models in models_by_grid.items()]
  runs.append(('other_key', models_by_grid[reference], jax.random.fold_in(key, 1 << 20)))
  for name, fn, grasp_at, ok_at in (('parallel_jaw', _PJ_REWARD, 4, 5), ('suction', _SU_REWARD, 6, 7)):
    labels, probs, fails, secs = {}, {}, {}, {}
    for grid, models, run_key in runs:
      lab, pro, fai, elapsed = [], [], [], 0.0
      for i, image in enumerate(images):
        ok, grasps = image[ok_at], image[grasp_at]  # every candidate slot (one shape: one compile per grid)
        keys = jax.random.split(jax.random.fold_in(run_key, i), ok.size)
        scene = _scene(models, *image[:4])
        if grid not in secs:  # compile once per grid's shapes outside the timing
          jax.block_until_ready(fn(keys, grasps, scene).reward)
          secs[grid] = 0.0
        clock = time.perf_counter()
        record = jax.block_until_ready(fn(keys, grasps, scene))
        elapsed += time.perf_counter() - clock
        lab.append(np.asarray(record.reward, bool)[ok])
        pro.append(np.asarray(record.robust_probability)[ok])
        fai.append(np.asarray(record.failure)[ok])
      labels[grid], probs[grid], fails[grid], secs[grid] = (np.concatenate(lab), np.concatenate(pro),
                                                            np.concatenate(fai), elapsed)
    out[name] = (labels, probs, fails, secs)
  return out


def _supervisor(models_by_grid, reference, num_grasps, key):
  """Per gripper: {grid: robust labels}, {grid: probabilities}, {grid: seconds} on grasps sampled at
  ``reference``; the keys ``'no_disturbance'`` and ``'other_key'`` hold the reference grid's labels without eps_w
  and with other Monte-Carlo draws (the label's own noise)."""
  out = {}
  for name, sample, fn, quiet in (('parallel_jaw', sample_antipodal_grasps, _PJ_SUPERVISOR, _PJ_NO_DISTURBANCE),
                                  ('suction', sample_suction_grasps, _SU_SUPERVISOR, _SU_NO_DISTURBANCE)):
    grasps, valid = [], []  # all num_grasps slots per object (one shape: one compile per grid), valid ones kept
    for o, model in enumerate(models_by_grid[reference]):
      g, ok = sample(jax.random.fold_in(key, o), model, num_grasps)
      grasps.append(g)
      valid.append(np.asarray(ok))
    keys = [jax.random.split(jax.random.fold_in(key, 1000 + o), num_grasps) for o in range(len(grasps))]
    labels, probs, secs = {}, {}, {}
    for grid, models in models_by_grid.items():
      pro, elapsed = [], 0.0
      jax.block_until_ready(fn(keys[0], models[0], grasps[0]))
      for o, model in enumerate(models):
        clock = time.perf_counter()
        pro.append(np.asarray(jax.block_until_ready(fn(keys[o], model, grasps[o])))[valid[o]])
        elapsed += time.perf_counter() - clock
      probs[grid] = np.concatenate(pro)
      labels[grid], secs[grid] = probs[grid] > SUPERVISOR_THRESHOLD, elapsed
    probs['no_disturbance'] = np.concatenate([np.asarray(quiet(keys[o], model, grasps[o]))[valid[o]]
                                              for o, model in enumerate(models_by_grid[reference])])
    labels['no_disturbance'], secs['no_disturbance'] = probs['no_disturbance'] > SUPERVISOR_THRESHOLD, 0.0
    other = [jax.random.split(jax.random.fold_in(key, 5000 + o), num_grasps) for o in range(len(grasps))]
    probs['other_key'] = np.concatenate([np.asarray(fn(other[o], model, grasps[o]))[valid[o]]
                                         for o, model in enumerate(models_by_grid[reference])])
    labels['other_key'], secs['other_key'] = probs['other_key'] > SUPERVISOR_THRESHOLD, 0.0
    out[name] = (labels, probs, secs)
  return out


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
  parser.add_argument('--levels', type=int, nargs='+', default=[1, 2, 3])
  parser.add_argument('--objects', type=int, default=12, help='procedural objects per level')
  parser.add_argument('--heaps', type=int, default=6, help='heaps per level')
  parser.add_argument('--images-per-heap', type=int, default=2)
  parser.add_argument('--supervisor-grasps', type=int, default=100, help='grasps per object and gripper')
  parser.add_argument('--grids', type=int, nargs='+', default=[64, 100, 128])
  parser.add_argument('--seed', type=int, default=0)
  args = parser.parse_args()
  grids = sorted(args.grids)
  reference = grids[-1]
  renderer = DepthRenderer(*image_size(CONFIG))
  key = jax.random.key(args.seed)
  report = {'benchmark': 'label_sensitivity', 'reference_grid': reference, 'grids': grids,
            'machine': describe(), 'levels': {}}
  for level in args.levels:
    loaded = load_object_set([f'procedural:L{level}/0:{args.objects}'])
    models_by_grid, build_s = {}, {}
    for grid in grids:
      prepared, rejected = prepare_object_set(loaded, grid_size=grid)
      if rejected:
        raise SystemExit(f'level {level}: rejected {rejected}')
      models_by_grid[grid] = [p.model for p in prepared]
      clock = time.perf_counter()  # one uncached build, to weigh accuracy against set-up time
      build_object_model(prepared[0].mesh, grid_size=grid)
      build_s[grid] = time.perf_counter() - clock
    k_level = jax.random.fold_in(key, level)
    images = _heap_grasps(k_level, prepared, args.heaps, args.images_per_heap, renderer)
    rewards = _rewards(images, models_by_grid, reference, jax.random.fold_in(k_level, 1))
    supervised = _supervisor(models_by_grid, reference, args.supervisor_grasps, jax.random.fold_in(k_level, 2))
    report['levels'][str(level)] = {
        'objects': len(prepared), 'images': len(images),
        'build_s_one_object': {str(g): round(s, 3) for g, s in build_s.items()},
        'heap_rewards': {name: _compare(lab, pro, reference, sec, fai)
                         for name, (lab, pro, fai, sec) in rewards.items()},
        'supervisor': {name: _compare(lab, pro, reference, sec) for name, (lab, pro, sec) in supervised.items()},
    }
    print(json.dumps({'level_done': level}), flush=True, file=sys.stderr)
  print(json.dumps(report, indent=1))


if __name__ == '__main__':
  main()
