"""The training loop of one gripper's GQ-CNN: epochs of jitted SGD steps over a dataset directory, validation,
metrics, checkpoints and the best model.

Run layout under ``OUT``: ``metrics.jsonl`` and ``curves.png`` (both grippers, `dexjax.train.report`),
``<gripper>/checkpoints`` (resumable state, `dexjax.train.checkpoint`), ``<gripper>/best`` (the best model by
``checkpoint.best_metric``, loadable with `dexjax.models.load`).

Reproducibility: step ``t`` uses the key ``fold_in(seed, t)`` (augmentation and dropout) and the data order of
`dexjax.train.batches`, so a run resumed from any checkpoint performs the same steps on the same batches as an
uninterrupted run and ends with the same parameters.
"""

from __future__ import annotations

import functools
import os
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np
from tqdm.auto import tqdm

from dexjax.data.loader import DataDirs, dataset_label
from dexjax.models.saved import BEST_DIR, GraspQualityModel, save_model
from dexjax.train.batches import GripperStats, train_batches
from dexjax.train.checkpoint import Checkpointer, normalization_from_json, normalization_to_json
from dexjax.train.config import TrainConfig, config_to_dict
from dexjax.train.data import symmetrize
from dexjax.train.distributed import check_batch_size, data_mesh, is_main_process, replicate, shard_batch
from dexjax.train.validation import evaluate_model
from dexjax.train.report import append_record, format_epoch, plot_curves, prune_records
from dexjax.train.step import TrainState, create_state, learning_rate_schedule, make_optimizer, train_step


def _sgd_step(state: TrainState, batch: dict[str, jax.Array], norm, key: jax.Array, augment: bool,
              suction: bool, subtract_depth: bool = False, soft: bool = False) -> tuple[TrainState, dict]:
  """Augmentation (per-example symmetries), normalisation (crops relative to the grasp depth with
  ``subtract_depth``) and one `train_step`."""
  crops, poses = batch['crops'], batch['poses']
  if augment:
    keys = jax.random.split(jax.random.fold_in(key, 0), crops.shape[0])
    crops, poses = jax.vmap(functools.partial(symmetrize, suction=suction))(keys, crops, poses)
  crops, poses = norm.apply(crops, poses, subtract_depth)
  step_batch = {'crops': crops, 'poses': poses, 'labels': batch['labels'], 'weights': batch['weights']}
  if soft:
    step_batch['soft_labels'] = batch['soft_labels']
  return train_step(state, step_batch, jax.random.fold_in(key, 1))


sgd_step = jax.jit(_sgd_step, static_argnames=('augment', 'suction', 'subtract_depth', 'soft'), donate_argnums=0)


def _host(tree: Any) -> Any:
  """Host copy of a replicated pytree (each process holds the whole value on its devices)."""
  return jax.tree.map(lambda x: np.asarray(x.addressable_data(0)) if isinstance(x, jax.Array) else x, tree)


def _steps_per_epoch(stats: GripperStats, config: TrainConfig) -> int:
  """Whole batches of an epoch of the expected size (the learning-rate schedule's unit), at least 1."""
  return max(1, stats.examples_per_epoch(config.loop.class_balance) // config.loop.batch_size)


def check_trainable(gripper: str, stats: GripperStats, config: TrainConfig, data_dir: DataDirs = '') -> None:
  """Raises ValueError when ``gripper``'s training split cannot teach the network anything: fewer examples per
  epoch than one batch (no step would be taken), or no positive or no negative row (nothing to tell apart)."""
  where = f'{dataset_label(data_dir)}: ' if data_dir else ''
  examples = stats.examples_per_epoch(config.loop.class_balance)
  if examples < config.loop.batch_size:
    raise ValueError(f'{where}{gripper}: {examples} training examples per epoch, fewer than one batch: no step '
                     f'would be taken; expected at least loop.batch_size = {config.loop.batch_size} (generate more '
                     f'images, or lower loop.batch_size)')
  rows, positives = stats.train_rows, stats.train_positives
  if positives == 0 or positives == rows:
    missing = 'positive (reward 1)' if positives == 0 else 'negative (reward 0)'
    raise ValueError(f'{where}{gripper}: the training split has {rows} rows and no {missing} one: a GQ-CNN cannot '
                     f'learn to tell grasps apart; expected both labels (generate more images, or train other '
                     f'--grippers)')


def _better(metric: str, value: float | None, best: float | None) -> bool:
  if value is None:
    return False
  return best is None or (value < best if metric == 'val_loss' else value > best)


class Interrupted(Exception):
  """Raised by `train_gripper` when ``stop_after_steps`` is reached (what a killed run looks like on disk)."""


def train_gripper(data_dir: DataDirs, out_dir: str | os.PathLike, config: TrainConfig, gripper: str,
                  stats: GripperStats, *, resume: bool = False, progress: bool = False,
                  stop_after_steps: int | None = None, log=print, init_params: Any = None) -> dict[str, Any]:
  """Trains ``gripper``'s GQ-CNN for ``config.loop.epochs`` epochs; returns the best epoch's record.

  Args:
    data_dir: dataset directory (shards).
    out_dir: run directory ``OUT`` (see the module doc).
    config: the run's config.
    gripper: ``'parallel_jaw'`` or ``'suction'``.
    stats: training-split statistics (`dexjax.train.dataset_stats`).
    resume: continue from the newest checkpoint in ``OUT/<gripper>/checkpoints`` (a run that finished returns
      at once); without it, existing checkpoints are an error.
    progress: show a progress bar.
    stop_after_steps: stop (raising `Interrupted`, without saving) once the state reaches this step.
    log: where per-epoch lines go.
    init_params: parameters to start from (fine-tuning; same architecture) instead of a random initialisation.

  Raises:
    FileExistsError: checkpoints exist and ``resume`` is False.
    ValueError: the training split cannot teach anything (`check_trainable`).
    Interrupted: ``stop_after_steps`` was reached.
  """
  check_trainable(gripper, stats, config, data_dir)
  out, gripper_dir = Path(out_dir), Path(out_dir) / gripper
  mesh = data_mesh()
  check_batch_size(config.loop.batch_size, mesh)
  model_config = config.model_config(gripper)
  steps_per_epoch = _steps_per_epoch(stats, config)
  schedule = learning_rate_schedule(config.optimizer, steps_per_epoch)
  key = jax.random.key(config.seed)
  state = create_state(jax.random.fold_in(key, 0), model_config, make_optimizer(config.optimizer, steps_per_epoch))
  if init_params is not None:
    state = state.replace(params=jax.tree.map(jax.numpy.asarray, init_params))
  progress_data = {'epoch': 0, 'batch': 0, 'loss_sum': 0.0, 'accuracy_sum': 0.0, 'best': None, 'best_record': None,
                   'normalization': normalization_to_json(stats.normalization), 'config': config_to_dict(config),
                   'gripper': gripper}
  main = is_main_process()
  with Checkpointer(gripper_dir, config.checkpoint) as checkpointer:
    if checkpointer.latest_step() is not None:
      if not resume:
        raise FileExistsError(f'{checkpointer.directory}: checkpoints of an earlier run exist; pass --resume to '
                              f'continue it, or choose another --out')
      state, progress_data = checkpointer.restore(state)
      log(f'{gripper}: resumed at step {int(state.step)} (epoch {progress_data["epoch"] + 1}, batch '
          f'{progress_data["batch"]})')
    if main:
      prune_records(out, gripper, progress_data['epoch'])
    norm = replicate(normalization_from_json(progress_data['normalization']), mesh)
    state = replicate(state, mesh)
    suction = gripper == 'suction'
    record = model = None
    while progress_data['epoch'] < config.loop.epochs:
      epoch = progress_data['epoch']
      start, first_batch = time.perf_counter(), progress_data['batch']
      bar = tqdm(total=steps_per_epoch, initial=first_batch, desc=f'{gripper} epoch {epoch + 1}/{config.loop.epochs}',
                 unit='step', disable=not (progress and main), leave=False)
      for batch in train_batches(data_dir, config, gripper, epoch, stats, skip=first_batch):
        if stop_after_steps is not None and int(state.step) >= stop_after_steps:
          bar.close()
          raise Interrupted(f'{gripper}: stopped at step {int(state.step)}')
        step_key = jax.random.fold_in(key, int(state.step) + 1)
        state, metrics = sgd_step(state, shard_batch(batch, mesh), norm, step_key, augment=config.loop.symmetrize,
                                  suction=suction, subtract_depth=config.model.subtracts_grasp_depth,
                                  soft=config.loop.target != 'label')
        progress_data['batch'] += 1
        progress_data['loss_sum'] += float(metrics['loss'])
        progress_data['accuracy_sum'] += float(metrics['accuracy'])
        bar.update(1)
        rate = (progress_data['batch'] - first_batch) * config.loop.batch_size / max(bar.format_dict['elapsed'], 1e-9)
        bar.set_postfix(loss=f'{progress_data["loss_sum"] / progress_data["batch"]:.3f}', ex_s=f'{rate:.0f}')
        if int(state.step) % config.checkpoint.every_steps == 0:
          checkpointer.save(state, progress_data)
      bar.close()
      seconds = time.perf_counter() - start
      done = progress_data['batch']
      model = GraspQualityModel(params=_host(state.params), normalization=_host(norm), config=model_config,
                                gripper=gripper, crop_window=config.crop_window)
      val = evaluate_model(model, data_dir, config, 'val', progress=progress and main)
      record = {'gripper': gripper, 'epoch': epoch + 1, 'step': int(state.step),
                'train_loss': progress_data['loss_sum'] / done if done else None,
                'train_accuracy': progress_data['accuracy_sum'] / done if done else None,
                'learning_rate': float(schedule(int(state.step))),
                'examples_per_s': (done - first_batch) * config.loop.batch_size / max(seconds, 1e-9),
                **{f'val_{k}': v for k, v in val.items()}}
      metric = config.checkpoint.best_metric
      if main:
        append_record(out, record)
        plot_curves(out)
        log(format_epoch(record))
      if _better(metric, record.get(metric), progress_data['best']):
        save_model(gripper_dir / BEST_DIR, int(state.step), model, info=record)  # every process: orbax syncs
        progress_data['best'], progress_data['best_record'] = record[metric], record
      progress_data.update(epoch=epoch + 1, batch=0, loss_sum=0.0, accuracy_sum=0.0)
      checkpointer.save(state, progress_data, replace=True)
  best = progress_data['best_record']
  if best is None and model is not None:  # no epoch gave a defined metric: keep the last model
    save_model(gripper_dir / BEST_DIR, int(state.step), model, info=record)
    best = record
  return best


def final_state_params(out_dir: str | os.PathLike, config: TrainConfig, gripper: str,
                       stats: GripperStats) -> Any:
  """Parameters of the newest training checkpoint of ``gripper`` (host arrays), e.g. to compare two runs."""
  model_config = config.model_config(gripper)
  template = create_state(jax.random.key(0), model_config,
                          make_optimizer(config.optimizer, _steps_per_epoch(stats, config)))
  with Checkpointer(Path(out_dir) / gripper, config.checkpoint) as checkpointer:
    restored = checkpointer.restore(template)
  if restored is None:
    raise FileNotFoundError(f'{Path(out_dir) / gripper}: no training checkpoint')
  return _host(restored[0].params)


__all__ = ['Interrupted', 'check_trainable', 'final_state_params', 'sgd_step', 'train_gripper']
