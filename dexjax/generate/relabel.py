"""Fresh reward draws for a generated dataset's rows: the same heaps, images and grasps, new Monte-Carlo draws.

A row's label is the seed's reward S(x, u): the robust probability of M = 10 perturbed draws (mass, gripper pose),
thresholded. `relabel_shard` labels every grasp a shard stores again, in the heap the shard stores (object ids,
settled poses and per-object friction), with keys of the caller's choosing and any M:

* with the generator's own keys (`generation_reward_keys`) it reproduces the stored labels, which checks that
  nothing else enters them;
* with independent keys and the same M it measures how much of a label is the luck of its draws (how many
  labels a second labelling flips);
* with many draws (M = 100) it estimates each grasp's robust probability well enough to score a predictor that
  knew it: the best any model of the image can do against the M = 10 labels (``scripts/pretrain.py ceiling``,
  docs/models.md);
* with ``friction_draws`` > 0 the target's friction is drawn from the heap distribution's prior instead of taken
  from the heap state, which a depth image does not show: the probability then averages over frictions.

`relabel_dataset` writes a whole run again with M draws per label (``python -m dexjax.generate --relabel SRC
--num-samples M --out DIR``): the same shards, with each row's reward drawn from the generator's own key and M
draws, so the new run is the one ``python -m dexjax.generate`` would have written with ``reward.num_samples: M``
(save the rows of images that lost actions, whose keys are not stored: they get other, independent keys).
The shipped suction model learns from such a run (M = 100) the probability that a 10-draw label is positive,
without the noise of each row's own 10 draws (`loop.target: label_probability`, docs/models.md).

Work is per image and gripper, padded to the run's actions per gripper, so one compilation serves a dataset.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from dexjax.cli import OutputError
from dexjax.config import validate_generate_config
from dexjax.data.manifest import finish_shard, load_manifest, open_manifest, pending_shards
from dexjax.data.shards import GRIPPER_NAMES, Shard, read_shard, shard_path
from dexjax.generate.config import fingerprint
from dexjax.generate.labels import PARALLEL_JAW, SUCTION, LabelParams, reward_keys
from dexjax.generate.pipeline import image_label_key, label_params
from dexjax.generate.report import RowStats
from dexjax.generate.run import check_run_dir, load_run_config, write_run_config
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp
from dexjax.objects.sets import usable_objects
from dexjax.quality.heap_reward import (NONE, NOT_ROBUST, HeapScene, RewardRecord, decided_by_robustness, heap_scene,
                                        parallel_jaw_heap_reward, suction_heap_reward)
from dexjax.sim.heap import HeapDistribution, sample_friction


@struct.dataclass
class Relabelled:
  """New labels of a shard's rows, in the shard's row order.

  Attributes:
    reward: (N,) bool, S(x, u) with the new draws (robust probability > threshold, where the other checks pass).
    robust_probability: (N,) float32, the new Monte-Carlo estimate (mean over friction draws, if any).
    failure: (N,) int32 index into `dexjax.quality.REWARD_FAILURES` (with friction draws: the first draw's).
  """

  reward: np.ndarray
  robust_probability: np.ndarray
  failure: np.ndarray


def row_grasp(pose: jax.Array, gripper: int, jaw_width: float) -> ParallelJawGrasp | SuctionGrasp:
  """The world-frame grasp a row's ``grasp_pose`` (4, 4) stands for (`dexjax.grasps.parallel_jaw_pose` and
  `suction_pose` inverted): x is the approach, y the jaw axis; a jaw opens to ``jaw_width`` metres."""
  if gripper == PARALLEL_JAW:
    return ParallelJawGrasp(center=pose[:3, 3], axis=pose[:3, 1], approach=pose[:3, 0],
                            width=jnp.asarray(jaw_width, jnp.float32))
  return SuctionGrasp(center=pose[:3, 3], approach=pose[:3, 0])


def _reward(key: jax.Array, pose: jax.Array, scene: HeapScene, params: LabelParams, gripper: int) -> RewardRecord:
  grasp = row_grasp(pose, gripper, params.parallel_jaw_sampler.gripper_width)
  if gripper == PARALLEL_JAW:
    return parallel_jaw_heap_reward(key, grasp, scene, params.bin, params.parallel_jaw, params.reward,
                                    params.parallel_jaw_perturbations)
  return suction_heap_reward(key, grasp, scene, params.bin, params.suction, params.reward,
                             params.suction_perturbations)


def _rows_reward(keys: jax.Array, poses: jax.Array, scene: HeapScene, params: LabelParams, gripper: int,
                 friction: jax.Array | None) -> RewardRecord:
  """Rewards of (A,) rows of one image and gripper; ``friction`` (A,) replaces every slot's, per row."""
  def one(key, pose, f):
    heap = scene if f is None else scene.replace(friction=jnp.full_like(scene.friction, f))
    return _reward(key, pose, heap, params, gripper)
  return jax.vmap(one)(keys, poses, friction)


_rows_reward_jit = jax.jit(_rows_reward, static_argnames=('gripper',))


def generation_reward_keys(seed: int, shard_index: int, shard: Shard, num_actions: int
                           ) -> tuple[jax.Array, np.ndarray]:
  """The keys the generator drew the rows' rewards with: (keys (N,), known (N,) bool).

  A row is an action that existed, in order; when an image kept all ``num_actions`` actions of a gripper, row a
  of it is action a and its key is known. Where some actions did not exist, which action a row was is not
  stored: row a gets action a's key, which may belong to another action, and ``known`` is False.
  """
  rows = shard.rows
  keys, known = [], []
  for j in range(len(shard.images['heap_id'])):
    label_key = image_label_key(seed, shard_index, j)
    for gripper in (PARALLEL_JAW, SUCTION):
      count = int(np.sum((rows['image_index'] == j) & (rows['gripper'] == gripper)))
      keys.append(reward_keys(label_key, gripper, num_actions)[:count])
      known.append(np.full(count, count == num_actions))
  # Groups were made in (image, gripper) order; rows are put back in the shard's order.
  order = np.argsort(np.lexsort((rows['gripper'], rows['image_index'])), kind='stable')
  return jnp.concatenate(keys)[order], np.concatenate(known)[order]


def relabel_shard(models: Sequence, params: LabelParams, shard: Shard, key: jax.Array | None, *,
                  keys: jax.Array | None = None, friction_draws: int = 0,
                  heap: HeapDistribution = HeapDistribution()) -> Relabelled:
  """The rewards of ``shard``'s rows drawn again (see the module docstring).

  Args:
    models: the run's N object models (`dexjax.objects.usable_objects`, in the run's order: the shard's
      ``object_ids`` index them).
    params: the run's `LabelParams` (`dexjax.generate.label_params`); its ``reward.num_samples`` is M.
    shard: the shard (`dexjax.data.read_shard`).
    key: a `jax.random` key; row i draws with ``fold_in(key, i)``. Ignored (may be None) when ``keys`` is given.
    keys: optional (N,) keys, one per row (e.g. the first of `generation_reward_keys`).
    friction_draws: 0: the heap state's friction (as generation); k > 0: the probability is the mean over k
      frictions drawn from ``heap``'s prior, each with M draws.
    heap: the heap distribution whose friction prior ``friction_draws`` uses (the run's ``config.heap``).

  Returns:
    `Relabelled`, (N,) arrays in the shard's row order.
  """
  rows, images = shard.rows, shard.images
  n = len(rows['gripper'])
  size = params.policy.actions_per_gripper
  if keys is None:
    keys = jax.vmap(jax.random.fold_in, in_axes=(None, 0))(key, jnp.arange(n))
  out = {'reward': np.zeros(n, bool), 'robust_probability': np.zeros(n, np.float32),
         'failure': np.zeros(n, np.int32)}
  for j in range(len(images['heap_id'])):
    ids = np.asarray(images['object_ids'][j])
    scene = heap_scene(models, ids, ids >= 0, images['object_poses'][j], images['object_friction'][j],
                       mass=images['object_mass'][j])
    for gripper in (PARALLEL_JAW, SUCTION):
      index = np.nonzero((rows['image_index'] == j) & (rows['gripper'] == gripper))[0]
      if len(index) == 0:
        continue
      if len(index) > size:
        raise ValueError(f'{shard.path}: image {j} has {len(index)} rows of gripper {gripper}, more than the '
                         f'run\'s policy.actions_per_gripper = {size}')
      padded = np.concatenate([index, np.full(size - len(index), index[0])])
      poses = jnp.asarray(rows['grasp_pose'][padded])
      probability, failure = _draws(keys[padded], poses, scene, params, gripper, friction_draws, heap)
      out['robust_probability'][index] = probability[:len(index)]
      out['failure'][index] = failure[:len(index)]
  # The reward's last check, on the (possibly averaged) probability: `heap_reward` orders the checks so.
  decided = decided_by_robustness(out['failure'])
  out['reward'] = decided & (out['robust_probability'] > params.reward.threshold)
  out['failure'] = np.where(out['reward'], NONE, np.where(decided, NOT_ROBUST, out['failure'])).astype(np.int32)
  return Relabelled(**out)


def _draws(keys, poses, scene, params, gripper, friction_draws, heap) -> tuple[np.ndarray, np.ndarray]:
  """(robust probability (A,), failure (A,)) of padded rows, averaged over ``friction_draws`` prior frictions."""
  if friction_draws == 0:
    record = _rows_reward_jit(keys, poses, scene, params, gripper=gripper, friction=None)
    return np.asarray(record.robust_probability), np.asarray(record.failure)
  probability, failure = [], None
  for d in range(friction_draws):
    draw_keys = jax.vmap(lambda k: jax.random.split(jax.random.fold_in(k, d)))(keys)
    friction = jax.vmap(sample_friction, in_axes=(0, None))(draw_keys[:, 1], heap)
    record = _rows_reward_jit(draw_keys[:, 0], poses, scene, params, gripper=gripper, friction=friction)
    probability.append(np.asarray(record.robust_probability))
    failure = np.asarray(record.failure) if failure is None else failure
  return np.mean(probability, axis=0).astype(np.float32), failure


def relabel_dataset(data_dir: str | os.PathLike[str], out_dir: str | os.PathLike[str], num_samples: int, *,
                    config_path: str | os.PathLike[str] | None = None, cache_dir: str | None = None,
                    progress: bool = True, overwrite: bool = False) -> dict[str, Any]:
  """Writes the finished shards of run ``data_dir`` to ``out_dir`` with every reward drawn again with M =
  ``num_samples`` (see the module docstring); resumable like a generation run (rerun to continue).

  Args:
    data_dir: a finished or partial run of ``python -m dexjax.generate`` (its shards, manifest, ``config.json``).
    out_dir: the new run's directory (`dexjax.generate.check_run_dir` rules): shards, manifest and a
      ``config.json`` whose ``reward.num_samples`` is M. Shard i of it is shard i of ``data_dir`` relabelled.
    num_samples: M, Monte-Carlo draws per label (the seed's is 10).
    config_path: the config file the run was made with (default: the defaults; `load_run_config` checks it).
    cache_dir: object cache (as for generation).
    progress: a progress bar on stderr.
    overwrite: as for `dexjax.generate.generate_dataset`.

  Returns:
    ``rows``, per-gripper counts (`dexjax.generate.RowStats`) of the rows written by this call, ``flipped`` per
    gripper (the share of those rows whose reward changed), ``shards`` (``total``, ``skipped``, ``written``,
    ``missing``: the source's unfinished shards), ``seconds`` and ``rows_per_s``.

  Raises:
    FileNotFoundError: ``data_dir`` holds no run; `ConfigError`: ``config_path`` is not the run's.
    OutputError: ``out_dir`` is ``data_dir`` or may not be written; ValueError: ``num_samples`` < 1.
  """
  if num_samples < 1:
    raise ValueError(f'--num-samples: expected an integer >= 1, got {num_samples}')
  source = Path(data_dir)
  out = check_run_dir(out_dir, overwrite=overwrite)
  if out.resolve() == source.resolve():
    raise OutputError('--out', out, 'is the run being relabelled; expected a new directory')
  config = load_run_config(source, config_path)
  new = dataclasses.replace(config, reward=config.reward.replace(num_samples=num_samples))
  validate_generate_config(new, os.fspath(config_path or 'the default config'))
  manifest = load_manifest(source)
  if manifest is None:
    raise FileNotFoundError(f'{source}: no manifest.json (not a run of python -m dexjax.generate)')
  total, key = manifest.num_shards, fingerprint(new)
  open_manifest(out, key, new.seed, total, replace_foreign=overwrite)
  write_run_config(out, new)
  todo = pending_shards(out, total, key, seed=new.seed)
  ready = [i for i in todo if i in manifest.shards]
  models = [p.model for p in usable_objects(new, cache_dir)[0]] if ready else []
  params = label_params(new)
  stats, changed = RowStats(), {}
  clock = time.perf_counter()
  for index in _progress(ready, progress):
    shard = read_shard(shard_path(source, index))
    keys, _ = generation_reward_keys(config.seed, index, shard, params.policy.actions_per_gripper)
    new_labels = relabel_shard(models, params, shard, None, keys=keys)
    rows = dict(shard.rows, reward=new_labels.reward.astype(np.int8), failure=new_labels.failure.astype(np.int8),
                robust_probability=new_labels.robust_probability)
    finish_shard(out, index, shard.images, rows, {'config_fingerprint': key, 'seed': new.seed,
                                                  'relabelled_from': os.fspath(source.resolve())})
    stats.add(rows)
    for code in np.unique(rows['gripper']):
      sel = rows['gripper'] == code
      flips = changed.setdefault(int(code), [0, 0])
      flips[0] += int((rows['reward'][sel] != shard.rows['reward'][sel]).sum())
      flips[1] += int(sel.sum())
  seconds = time.perf_counter() - clock
  summary = stats.to_dict(seconds)
  summary['flipped'] = {GRIPPER_NAMES[code]: round(f / n, 4) for code, (f, n) in sorted(changed.items())}
  summary['shards'] = {'total': total, 'skipped': total - len(todo), 'written': len(ready),
                       'missing': len(todo) - len(ready)}
  summary['out_dir'] = os.fspath(out)
  return summary


def _progress(items: list[int], show: bool):
  if not show:
    return items
  from tqdm.auto import tqdm  # pylint: disable=g-import-not-at-top
  return tqdm(items, desc='relabel', unit='shard')


__all__ = ['Relabelled', 'generation_reward_keys', 'relabel_dataset', 'relabel_shard', 'row_grasp']
