"""Generate a Dex-Net 4.0-style dataset of labelled grasps on rendered heaps.

  python -m dexjax.generate --config configs/dexnet4.yaml --out DIR --num-images N
      [--objects SOURCE ...] [--gripper-config FILE] [--camera-config FILE] [--seed S]
      [--collection-policy tau|on_policy] [--model RUN]
      [--shard i/N] [--workers W] [--backend serial|process|ray] [--ray-address ADDR]
      [--cache-dir DIR] [--no-preview] [--verify] [--overwrite] [--json]
  python -m dexjax.generate --relabel SRC --num-samples M --out DIR [--config FILE] [--cache-dir DIR] [--json]

Writes shards, ``manifest.json``, ``config.json`` and ``preview.png`` to DIR, then prints a summary (rows,
positive rate and failure reasons per gripper, rows per second). Rerun the same command to resume a killed run.
DIR must be new, empty or a run of this command: files it did not write are never replaced (``--overwrite``
lifts this). Exit code 0 on success, 1 when some shards failed (the others are written), 2 for bad input
(docs/errors.md).

With ``--collection-policy on_policy --model RUN`` the candidates labelled are the grasps the learned policy of
training run RUN scores on each image (its CEM of both grippers; on-policy dataset synthesis,
docs/generate.md), not the seed's uniform ones.

With ``--relabel SRC`` it writes run SRC's shards again with every reward drawn with M = ``--num-samples``
Monte-Carlo draws (the same heaps, images and grasps; ``--config`` is the file SRC was made with), resumably:
labels of many draws to train on (docs/generate.md, "Labelling a dataset again").
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from dexjax.cli import add_overwrite_flag, command
from dexjax.config import validate_generate_config


def _parser() -> argparse.ArgumentParser:
  p = argparse.ArgumentParser(prog='python -m dexjax.generate', description=__doc__.split('\n\n')[0])
  p.add_argument('--config', help='generation config (layout: configs/dexnet4.yaml; default: Dex-Net 4.0 values)')
  p.add_argument('--out', required=True, help='output directory (created; rerun to resume)')
  p.add_argument('--num-images', type=int, help='images to generate (rounded up to whole shards)')
  p.add_argument('--objects', nargs='+', metavar='SOURCE',
                 help='object sources: builtin:level1|level2|level3, builtin:NAME, procedural:L2/0:1000, mesh '
                      'files or folders (replaces the config\'s objects.sources)')
  p.add_argument('--gripper-config', help='gripper file (layout: configs/quality.yaml)')
  p.add_argument('--camera-config', help='camera file: a YAML of camera-distribution ranges, or intrinsics / a '
                                         'posed camera (JSON, ROS CameraInfo JSON/YAML)')
  p.add_argument('--seed', type=int, help='run seed (replaces the config\'s)')
  p.add_argument('--collection-policy', choices=('tau', 'on_policy'),
                 help="which policy proposes the candidates: the seed's uniform ones (tau) or a learned policy's "
                      "(on_policy, with --model); replaces the config's collection.policy")
  p.add_argument('--model', metavar='RUN', help='on_policy: the collecting policy\'s GQ-CNNs (a training run, saved '
                                                'model or model file); replaces the config\'s collection.model')
  p.add_argument('--shard', default='0/1', metavar='i/N', help='write only the shards with index %% N == i')
  p.add_argument('--workers', type=int, default=1, help='parallel workers (default 1)')
  p.add_argument('--backend', choices=('serial', 'process', 'ray'), default='process',
                 help='how workers run when --workers > 1 (default: local processes)')
  p.add_argument('--ray-address', help='join this Ray cluster (default: start a local Ray instance)')
  p.add_argument('--cache-dir', help='object and supervisor cache (default $DEXJAX_CACHE or ~/.cache/dexjax/objects)')
  p.add_argument('--no-preview', action='store_true', help='do not write preview.png')
  p.add_argument('--verify', action='store_true', help='re-read every finished shard before resuming (slow)')
  p.add_argument('--json', action='store_true', help='print the summary as JSON')
  p.add_argument('--relabel', metavar='SRC', help="instead of generating: write run SRC's shards again with new "
                                                  'reward draws (--num-samples of them per label)')
  p.add_argument('--num-samples', type=int, help='with --relabel: Monte-Carlo draws M per label (the seed: 10)')
  add_overwrite_flag(p)
  return p


@command
def main(argv: list[str] | None = None) -> int:
  args = _parser().parse_args(argv)
  if args.relabel is not None:
    return _relabel(args)
  if args.num_images is None:
    raise ValueError('--num-images: expected an integer >= 1 (images to generate), got none')
  if args.workers < 1:
    raise ValueError(f'--workers: expected an integer >= 1, got {args.workers}')
  if args.num_images < 1:
    raise ValueError(f'--num-images: expected an integer >= 1, got {args.num_images}')
  from dexjax.data.manifest import parse_shard_assignment  # pylint: disable=g-import-not-at-top (slow imports)
  from dexjax.generate.config import load_generate_config  # pylint: disable=g-import-not-at-top
  from dexjax.generate.report import format_summary  # pylint: disable=g-import-not-at-top
  from dexjax.generate.run import check_run_dir, generate_dataset  # pylint: disable=g-import-not-at-top
  assignment = parse_shard_assignment(args.shard)
  check_run_dir(args.out, overwrite=args.overwrite)  # before the configs: a wrong --out fails at once
  config = load_generate_config(args.config, gripper_config=args.gripper_config, camera_config=args.camera_config,
                                objects=args.objects, seed=args.seed,
                                collection_policy=args.collection_policy, model=args.model)
  validate_generate_config(config, args.config or 'the default config')  # fields that constrain each other
  summary = generate_dataset(config, args.out, args.num_images, assignment=assignment, backend=args.backend,
                             workers=args.workers, ray_address=args.ray_address, cache_dir=args.cache_dir,
                             progress=not args.json, preview=not args.no_preview, verify=args.verify,
                             overwrite=args.overwrite)
  if args.json:
    print(json.dumps(summary, indent=1))
  else:
    print(format_summary(summary))
    print(f"stage seconds: {', '.join(f'{k} {v:.1f}' for k, v in summary['stage_seconds'].items())}")
    shards = summary['shards']
    print(f"shards: {shards['written']} written, {shards['skipped']} already done, {len(shards['failed'])} failed "
          f"of {shards['assigned']} assigned ({shards['total']} in the run); output {os.path.abspath(args.out)}")
    for index, reason in shards['failed'].items():
      print(f'shard {index} failed: {reason}', file=sys.stderr)
  return 1 if summary['shards']['failed'] else 0


_GENERATION_ONLY = ('objects', 'gripper_config', 'camera_config', 'seed', 'num_images', 'collection_policy', 'model')


def _relabel(args: argparse.Namespace) -> int:
  """``--relabel SRC``: `dexjax.generate.relabel_dataset`, then its summary."""
  for name in _GENERATION_ONLY:
    if getattr(args, name) is not None:
      raise ValueError(f"--{name.replace('_', '-')}: not used with --relabel (the run SRC fixes it); got "
                       f'{getattr(args, name)!r}')
  if args.num_samples is None:
    raise ValueError('--num-samples: expected an integer >= 1 with --relabel, got none')
  from dexjax.generate.relabel import relabel_dataset  # pylint: disable=g-import-not-at-top (slow imports)
  summary = relabel_dataset(args.relabel, args.out, args.num_samples, config_path=args.config,
                            cache_dir=args.cache_dir, progress=not args.json, overwrite=args.overwrite)
  if args.json:
    print(json.dumps(summary, indent=1))
  else:
    shards = summary['shards']
    flipped = ', '.join(f'{k} {100 * v:.1f} %' for k, v in summary['flipped'].items())
    print(f"relabelled {summary['rows']} rows with M = {args.num_samples} ({summary['rows_per_s'] or 0:.0f} rows/s); "
          f"rewards changed: {flipped or 'none written'}")
    print(f"shards: {shards['written']} written, {shards['skipped']} already done, {shards['missing']} not "
          f"finished in {args.relabel} (rerun when they are); output {os.path.abspath(args.out)}")
  return 0


if __name__ == '__main__':
  sys.exit(main())
