"""Scores a trained GQ-CNN on a split of any generated dataset: the validation metrics of a run, and
``python -m dexjax.evaluate``."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import numpy as np
import optax
from tqdm.auto import tqdm

from dexjax.data.loader import DataDirs, dataset_label, row_groups
from dexjax.models.saved import GraspQualityModel
from dexjax.train.batches import eval_batches
from dexjax.train.config import TrainConfig
from dexjax.train.metrics import bootstrap_intervals, classification_metrics


@jax.jit
def _logits(model: GraspQualityModel, crops: jax.Array, poses: jax.Array) -> jax.Array:
  return model.logits(crops, poses)


def predict_rows(model: GraspQualityModel, data_dir: DataDirs, config: TrainConfig = TrainConfig(),
                 split: str = 'val', progress: bool = False) -> dict[str, np.ndarray]:
  """``model``'s prediction for every row of its gripper in ``split`` (``'train'``, ``'val'`` or ``'all'``).

  ``config`` supplies the split rule (``split`` section) and the evaluation batch size; the crop size and window
  are the model's. Returns (N,) arrays in the dataset's reading order: ``scores`` p(success), ``labels`` int32,
  ``robust_probability`` (the label's Monte-Carlo estimate), ``loss`` (the cross-entropy of each row), and where
  each row came from, ``dataset_index``, ``shard_index``, ``row_index`` (its index in the shard's rows),
  ``image_index`` and ``target_slot`` (see `dexjax.data.row_groups`).
  """
  config = dataclasses.replace(config, model=model.config, crop_window=model.crop_window)
  keys = ('labels', 'robust_probability', 'dataset_index', 'shard_index', 'row_index', 'image_index', 'target_slot')
  parts: dict[str, list] = {k: [] for k in ('scores', 'loss', *keys)}
  batches = eval_batches(data_dir, config, model.gripper, split)
  for batch in tqdm(batches, desc=f'evaluate {model.gripper}', unit='batch', disable=not progress, leave=False):
    logits = np.asarray(_logits(model, batch['crops'], batch['poses']))
    mask = batch['mask']
    parts['scores'].append(np.asarray(jax.nn.softmax(logits[mask], -1)[:, 1]))
    parts['loss'].append(np.asarray(optax.softmax_cross_entropy_with_integer_labels(logits[mask],
                                                                                   batch['labels'][mask])))
    for key in keys:
      parts[key].append(np.asarray(batch[key])[mask])
  empty = {'scores': np.float32, 'loss': np.float32, 'robust_probability': np.float32}
  return {k: np.concatenate(v) if v else np.zeros(0, empty.get(k, np.int32)) for k, v in parts.items()}


def evaluate_model(model: GraspQualityModel, data_dir: DataDirs, config: TrainConfig = TrainConfig(),
                   split: str = 'val', progress: bool = False, interval_by: str | None = None,
                   num_resamples: int = 1000) -> dict[str, Any]:
  """Metrics of ``model`` on the rows of its gripper in ``split`` (``'train'``, ``'val'`` or ``'all'``).

  Returns `classification_metrics` of `predict_rows` (threshold 0.5 on p(success)) plus ``loss``, the mean
  cross-entropy (None without examples). With ``interval_by`` (``'object'`` or ``'heap'``), also ``intervals``:
  95 % `bootstrap_intervals` of the balanced accuracy and average precision resampling whole objects or heaps
  (`dexjax.data.row_groups`) ``num_resamples`` times.
  """
  rows = predict_rows(model, data_dir, config, split, progress)
  metrics = classification_metrics(rows['scores'], rows['labels'])
  metrics['loss'] = float(rows['loss'].mean()) if len(rows['labels']) else None
  if interval_by is not None:
    groups = row_groups(data_dir, rows['shard_index'], rows['image_index'], rows['target_slot'], interval_by,
                        rows['dataset_index'])
    metrics['intervals'] = {'by': interval_by, **bootstrap_intervals(rows['scores'], rows['labels'], groups,
                                                                     num_resamples)}
  return metrics


def sample_examples(model: GraspQualityModel, data_dir: DataDirs, num: int, config: TrainConfig = TrainConfig(),
                    split: str = 'val', seed: int = 0) -> dict[str, np.ndarray]:
  """A uniformly random subset of ``num`` rows of ``model``'s gripper in ``split``, as the model sees them:
  ``{'crops': (n, S, S, 1) metres, 'poses': (n, pose_dim), 'labels': (n,)}``, n = min(num, rows). One streaming
  pass (each row gets a random key; the ``num`` smallest are kept), so memory stays at ``num`` rows."""
  config = dataclasses.replace(config, model=model.config, crop_window=model.crop_window)
  rng = np.random.default_rng(seed)
  kept: dict[str, np.ndarray] | None = None
  for batch in eval_batches(data_dir, config, model.gripper, split):
    mask = batch['mask']
    rows = {'crops': np.asarray(batch['crops'])[mask], 'poses': np.asarray(batch['poses'])[mask],
            'labels': np.asarray(batch['labels'])[mask], 'key': rng.random(int(mask.sum()))}
    kept = rows if kept is None else {k: np.concatenate([kept[k], v]) for k, v in rows.items()}
    if len(kept['key']) > num:
      order = np.argpartition(kept['key'], num)[:num]
      kept = {k: v[order] for k, v in kept.items()}
  if kept is None:
    raise ValueError(f'{dataset_label(data_dir)}: no {model.gripper} rows in split {split!r}')
  order = np.argsort(kept.pop('key'))
  return {k: v[order] for k, v in kept.items()}


__all__ = ['evaluate_model', 'predict_rows', 'sample_examples']
