"""Train GQ-CNNs (the project's main job).

  python -m dexjax.train                      # quick start: built-in dataset (generated once), both grippers
  python -m dexjax.train --config configs/dexnet4_pj.yaml --data DIR [DIR ...] [--out OUT] [--resume]
      [--grippers parallel_jaw suction] [--epochs N] [--seed S] [--init pretrained|RUN|MODEL] [--cache-dir DIR]
      [--no-progress] [--json]
      [--distributed [--coordinator HOST:PORT --num-processes N --process-id I]]

Writes OUT/metrics.jsonl (one JSON object per epoch and gripper), OUT/curves.png, OUT/<gripper>/best (the best
model by validation, dexjax.models.load) and OUT/<gripper>/checkpoints (resumable with --resume). OUT defaults
to runs/<config name>-<date-time>; --resume without --out continues the newest such run. A new run needs a new
or empty OUT; --resume needs an earlier run there. A training split that cannot teach anything (one label only,
less than a batch) is refused before anything is written. Exit code 0 on success, 1 when generating the quick-start
dataset failed, 2 for bad input (docs/errors.md).

--init pretrained fine-tunes the shipped models (dexjax.models.pretrained) on --data instead of starting from random
weights: the run takes their architecture and input normalisation (docs/models.md); --init RUN or MODEL starts
from another trained run or saved model.

Several --data directories are trained on as one dataset (their union: e.g. the rounds of on-policy synthesis and
the set they started from, python -m dexjax.rounds --aggregate).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

from dexjax.cli import command, report_failure
from dexjax.config_rules import ConfigError


def _parser() -> argparse.ArgumentParser:
  p = argparse.ArgumentParser(prog='python -m dexjax.train', description=__doc__.split('\n\n')[0])
  p.add_argument('--config', help='training config (layout: configs/dexnet4_pj.yaml; default: the quick start)')
  p.add_argument('--data', nargs='+', help='dataset directory from python -m dexjax.generate, or several (their '
                                           'union; default: the built-in quick-start set, generated on first use '
                                           'and cached)')
  p.add_argument('--out', help='run directory (default runs/<config name>-<date-time>)')
  p.add_argument('--resume', action='store_true', help='continue the run in --out (default: the newest of this '
                                                       'config) from its last checkpoint')
  p.add_argument('--grippers', nargs='+', choices=('parallel_jaw', 'suction'), help='replaces the config\'s grippers')
  p.add_argument('--epochs', type=int, help='replaces loop.epochs')
  p.add_argument('--seed', type=int, help='replaces the config\'s seed')
  p.add_argument('--init', metavar='pretrained|RUN|MODEL', help='fine-tune: start from the shipped models '
                 '(pretrained), a training run or a saved model; replaces the config\'s init')
  p.add_argument('--cache-dir', help='object, supervisor and quick-start dataset cache (default $DEXJAX_CACHE or '
                                     '~/.cache/dexjax/objects)')
  p.add_argument('--no-progress', action='store_true', help='no progress bars')
  p.add_argument('--json', action='store_true', help='print the summary as JSON')
  p.add_argument('--distributed', action='store_true', help='multi-host: call jax.distributed.initialize first')
  p.add_argument('--coordinator', help='coordinator HOST:PORT (with --distributed; default: from the cluster)')
  p.add_argument('--num-processes', type=int, help='number of processes (with --distributed)')
  p.add_argument('--process-id', type=int, help='this process\'s index (with --distributed)')
  return p


def _out_dir(args, name: str) -> Path:
  if args.out:
    return Path(args.out)
  runs = sorted(Path('runs').glob(f'{name}-*'))
  if args.resume:
    if not runs:
      raise FileNotFoundError(f'runs/{name}-*: no run to resume; pass --out')
    return runs[-1]
  return Path('runs') / f'{name}-{time.strftime("%Y%m%d-%H%M%S")}'


@command
def main(argv: list[str] | None = None) -> int:
  args = _parser().parse_args(argv)
  from dexjax.train import distributed  # pylint: disable=g-import-not-at-top (slow imports after parsing)
  from dexjax.train.config import load_train_config  # pylint: disable=g-import-not-at-top
  from dexjax.train.run import check_run_dir, quickstart_dataset, train_run  # pylint: disable=g-import-not-at-top
  log = (lambda *a, **k: print(*a, file=sys.stderr, **k)) if args.json else print
  if args.distributed:
    distributed.initialize(args.coordinator, args.num_processes, args.process_id)
  config = load_train_config(args.config)
  if args.grippers:
    config = dataclasses.replace(config, grippers=tuple(dict.fromkeys(args.grippers)))
  if args.epochs is not None:
    config = dataclasses.replace(config, loop=dataclasses.replace(config.loop, epochs=args.epochs))
  if args.seed is not None:
    config = dataclasses.replace(config, seed=args.seed)
  if args.init is not None:
    config = dataclasses.replace(config, init=args.init)
  try:
    config = config.validate('command line')
  except ConfigError as e:  # a value given as an option is named as the option
    given = {'loop.epochs': ('--epochs', args.epochs), 'seed': ('--seed', args.seed),
             'grippers': ('--grippers', args.grippers), 'init': ('--init', args.init)}
    option, value = given.get(e.field, (None, None))
    if value is None:
      raise
    raise ConfigError(option, e.field, e.problem) from None
  name = Path(args.config).stem if args.config else 'quickstart'
  out = _out_dir(args, name)
  if distributed.is_main_process():
    check_run_dir(out, resume=args.resume)  # before the (long) quick-start dataset: a wrong --out fails at once
  try:
    data = args.data or quickstart_dataset(config, args.cache_dir, progress=not args.no_progress, log=log)
  except RuntimeError as e:  # some of its shards failed: not bad input, rerun to retry them
    return report_failure(e)
  summary = train_run(config, data, out, resume=args.resume, progress=not args.no_progress, log=log)
  if args.json:
    print(json.dumps(summary, indent=1))
  return 0


if __name__ == '__main__':
  sys.exit(main())
