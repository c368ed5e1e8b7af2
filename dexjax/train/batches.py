"""Fixed-size example batches of one gripper from a dataset directory, in a reproducible order.

Epoch ``e`` of a run reads `dexjax.data.iterate_rows` with the seed ``(seed, e)``, keeps the rows of the
gripper (and, with ``class_balance='undersample'``, each negative with probability p drawn from the same seeded
stream), and groups them into batches of exactly ``batch_size`` rows (the remainder is dropped: one jitted
shape). The order is a function of (dataset, config, seed, epoch) only, so `train_batches` with ``skip=k``
yields exactly the batches k, k+1, ... of an uninterrupted epoch (skipped batches are counted, not cropped):
that is how a resumed run continues with the same data order.

`dataset_stats` counts rows and positives per gripper in the training split and fits the input normalisation on
``normalization_rows`` rows of each gripper drawn uniformly at random (a second pass when a gripper has more).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import numpy as np

from dexjax.data.loader import DataDirs, dataset_label, iterate_rows
from dexjax.data.shards import GRIPPER_NAMES
from dexjax.models.normalization import Normalization, fit_normalization
from dexjax.train.config import LoopConfig, TrainConfig
from dexjax.train.data import gripper_examples, label_probability

_LOADER_BATCH = 256  # rows per loader batch (both grippers); only the grouping of reads, not the result
# where an evaluated row came from
_SOURCE_FIELDS = ('dataset_index', 'shard_index', 'row_index', 'image_index', 'target_slot')


@dataclasses.dataclass(frozen=True)
class GripperStats:
  """What a run needs to know of its training split before the first step (one gripper).

  Attributes:
    train_rows, train_positives: rows of the gripper in the training split, and how many have label 1.
    normalization: input statistics fitted on the training split.
  """

  train_rows: int
  train_positives: int
  normalization: Normalization

  @property
  def positive_rate(self) -> float:
    return self.train_positives / max(self.train_rows, 1)

  def keep_negative_probability(self) -> float:
    """Undersampling: the probability a negative is kept so both classes are about equally frequent."""
    negatives = self.train_rows - self.train_positives
    return 1.0 if negatives == 0 or self.train_positives == 0 else min(1.0, self.train_positives / negatives)

  def class_weights(self) -> tuple[float, float]:
    """(negative, positive) loss weights giving both classes half of the loss; (1, 1) if a class is missing."""
    rate = self.positive_rate
    if rate <= 0.0 or rate >= 1.0:
      return 1.0, 1.0
    return 0.5 / (1.0 - rate), 0.5 / rate

  def examples_per_epoch(self, class_balance: str) -> int:
    """Expected training examples per epoch (undersampling drops negatives)."""
    if class_balance != 'undersample':
      return self.train_rows
    negatives = self.train_rows - self.train_positives
    return int(round(self.train_positives + negatives * self.keep_negative_probability()))


def _split_rows(data_dir: DataDirs, config: TrainConfig, split: str, seed,
                shuffle_buffer: int) -> Iterator[dict[str, np.ndarray]]:
  """`iterate_rows` of ``split`` under the run's split rule, images as references (crops read small windows)."""
  return iterate_rows(data_dir, split, batch_size=_LOADER_BATCH, seed=seed, shuffle_buffer=shuffle_buffer,
                      by=config.split.by, val_fraction=config.split.val_fraction, split_seed=config.split.seed,
                      stack_images=False)


def _rows(data_dir: DataDirs, config: TrainConfig, split: str, seed, shuffle_buffer: int,
          gripper: str) -> Iterator[dict[str, np.ndarray]]:
  """Loader batches restricted to ``gripper``'s rows (batches without any are skipped)."""
  code = GRIPPER_NAMES.index(gripper)
  for batch in _split_rows(data_dir, config, split, seed, shuffle_buffer):
    sel = batch['gripper'] == code
    if sel.any():
      yield {k: v[sel] for k, v in batch.items()}


def _concat(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
  return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _grouped(rows: Iterator[dict[str, np.ndarray]], size: int, drop_remainder: bool) -> Iterator[dict]:
  """Regroups a stream of row dicts into dicts of exactly ``size`` rows (the last may be short unless dropped)."""
  parts, count = [], 0
  for part in rows:
    parts.append(part)
    count += len(part['gripper'])
    while count >= size:
      merged = _concat(parts)
      yield {k: v[:size] for k, v in merged.items()}
      rest = {k: v[size:] for k, v in merged.items()}
      parts, count = [rest], count - size
  if count and not drop_remainder:
    yield _concat(parts)


def _epoch_seed(seed: int, epoch: int) -> list[int]:
  return [seed, epoch, 0x7A1]


def train_batches(data_dir: DataDirs, config: TrainConfig, gripper: str, epoch: int, stats: GripperStats,
                  skip: int = 0) -> Iterator[dict[str, np.ndarray]]:
  """Training batches ``skip``, ``skip + 1``, ... of ``epoch`` for ``gripper`` (see the module doc).

  Yields:
    Dicts of ``crops`` (B, S, S, 1) metres, ``poses`` (B, pose_dim), ``labels`` (B,) int32 and ``weights`` (B,)
    float32 (class weights with ``class_balance='weight'``, else ones); B = ``config.loop.batch_size``.
  """
  loop = config.loop
  rng = np.random.default_rng(_epoch_seed(config.seed, epoch) + [1])
  keep_p = stats.keep_negative_probability()
  w_neg, w_pos = stats.class_weights() if loop.class_balance == 'weight' else (1.0, 1.0)

  def balanced(rows):
    for part in rows:
      if loop.class_balance == 'undersample':
        keep = (part['reward'] == 1) | (rng.random(len(part['reward'])) < keep_p)
        part = {k: v[keep] for k, v in part.items()}
      if len(part['reward']):
        yield part

  rows = _rows(data_dir, config, 'train', _epoch_seed(config.seed, epoch), loop.shuffle_buffer, gripper)
  for index, batch in enumerate(_grouped(balanced(rows), loop.batch_size, drop_remainder=True)):
    if index < skip:
      continue
    examples = gripper_examples(batch, gripper, config.model.crop_size, config.crop_window)
    if loop.target == 'label':
      examples['weights'] = np.where(examples['labels'] == 1, w_pos, w_neg).astype(np.float32)
    else:
      examples['soft_labels'], examples['weights'] = _balanced_soft_targets(examples['soft_labels'], loop, w_pos,
                                                                            w_neg)
    yield examples


def _balanced_soft_targets(soft: np.ndarray, loop: LoopConfig, w_pos: float,
                           w_neg: float) -> tuple[np.ndarray, np.ndarray]:
  """(targets, weights) (B,) of soft targets (the robust probabilities, `dexjax.train.soft_labels`) for
  ``loop.target``: the class-balanced loss's expectation over the target, weight ``s w+ + (1 - s) w-`` towards
  ``s w+ / weight`` (`LoopConfig`)."""
  if loop.target == 'label_probability':
    soft = label_probability(soft, loop.label_draws, loop.label_threshold)
  weights = soft * w_pos + (1.0 - soft) * w_neg
  return (soft * w_pos / weights).astype(np.float32), weights.astype(np.float32)


def eval_batches(data_dir: DataDirs, config: TrainConfig, gripper: str,
                 split: str = 'val') -> Iterator[dict[str, np.ndarray]]:
  """Every row of ``gripper`` in ``split`` (``'train'``, ``'val'`` or ``'all'``), once, in batches of exactly
  ``config.loop.eval_batch_size`` (the last padded): dicts as `train_batches` plus ``mask`` (B,) bool (False on
  padding), ``robust_probability`` (B,) and where each row came from, ``dataset_index``, ``shard_index``,
  ``row_index`` (in its shard), ``image_index`` and ``target_slot`` (B,) int32."""
  splits = ('train', 'val') if split == 'all' else (split,)
  size = config.loop.eval_batch_size

  def rows():
    for name in splits:
      yield from _rows(data_dir, config, name, 0, 0, gripper)

  for batch in _grouped(rows(), size, drop_remainder=False):
    examples = gripper_examples(batch, gripper, config.model.crop_size, config.crop_window)
    n = len(examples['labels'])
    examples['mask'] = np.arange(size) < n
    examples['weights'] = examples['mask'].astype(np.float32)
    for key in _SOURCE_FIELDS:
      examples[key] = np.asarray(batch[key], np.int32)
    for key in ('crops', 'poses', 'labels', 'robust_probability', *_SOURCE_FIELDS):
      pad = [(0, size - n)] + [(0, 0)] * (examples[key].ndim - 1)
      examples[key] = np.pad(examples[key], pad)
    yield examples


def _normalization_sample(rows: dict[str, np.ndarray], gripper: str, config: TrainConfig,
                          rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
  """(crops, poses) of ``rows`` of one gripper as the statistics see them (suction: approach-angle signs
  randomised when ``symmetrize`` is on, as the augmentation will; spec section 1.3)."""
  ex = gripper_examples(rows, gripper, config.model.crop_size, config.crop_window)
  poses = ex['poses']
  if gripper == 'suction' and config.loop.symmetrize:
    poses[:, 1] *= np.where(rng.random(len(poses)) < 0.5, -1.0, 1.0)
  return ex['crops'], poses


def _chosen_rows(data_dir: DataDirs, config: TrainConfig, chosen: dict[str, np.ndarray],
                 rng: np.random.Generator) -> dict[str, list]:
  """A second pass over the training split in the first pass's order: the (crops, poses) of the rows of each
  gripper at the sorted positions ``chosen[gripper]`` (indices among that gripper's rows)."""
  seen = {g: 0 for g in chosen}
  samples: dict[str, list] = {g: [] for g in chosen}
  for batch in _split_rows(data_dir, config, 'train', config.seed, 0):
    for gripper, positions in chosen.items():
      sel = np.flatnonzero(batch['gripper'] == GRIPPER_NAMES.index(gripper))
      lo, hi = np.searchsorted(positions, [seen[gripper], seen[gripper] + len(sel)])
      if hi > lo:
        take = sel[positions[lo:hi] - seen[gripper]]
        samples[gripper].append(_normalization_sample({k: v[take] for k, v in batch.items()}, gripper, config, rng))
      seen[gripper] += len(sel)
  return samples


def dataset_stats(data_dir: DataDirs, config: TrainConfig) -> dict[str, GripperStats]:
  """Row and positive counts of each of ``config.grippers`` in the training split, and input normalisation
  fitted on ``config.loop.normalization_rows`` rows of each gripper drawn uniformly at random (without
  replacement, seeded by ``config.seed``) from its training rows, or on all of them when there are fewer.

  One pass counts the rows (keeping the crops of the first ``normalization_rows``, enough when a gripper has no
  more); a gripper with more rows gets a second pass that crops only the drawn rows, so the statistics are not
  those of the first shards read (whose rows share heaps and objects).

  Raises:
    ValueError: a gripper has no training rows (naming the directory and the gripper).
  """
  limit = config.loop.normalization_rows
  counts = {g: [0, 0] for g in config.grippers}
  samples: dict[str, list] = {g: [] for g in config.grippers}
  rng = np.random.default_rng([config.seed, 0x57A7])
  for batch in _split_rows(data_dir, config, 'train', config.seed, 0):
    for gripper in config.grippers:
      sel = batch['gripper'] == GRIPPER_NAMES.index(gripper)
      room = limit - counts[gripper][0]
      counts[gripper][0] += int(sel.sum())
      counts[gripper][1] += int((batch['reward'][sel] == 1).sum())
      if room > 0 and sel.any():
        samples[gripper].append(_normalization_sample({k: v[sel][:room] for k, v in batch.items()}, gripper,
                                                      config, rng))
  for gripper in config.grippers:
    if counts[gripper][0] == 0:
      raise ValueError(f"{dataset_label(data_dir)}: no training rows of gripper '{gripper}' (split by "
                       f"{config.split.by}, val_fraction {config.split.val_fraction}); generate more images or "
                       f"train other grippers (field 'grippers')")
  chosen = {g: np.sort(rng.choice(counts[g][0], limit, replace=False)) for g in config.grippers
            if counts[g][0] > limit}
  if chosen:
    samples.update(_chosen_rows(data_dir, config, chosen, rng))
  return {g: GripperStats(counts[g][0], counts[g][1], fit_normalization(samples[g], config.model.subtracts_grasp_depth))
          for g in config.grippers}


__all__ = ['GripperStats', 'dataset_stats', 'eval_batches', 'train_batches']
