"""``python -m dexjax.sim``: settle heaps of your objects, or draw settled procedural heaps.

  python -m dexjax.sim settle SOURCE [SOURCE ...] [--heaps B] [--seed S] [--backend auto|rollout|mjx]
                              [--scale S] [--recursive] [--out HEAPS.npz] [--json]
  python -m dexjax.sim preview OUT.png [--levels 1 2 3] [--heaps-per-level B] [--pool N] [--seed S]

``settle`` loads an object set (``builtin:all``, ``procedural:L2/0:100``, mesh files, folders; see
`dexjax.objects.load_object_set`), draws B heaps from the Dex-Net 4.0 heap distribution, settles them and
prints a summary (``--json``: one JSON object). ``--out`` saves the final poses, flags and object names as
``.npz`` (exactly at that path). Exit code 0 when every heap settled inside the bin, 1 when some object was
flagged (left the bin, never settled) or rejected, 2 for bad input (a SOURCE path that does not exist, a range
of more than 100,000 objects, ...) or when fewer objects loaded than a heap needs (docs/errors.md). ``preview``
draws a PNG of settled heaps, one row per procedural difficulty level. Outputs are checked before any computing;
an existing file is only replaced if this command wrote it, or with ``--overwrite``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import jax
import numpy as np

from dexjax.cli import (add_overwrite_flag, atomic_write, check_output_file, command, is_dexjax_png, owned_npz,
                        stamp_png)
from dexjax.objects.sets import check_object_sources, load_object_set, prepare_object_set
from dexjax.sim.bodies import heap_objects
from dexjax.sim.heap import HeapDistribution, sample_heap_states
from dexjax.sim.settling import BACKENDS, settle


def _parser() -> argparse.ArgumentParser:
  p = argparse.ArgumentParser(prog='python -m dexjax.sim', description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
  sub = p.add_subparsers(dest='command', metavar='{settle,preview}', required=True)
  s = sub.add_parser('settle', help='settle heaps of an object set and report')
  s.add_argument('sources', nargs='+', metavar='SOURCE', help='builtin:NAME|all, procedural ranges, files, folders')
  s.add_argument('--heaps', type=int, default=16, help='number of heaps (default 16)')
  s.add_argument('--seed', type=int, default=0, help='random seed of the heap states (default 0)')
  s.add_argument('--backend', choices=BACKENDS, default='auto', help='physics backend (default auto)')
  s.add_argument('--scale', type=float, default=1.0, help='unit scale of mesh files to metres (0.001: mm)')
  s.add_argument('--recursive', action='store_true', help='also read sub-directories of folders')
  s.add_argument('--out', metavar='HEAPS.npz', help='save poses, object ids, flags and object names')
  s.add_argument('--json', action='store_true', help='print the summary as one JSON object')
  add_overwrite_flag(s)
  v = sub.add_parser('preview', help='draw settled heaps of procedural objects into a PNG')
  v.add_argument('out', metavar='OUT.png', help='output PNG')
  v.add_argument('--levels', type=int, nargs='+', default=[1, 2, 3], help='difficulty levels (default 1 2 3)')
  v.add_argument('--heaps-per-level', type=int, default=3, help='heaps per level (default 3)')
  v.add_argument('--pool', type=int, default=12, help='objects per level to draw heaps from (default 12)')
  v.add_argument('--seed', type=int, default=0, help='random seed (default 0)')
  add_overwrite_flag(v)
  v.add_argument('--backend', choices=BACKENDS, default='auto', help='physics backend (default auto)')
  return p


#: Arrays of a ``settle --out`` file: an existing file with all of them is this command's own output.
SETTLE_ARRAYS = ('poses', 'object_ids', 'mask', 'left_bin', 'never_settled', 'steps', 'settled', 'object_names')


#: Largest ``--heaps`` of one run (all are sampled and kept in memory together; split larger runs).
MAX_HEAPS = 100_000

#: Procedural difficulty levels ``preview --levels`` draws.
LEVELS = (1, 2, 3)


def _settle(args: argparse.Namespace) -> int:
  if not 1 <= args.heaps <= MAX_HEAPS:
    raise ValueError(f'--heaps: expected an integer in [1, {MAX_HEAPS:,}] (MAX_HEAPS; split larger runs), got '
                     f'{args.heaps}')
  if not (math.isfinite(args.scale) and args.scale > 0):
    raise ValueError(f'--scale: expected a finite number > 0 (metres per file unit, e.g. 0.001 for millimetres), '
                     f'got {args.scale}')
  out = args.out and check_output_file(args.out, owned=owned_npz(*SETTLE_ARRAYS), overwrite=args.overwrite)
  check_object_sources(args.sources)  # a missing path or a huge range: exit 2 before any object is built
  report = load_object_set(args.sources, scale=args.scale, recursive=args.recursive)
  prepared, rejected = prepare_object_set(report, model=False, progress=not args.json)
  for r in rejected:
    print(f'rejected {r}', file=sys.stderr)
  dist = HeapDistribution()
  if len(prepared) < dist.min_count:
    raise ValueError(f'{len(prepared)} object(s) loaded; a heap needs at least {dist.min_count}')
  states = sample_heap_states(jax.random.key(args.seed), args.heaps, len(prepared), dist)
  start = time.perf_counter()
  result = settle(heap_objects(prepared), states, backend=args.backend)
  seconds = time.perf_counter() - start
  summary = {**result.summary(), 'rejected_objects': len(rejected), 'seconds': round(seconds, 3),
             'heaps_per_s': round(args.heaps / seconds, 3)}
  if out:
    arrays = dict(poses=result.poses, object_ids=np.asarray(states.object_ids), mask=result.mask,
                  left_bin=result.left_bin, never_settled=result.never_settled, steps=result.steps,
                  settled=result.settled, object_names=np.array([p.name for p in prepared]))
    atomic_write(out, lambda f: np.savez_compressed(f, **arrays))
  if args.json:
    print(json.dumps(summary))
  else:
    print(f"{summary['heaps']} heaps of {summary['objects']} objects ({len(prepared)} available) with "
          f"{summary['backend']} in {seconds:.2f} s ({summary['heaps_per_s']:.1f} heaps/s): "
          f"{summary['settled_heaps']} settled, {summary['left_bin']} objects left the bin, "
          f"{summary['never_settled']} never settled; steps mean {summary['mean_steps']:.0f}, max "
          f"{summary['max_steps']}" + (f'; wrote {args.out}' if args.out else ''))
  flagged = summary['left_bin'] or summary['never_settled'] or summary['diverged_heaps'] or rejected
  return 1 if flagged else 0


def _preview(args: argparse.Namespace) -> int:
  bad = [level for level in args.levels if level not in LEVELS]
  if bad:
    raise ValueError(f'--levels: expected difficulty levels among 1, 2 and 3, got {bad[0]}')
  for option, value in (('--heaps-per-level', args.heaps_per_level), ('--pool', args.pool)):
    if not 1 <= value <= MAX_HEAPS:
      raise ValueError(f'{option}: expected an integer in [1, {MAX_HEAPS:,}], got {value}')
  out = check_output_file(args.out, option='OUT.png', owned=is_dexjax_png, overwrite=args.overwrite)
  from dexjax.sim.preview import procedural_heap_rows, save_heap_sheet  # pylint: disable=g-import-not-at-top
  rows = procedural_heap_rows(levels=args.levels, heaps_per_level=args.heaps_per_level, pool=args.pool,
                              seed=args.seed, backend=args.backend)
  save_heap_sheet(args.out, rows)
  stamp_png(out, 'python -m dexjax.sim preview')
  for row in rows:
    s = row.result.summary()
    print(f"{row.label}: {s['heaps']} heaps, {s['objects']} objects, {s['settled_heaps']} settled, "
          f"{s['left_bin']} left the bin, mean steps {s['mean_steps']:.0f}")
  print(f'wrote {args.out}')
  return 0


@command
def main(argv: list[str] | None = None) -> int:
  args = _parser().parse_args(argv)
  return _settle(args) if args.command == 'settle' else _preview(args)


if __name__ == '__main__':
  sys.exit(main())
