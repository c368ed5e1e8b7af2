"""On-policy dataset synthesis in rounds: collect, train, collect with the trained policy, train again.

  python -m dexjax.rounds --generate-config configs/deployment.yaml --train-config configs/pretrained.yaml
      --out DIR --rounds R --images N [--init pretrained|RUN] [--base-data DIR ...] [--aggregate] [--workers W]
      [--cache-dir DIR] [--json]

Round r writes ``DIR/round-<r>/data`` (python -m dexjax.generate; from round 1 on, or from round 0 with --init,
the candidates are the grasps the previous round's policy scores: on-policy synthesis, docs/generate.md) and
``DIR/round-<r>/train`` (python -m dexjax.train, fine-tuning the previous round's models). Rerun the same command
to resume; finished rounds are skipped. ``DIR/round-<R-1>/train`` holds the final models (``--model`` of
``python -m dexjax.plan`` and ``python -m dexjax.benchmark``). Each round trains on its own collection, with
--aggregate on every round's so far (DAgger), and with --base-data also on those datasets (e.g. the set --init was
trained on, so the models keep knowing the random candidates they started from). Exit code 0, 1 when some shards
of a collection failed (rerun to retry them), 2 for bad input (docs/errors.md).
"""

from __future__ import annotations

import argparse
import json
import sys

from dexjax.cli import command, report_failure


def _parser() -> argparse.ArgumentParser:
  p = argparse.ArgumentParser(prog='python -m dexjax.rounds', description=__doc__.split('\n\n')[0])
  p.add_argument('--generate-config', help='generation config of every round (default: Dex-Net 4.0 values; '
                                           'configs/deployment.yaml: data like the benchmark\'s)')
  p.add_argument('--train-config', help='training config of every round (default: the quick start\'s)')
  p.add_argument('--out', required=True, help='the rounds\' directory (rerun to resume)')
  p.add_argument('--rounds', type=int, required=True, help='rounds to run (>= 1)')
  p.add_argument('--images', type=int, required=True, help='images each round collects')
  p.add_argument('--init', help='collect round 0 on-policy with these models and start training from them '
                                '(pretrained, a training run or a saved model; default: tau, from scratch)')
  p.add_argument('--base-data', nargs='+', default=[], help='datasets every round also trains on (e.g. the one '
                                                           '--init was trained on)')
  p.add_argument('--aggregate', action='store_true', help='each round trains on every round\'s collection so far, '
                                                         'not only its own')
  p.add_argument('--workers', type=int, default=1, help='collection workers (default 1)')
  p.add_argument('--cache-dir', help='object and supervisor cache (default $DEXJAX_CACHE or ~/.cache/dexjax/objects)')
  p.add_argument('--json', action='store_true', help='print rounds.json at the end')
  return p


@command
def main(argv: list[str] | None = None) -> int:
  args = _parser().parse_args(argv)
  for name in ('rounds', 'images', 'workers'):
    if getattr(args, name) < 1:
      raise ValueError(f'--{name}: expected an integer >= 1, got {getattr(args, name)}')
  from dexjax.generate.config import load_generate_config  # pylint: disable=g-import-not-at-top (slow imports)
  from dexjax.train.config import load_train_config  # pylint: disable=g-import-not-at-top
  from dexjax.train.on_policy_rounds import run_rounds  # pylint: disable=g-import-not-at-top
  generate = load_generate_config(args.generate_config)
  train = load_train_config(args.train_config).validate(args.train_config or 'the default config')
  log = (lambda *a, **k: print(*a, file=sys.stderr, **k)) if args.json else print
  try:
    records = run_rounds(generate, train, args.out, args.rounds, args.images, init=args.init,
                         base_data=args.base_data, aggregate=args.aggregate, workers=args.workers,
                         cache_dir=args.cache_dir, progress=not args.json, log=log)
  except RuntimeError as e:  # some shards of a collection failed: rerun to retry them
    return report_failure(e)
  if args.json:
    print(json.dumps(records, indent=1))
  return 0


if __name__ == '__main__':
  sys.exit(main())
