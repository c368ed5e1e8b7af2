"""The configuration of a GQ-CNN training run, read from YAML (layout: ``configs/dexnet4_pj.yaml``).

`TrainConfig()` is the embedded quick-start default of ``python -m dexjax.train``: both grippers, the small
32 x 32 network on 96-pixel windows downsampled 3x (Dex-Net 2.0's input), a dozen epochs, class-balanced loss,
and a small built-in dataset generated on first use (`QuickstartData`). ``configs/dexnet4_pj.yaml`` and
``configs/dexnet4_suction.yaml`` are the Dex-Net 4.0 recipe (spec section 3: 96 x 96 crops, 50 epochs, batch 64,
no class re-weighting). Every field is type-checked; `dexjax.config.ConfigError` names the file and the field.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any, Mapping

from dexjax.config import ConfigError, as_dict, check_sections, load_yaml, override, string_list
from dexjax.config_rules import MAX_SAMPLES, count_rule
from dexjax.data.shards import GRIPPER_NAMES
from dexjax.models.gqcnn import PARALLEL_JAW_POSE_DIM, SUCTION_POSE_DIM, GQCNNConfig
from dexjax.train.step import OptimizerConfig

CLASS_BALANCE = ('none', 'weight', 'undersample')

MAX_EPOCHS = 10_000
"""Largest ``loop.epochs``."""

MAX_BATCH_SIZE = 65_536
"""Largest ``loop.batch_size`` and ``loop.eval_batch_size`` (examples per step)."""

MAX_BUFFER_ROWS = 1_000_000
"""Largest ``loop.shuffle_buffer`` and ``loop.normalization_rows`` (rows held in memory at once)."""
BEST_METRICS = ('val_balanced_accuracy', 'val_average_precision', 'val_accuracy', 'val_loss')
_MODEL_TUPLES = ('conv_filters', 'conv_kernels', 'pool_after')
TARGETS = ('label', 'robust_probability', 'label_probability')


@dataclasses.dataclass(frozen=True)
class LoopConfig:
  """What one epoch does.

  Attributes:
    epochs: passes over the training split.
    batch_size: examples per SGD step (global over devices and hosts; a multiple of the device count).
    symmetrize: random 180-degree rotation and flips about the grasp pixel (spec section 3.4).
    class_balance: ``'none'`` (Dex-Net 4.0), ``'weight'`` (positives and negatives weigh half the loss each),
      ``'undersample'`` (negatives kept with probability positive rate / negative rate, drawn per epoch).
    normalization_rows: training rows (at most) the input statistics are fitted on.
    shuffle_buffer: rows mixed by the streaming loader (`dexjax.data.iterate_rows`).
    eval_batch_size: examples per validation forward pass.
    target: ``'label'`` (Dex-Net 4.0: the reward, 0 or 1), ``'robust_probability'`` (soft targets: the robust
      probability of the M draws where robustness decided the reward, else 0; `dexjax.train.soft_labels`) or
      ``'label_probability'`` (soft targets: the probability that a label of ``label_draws`` draws is positive,
      given that robust probability; `dexjax.train.label_probability`: labels of many draws, e.g. a run
      relabelled with M = 100, teach the M = 10 label without its draws' noise). Soft targets are class-balanced
      as their expected loss: a row weighs ``s w+ + (1 - s) w-`` towards the target ``s w+ / (s w+ + (1 - s) w-)``.
    label_draws: with ``'label_probability'``: the draws M of the label to predict (the seed's: 10).
    label_threshold: with ``'label_probability'``: the reward's threshold on the M-draw probability (0.5).
  """

  epochs: int = 12
  batch_size: int = 64
  symmetrize: bool = True
  class_balance: str = 'weight'
  normalization_rows: int = 20_000
  shuffle_buffer: int = 10_000
  eval_batch_size: int = 256
  target: str = 'label'
  label_draws: int = 10
  label_threshold: float = 0.5


@dataclasses.dataclass(frozen=True)
class SplitConfig:
  """Train / validation split (`dexjax.data.split_images`): ``by`` heap or object, ``val_fraction``, ``seed``."""

  by: str = 'heap'
  val_fraction: float = 0.2
  seed: int = 0


@dataclasses.dataclass(frozen=True)
class CheckpointConfig:
  """Checkpointing: every ``every_steps`` SGD steps and at each epoch's end (the ``keep`` newest are kept), plus
  the best model by ``best_metric`` on the validation split."""

  every_steps: int = 500
  keep: int = 2
  best_metric: str = 'val_balanced_accuracy'


@dataclasses.dataclass(frozen=True)
class QuickstartData:
  """The dataset ``python -m dexjax.train`` generates (once, then reuses) when no ``--data`` is given.

  Attributes:
    objects: object sources (`dexjax.objects.load_object_set`).
    num_images: rendered heap images (about 100 labelled rows each: 50 per gripper).
    workers: generation processes.
  """

  objects: tuple[str, ...] = ('procedural:L1/0:10', 'procedural:L2/0:10')
  num_images: int = 320
  workers: int = 2


@dataclasses.dataclass(frozen=True)
class TrainConfig:
  """A training run: one GQ-CNN per gripper in ``grippers``.

  Attributes:
    seed: initialisation, data order, dropout and augmentation seed.
    grippers: gripper names (`dexjax.data.GRIPPER_NAMES`) to train, one model each.
    model: the architecture (``pose_dim`` is set per gripper).
    crop_window: side of the grasp-centred window read from the depth image, pixels; resampled to
      ``model.crop_size`` (96 -> 32: 3x downsampling, bilinear; equal sizes: nearest, as gqcnn).
    optimizer, loop, split, checkpoint: see their classes.
    quickstart: the built-in dataset used without ``--data``.
    init: start from trained weights instead of random ones (fine-tuning): ``''`` (none), ``'pretrained'`` (the
      shipped models, `dexjax.models.pretrained`), a training run, a saved model directory or a model file. The
      run then takes its architecture (``model``, ``crop_window``) and input normalisation from those models.
  """

  seed: int = 0
  grippers: tuple[str, ...] = GRIPPER_NAMES
  model: GQCNNConfig = GQCNNConfig.small()
  crop_window: int = 96
  optimizer: OptimizerConfig = OptimizerConfig()
  loop: LoopConfig = LoopConfig()
  split: SplitConfig = SplitConfig()
  checkpoint: CheckpointConfig = CheckpointConfig()
  quickstart: QuickstartData = QuickstartData()
  init: str = ''

  def model_config(self, gripper: str) -> GQCNNConfig:
    """The architecture of ``gripper``'s network (pose dimension 1 for the parallel jaw, 2 for suction)."""
    pose_dim = SUCTION_POSE_DIM if gripper == 'suction' else PARALLEL_JAW_POSE_DIM
    return dataclasses.replace(self.model, pose_dim=pose_dim)

  def validate(self, source: str = '<config>') -> TrainConfig:
    """Checks cross-field rules; raises `ConfigError` naming the field and the expected value."""
    if not self.grippers or any(g not in GRIPPER_NAMES for g in self.grippers) or len(set(self.grippers)) < len(
        self.grippers):
      raise ConfigError(source, 'grippers', f'expected distinct names from {GRIPPER_NAMES}, got {self.grippers}')
    try:
      self.model.validate()
    except ValueError as e:
      raise ConfigError(source, 'model', str(e)) from None
    if self.crop_window < self.model.crop_size:
      raise ConfigError(source, 'crop_window', f'expected >= model.crop_size ({self.model.crop_size}), got '
                                               f'{self.crop_window}')
    loop = self.loop
    checks = [count_rule('loop.epochs', loop.epochs, 1, MAX_EPOCHS),
              count_rule('loop.batch_size', loop.batch_size, 1, MAX_BATCH_SIZE),
              count_rule('loop.eval_batch_size', loop.eval_batch_size, 1, MAX_BATCH_SIZE),
              count_rule('loop.normalization_rows', loop.normalization_rows, 1, MAX_BUFFER_ROWS),
              ('loop.class_balance', loop.class_balance in CLASS_BALANCE, f'one of {CLASS_BALANCE}'),
              ('loop.target', loop.target in TARGETS, f'one of {TARGETS}'),
              count_rule('loop.label_draws', loop.label_draws, 1, MAX_SAMPLES, 'Monte-Carlo draws'),
              ('loop.label_threshold', 0.0 <= loop.label_threshold < 1.0, 'a probability in [0, 1)'),
              ('split.by', self.split.by in ('heap', 'object'), "'heap' or 'object'"),
              ('split.val_fraction', 0.0 < self.split.val_fraction < 1.0, 'a fraction in (0, 1)'),
              ('split.seed', self.split.seed >= 0, 'an integer >= 0'),
              ('checkpoint.every_steps', self.checkpoint.every_steps >= 1, 'an integer >= 1'),
              ('checkpoint.keep', self.checkpoint.keep >= 1, 'an integer >= 1'),
              ('checkpoint.best_metric', self.checkpoint.best_metric in BEST_METRICS, f'one of {BEST_METRICS}'),
              count_rule('loop.shuffle_buffer', loop.shuffle_buffer, 1, MAX_BUFFER_ROWS),
              ('optimizer.learning_rate', self.optimizer.learning_rate > 0, 'a number > 0'),
              ('optimizer.weight_decay', self.optimizer.weight_decay >= 0, 'a number >= 0'),
              ('optimizer.momentum', 0 <= self.optimizer.momentum < 1, 'a number in [0, 1)'),
              ('optimizer.decay_rate', 0 < self.optimizer.decay_rate <= 1, 'a factor in (0, 1]'),
              ('optimizer.decay_epochs', self.optimizer.decay_epochs > 0, 'a number > 0'),
              ('quickstart.num_images', self.quickstart.num_images >= 1, 'an integer >= 1'),
              ('quickstart.workers', self.quickstart.workers >= 1, 'an integer >= 1')]
    for field, ok, expected in checks:
      if not ok:
        value = _get(self, field)
        raise ConfigError(source, field, f'expected {expected}, got {value!r}')
    return self


def _get(obj: Any, dotted: str) -> Any:
  for name in dotted.split('.'):
    obj = getattr(obj, name)
  return obj


def _model(values: Mapping[str, Any] | None, source: str) -> GQCNNConfig:
  """The ``model`` section: `GQCNNConfig` fields, with lists of any length for the layer tuples."""
  model = GQCNNConfig.small()
  if values is None:
    return model
  if not isinstance(values, Mapping):
    raise ConfigError(source, 'model', f'expected a mapping of field: value, got {values!r}')
  values, tuples = dict(values), {}
  for name in _MODEL_TUPLES:
    if name in values:
      value = values.pop(name)
      if not isinstance(value, list) or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0
                                                for v in value):
        raise ConfigError(source, f'model.{name}', f'expected a list of integers >= 0, got {value!r}')
      tuples[name] = tuple(value)
  if 'pose_dim' in values:
    raise ConfigError(source, 'model.pose_dim', 'set per gripper (1 parallel jaw, 2 suction); remove the field')
  return dataclasses.replace(override(model, values, source=source, section='model', minimum=0), **tuples)


_TOP = ('seed', 'grippers', 'model', 'crop_window', 'optimizer', 'loop', 'split', 'checkpoint', 'quickstart', 'init')


def train_config_from_dict(data: Mapping[str, Any], source: str = '<config>') -> TrainConfig:
  """A `TrainConfig` from a decoded YAML mapping (unset fields keep the quick-start defaults).

  Raises:
    ConfigError: an unknown section or field, a value of the wrong type or out of range.
  """
  check_sections(data, _TOP, source=source)
  c = TrainConfig()
  scalars = override(c, {k: data[k] for k in ('seed', 'crop_window', 'init') if k in data}, source=source,
                     section='', minimum=0)
  quickstart = dict(data.get('quickstart') or {})
  objects = quickstart.pop('objects', None)
  qs = override(c.quickstart, quickstart, source=source, section='quickstart', minimum=1)
  if objects is not None:
    qs = dataclasses.replace(qs, objects=string_list(objects, source=source, field='quickstart.objects',
                                                     what='object sources'))
  config = dataclasses.replace(
      scalars,
      grippers=(string_list(data['grippers'], source=source, field='grippers', what=f'names from {GRIPPER_NAMES}')
                if 'grippers' in data else c.grippers),
      model=_model(data.get('model'), source),
      # No generic minimum: `TrainConfig.validate` holds one rule per field (e.g. loop.epochs in [1, 10,000]),
      # the same for a file and the command line.
      optimizer=override(c.optimizer, data.get('optimizer'), source=source, section='optimizer'),
      loop=override(c.loop, data.get('loop'), source=source, section='loop'),
      split=override(c.split, data.get('split'), source=source, section='split'),
      checkpoint=override(c.checkpoint, data.get('checkpoint'), source=source, section='checkpoint'),
      quickstart=qs)
  return config.validate(source)


def load_train_config(path: str | os.PathLike[str] | None = None) -> TrainConfig:
  """The quick-start defaults, overridden by the YAML file ``path`` if given."""
  if path is None:
    return TrainConfig().validate()
  return train_config_from_dict(load_yaml(path), os.fspath(path))


def config_to_dict(config: TrainConfig) -> dict[str, Any]:
  """Plain-Python view (YAML/JSON ready; the inverse of `train_config_from_dict`)."""
  data = as_dict(config)
  data['model'].pop('pose_dim')
  return data


__all__ = ['BEST_METRICS', 'CLASS_BALANCE', 'CheckpointConfig', 'LoopConfig', 'QuickstartData', 'SplitConfig',
           'TrainConfig', 'config_to_dict', 'load_train_config', 'train_config_from_dict']
