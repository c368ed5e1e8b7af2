"""Score trained GQ-CNNs on a generated dataset and print one JSON object.

  python -m dexjax.evaluate --checkpoint CKPT --data DIR [DIR ...] [--split all|train|val] [--gripper G]
                            [--batch-size B] [--intervals object|heap]

CKPT is ``pretrained`` (the models shipped with dexjax, docs/models.md), a training run directory (every gripper
trained in it), ``RUN/<gripper>``, a saved model directory or a model file (``.msgpack``).
The data may come from other objects than the training set; several directories are scored as one union (as
``python -m dexjax.train --data A B``). ``--split all`` (the default) scores every row;
``train`` / ``val`` use the run's split rule (from ``RUN/config.yaml`` when present, else the default). Prints
``{"checkpoint", "data" (the directory, or the list of them), "split", "grippers": {gripper: {accuracy, balanced_accuracy, precision, recall,
average_precision, loss, examples, positives, ...}}}``; ``--intervals object`` adds ``intervals``: 95 % bootstrap
intervals of the balanced accuracy and AP over the dataset's objects (``heap``: its heaps). Exit code 0, or 2 for
bad input (docs/errors.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from pathlib import Path

from dexjax.cli import command


def _parser() -> argparse.ArgumentParser:
  p = argparse.ArgumentParser(prog='python -m dexjax.evaluate', description=__doc__.split('\n\n')[0])
  p.add_argument('--checkpoint', required=True, help='pretrained (the shipped models), a run directory, '
                                                     'RUN/<gripper>, a saved model directory or a model file')
  p.add_argument('--data', required=True, nargs='+', help='dataset directory (python -m dexjax.generate), or '
                                                          'several (scored as their union)')
  p.add_argument('--split', choices=('all', 'train', 'val'), default='all', help='rows to score (default all)')
  p.add_argument('--gripper', choices=('parallel_jaw', 'suction'), help='only this gripper (from a run directory)')
  p.add_argument('--batch-size', type=int, default=256, help='crops per forward pass (default 256)')
  p.add_argument('--views', choices=('saved', 'single', 'symmetric'), default='saved',
                 help="'symmetric': average each prediction over the crop's four symmetric views, 'single': one "
                      "view; default: as the model was saved (the shipped models: symmetric)")
  p.add_argument('--intervals', choices=('object', 'heap'),
                 help='add 95%% bootstrap intervals of the balanced accuracy and AP, resampling whole objects '
                      '(the grasped object of each row) or heaps: how precise the scores are')
  p.add_argument('--resamples', type=int, default=1000, help='bootstrap resamples for --intervals (default 1000)')
  p.add_argument('--no-progress', action='store_true', help='no progress bar')
  return p


def _run_config(checkpoint: Path):
  """The training run's config (its split rule), if ``checkpoint`` is a run or lies inside one."""
  from dexjax.train.config import TrainConfig, load_train_config  # pylint: disable=g-import-not-at-top
  from dexjax.train.run import CONFIG_FILE  # pylint: disable=g-import-not-at-top
  for folder in (checkpoint, *checkpoint.parents[:3]):
    if (folder / CONFIG_FILE).exists():
      return load_train_config(folder / CONFIG_FILE)
  return TrainConfig()


@command
def main(argv: list[str] | None = None) -> int:
  args = _parser().parse_args(argv)
  from dexjax.data.loader import require_shards  # pylint: disable=g-import-not-at-top (slow imports after parsing)
  from dexjax.data.shards import GRIPPER_NAMES  # pylint: disable=g-import-not-at-top
  from dexjax.models.shipped import PRETRAINED, held_grippers, load_models  # pylint: disable=g-import-not-at-top
  from dexjax.train.config import TrainConfig  # pylint: disable=g-import-not-at-top
  from dexjax.train.validation import evaluate_model  # pylint: disable=g-import-not-at-top
  checkpoint = args.checkpoint if args.checkpoint == PRETRAINED else Path(args.checkpoint).absolute()
  if args.batch_size < 1:
    raise ValueError(f'--batch-size: expected an integer >= 1, got {args.batch_size}')
  if args.resamples < 1:
    raise ValueError(f'--resamples: expected an integer >= 1, got {args.resamples}')
  data = args.data[0] if len(args.data) == 1 else list(args.data)
  require_shards(data)
  config = _run_config(Path(checkpoint)) if checkpoint != PRETRAINED else TrainConfig()
  config = dataclasses.replace(config, loop=dataclasses.replace(config.loop, eval_batch_size=args.batch_size))
  wanted = (args.gripper,) if args.gripper else GRIPPER_NAMES
  found = load_models(checkpoint, wanted)
  models = [found[g] for g in GRIPPER_NAMES if g in found and g in wanted]
  if args.views != 'saved':
    models = [dataclasses.replace(m, symmetric_views=args.views == 'symmetric') for m in models]
  if not models:
    raise FileNotFoundError(f'{checkpoint}: no model of gripper {args.gripper!r} '
                            f'(has {held_grippers(checkpoint, found)})')
  results = {m.gripper: evaluate_model(m, data, config, args.split, progress=not args.no_progress,
                                      interval_by=args.intervals, num_resamples=args.resamples) for m in models}
  absolute = [os.fspath(Path(d).absolute()) for d in args.data]
  print(json.dumps({'checkpoint': os.fspath(checkpoint), 'data': absolute[0] if len(absolute) == 1 else absolute,
                    'split': args.split, 'symmetric_views': {m.gripper: m.symmetric_views for m in models},
                    'grippers': results}, indent=1))
  return 0


if __name__ == '__main__':
  sys.exit(main())
