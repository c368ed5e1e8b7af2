"""``python -m dexjax.objects``: check a folder of your own meshes, preview procedural objects, show hulls and masses,
and whether each object can be picked alone.

  python -m dexjax.objects check DIR [--json] [--scale S] [--recursive]
  python -m dexjax.objects hulls MESH [--max-hulls K] [--max-vertices V] [--scale S]
  python -m dexjax.objects masses SOURCE ... [--json] [--scale S] [--recursive]
  python -m dexjax.objects pickable SOURCE ... [--drops 3] [--attempts 3] [--seed S] [--json] [--cache-dir DIR]
  python -m dexjax.objects --preview OUT.png [--per-level N] [--seed S]

``check`` loads every mesh file in DIR (OBJ, STL, PLY, GLB, OFF) and reports each as loaded, loaded with a
warning (an open or non-manifold mesh loaded as the solid its winding number encloses; an implausible size, e.g. a
file in millimetres without ``--scale 0.001``) or rejected with the reason; exit code 0 when at least one object
loaded, 1 when none did, 2 for bad input (docs/errors.md).
``--json`` prints ``{"loaded": [names], "rejected": [{"file": ..., "reason": ...}], "warnings": [{"name": ...,
"warning": ...}]}`` to stdout.
``hulls`` prints the convex collision pieces of one mesh (a file or ``builtin:NAME``). ``--scale`` (> 0),
``--max-hulls`` (1 to 1024) and ``--max-vertices`` (4 to 1024) are checked, naming the option, before any mesh is read.
``masses`` prints one line per object of the set the sources name (``procedural:L1/0:25@77``, ``builtin:all``,
files, folders): name, family, material, sorted extents (cm), volume (cm^3), density (kg/m^3) and the mass (kg)
the heap physics gives it (`dexjax.sim.heap_object`), then the set's mass summary beside the reward's Gamma prior
(mean 0.25 kg, sd 0.224 kg); ``--json`` prints ``{"objects": [...], "summary": {...}, "prior": {...},
"max_mass": 0.6, "rejected": [...]}``. A source that cannot be used (a malformed spec, a missing or broken file)
is bad input (exit 2); a folder's broken files are listed as rejected; exit 1 when no object loaded.
``pickable`` drops each object of the set alone into the benchmark's bin ``--drops`` times (a fresh resting pose
each) and lets the supervisor (the true state, both grippers) try to pick it ``--attempts`` times, judged in
MuJoCo and by the labels' reward (`dexjax.bench.pickability`); it prints per object the drops picked, picked at
the first attempt, whose first grasp the labels accept and with no grasp, the grippers that picked it and the
physics failures, then the objects picked in no drop: an object neither gripper can pick as it lies is a defect
of a benchmark's set. ``--json`` prints ``{"objects": [...], "summary": {...}, "settings": {...}}``; exit 1 when
no object loaded. It settles, renders and executes every attempt in MuJoCo: about 2.5 s per drop once compiled
(25 objects, 3 drops each: 3 minutes on a 2-core CPU).
``--preview`` draws a contact sheet of procedural objects at difficulty levels 1-3 (OUT.png is checked before
any drawing; an existing file is only replaced if this command drew it, or with ``--overwrite``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import warnings
from typing import TYPE_CHECKING

import trimesh

from dexjax.cli import add_overwrite_flag, check_output_file, command, is_dexjax_png, report_failure, stamp_png
from dexjax.config_rules import MAX_STATIC_COUNT
from dexjax.objects.builtin import resolve_mesh
from dexjax.objects.collision import cached_collision_hulls
from dexjax.objects.folder import FolderReport, emit_warnings, load_mesh_folder

if TYPE_CHECKING:
  from dexjax.bench.pickability import ObjectPickability
  from dexjax.objects.masses import ObjectMass


def _parser() -> argparse.ArgumentParser:
  p = argparse.ArgumentParser(prog='python -m dexjax.objects', description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument('--preview', metavar='OUT.png', help='write a contact sheet of procedural objects (levels 1-3)')
  p.add_argument('--per-level', type=int, metavar='N', help='objects per difficulty level in the preview')
  p.add_argument('--seed', type=int, metavar='S', help='random seed of the preview')
  add_overwrite_flag(p)
  sub = p.add_subparsers(dest='command', metavar='{check,hulls,masses,pickable}')
  check = sub.add_parser('check', help='load a folder of meshes and report each file')
  check.add_argument('dir', metavar='DIR', help='folder of mesh files')
  check.add_argument('--json', action='store_true', help='print the report as JSON on stdout')
  check.add_argument('--scale', type=float, default=1.0, help='unit scale to metres, e.g. 0.001 for millimetres')
  check.add_argument('--recursive', action='store_true', help='also read sub-directories')
  hulls = sub.add_parser('hulls', help="print a mesh's convex collision pieces")
  hulls.add_argument('mesh', metavar='MESH', help='mesh file or builtin:NAME')
  hulls.add_argument('--max-hulls', type=int, default=8, help='maximum convex pieces (default 8)')
  hulls.add_argument('--max-vertices', type=int, default=64, help='maximum vertices per piece (default 64)')
  hulls.add_argument('--scale', type=float, default=1.0, help='unit scale to metres, e.g. 0.001 for millimetres')
  masses = sub.add_parser('masses', help="print each object's size, density and mass beside the reward's prior")
  masses.add_argument('sources', nargs='+', metavar='SOURCE',
                      help="object sources: 'procedural:L1/0:25@77', 'builtin:all', mesh files or folders")
  masses.add_argument('--json', action='store_true', help='print the table and summary as JSON on stdout')
  masses.add_argument('--scale', type=float, default=1.0, help='unit scale of mesh files to metres')
  masses.add_argument('--recursive', action='store_true', help='also read the sub-directories of folders')
  pick = sub.add_parser('pickable', help='drop each object alone into the bin and let the supervisor pick it')
  pick.add_argument('sources', nargs='+', metavar='SOURCE',
                    help="object sources: 'procedural:L1/0:25@77', 'builtin:all', mesh files or folders")
  pick.add_argument('--drops', type=int, default=3, help='drops (trials) per object (default 3)')
  pick.add_argument('--attempts', type=int, default=3, help='attempts per drop (default 3)')
  pick.add_argument('--seed', type=int, default=argparse.SUPPRESS,  # given before the command too (the preview's)
                    help='seed of the drops, cameras and judges (default 0)')
  pick.add_argument('--json', action='store_true', help='print the rows and summary as JSON on stdout')
  pick.add_argument('--cache-dir', help='object cache (default $DEXJAX_CACHE or ~/.cache/dexjax/objects)')
  return p


def _check(args: argparse.Namespace) -> int:
  report = load_mesh_folder(args.dir, scale=args.scale, recursive=args.recursive)
  emit_warnings(report.loaded)  # also on stderr, as every CLI reports warnings
  if args.json:
    print(json.dumps(report.to_json()))
  else:
    _print_report(report, args.dir)
  return 0 if report.loaded else 1


def _print_report(report: FolderReport, directory: str) -> None:
  """Human-readable report: a rich table when rich is installed, plain lines otherwise."""
  rows = sorted([(os.path.relpath(o.path, directory).replace(os.sep, '/'), 'warning' if o.warnings else 'loaded',
                  '; '.join([f'{o.name}: {_describe(o.mesh)}', *map(str, o.warnings)])) for o in report.loaded]
                + [(r.file, 'rejected', r.reason) for r in report.rejected])
  warned = sum(1 for o in report.loaded if o.warnings)
  summary = (f'{len(report.loaded)} loaded ({warned} with warnings), {len(report.rejected)} rejected in '
             f'{directory}')
  try:
    from rich.console import Console
    from rich.table import Table
    from rich.text import Text
  except ImportError:
    for file, status, detail in rows:
      print(f'{status:8s}  {file}  {detail}')
    print(summary)
    return
  table = Table(show_header=True, header_style='bold')
  for column in ('file', 'status', 'details'):
    table.add_column(column, overflow='fold')
  for file, status, detail in rows:
    style = {'loaded': 'green', 'warning': 'yellow'}.get(status, 'red')
    table.add_row(Text(file), Text(status, style=style), Text(detail))
  console = Console(highlight=False)
  console.print(table)
  console.print(Text(summary))


def _describe(mesh: trimesh.Trimesh) -> str:
  """Extents (cm), volume (cm^3) and face count of a mesh in metres."""
  ex = mesh.extents * 100
  return f'{ex[0]:.1f} x {ex[1]:.1f} x {ex[2]:.1f} cm, {mesh.volume * 1e6:.1f} cm^3, {len(mesh.faces)} faces'


def _hulls(args: argparse.Namespace) -> int:
  mesh, name = resolve_mesh(args.mesh, scale=args.scale)
  hulls = cached_collision_hulls(mesh, max_hulls=args.max_hulls, max_vertices=args.max_vertices)
  pieces = [trimesh.convex.convex_hull(h) for h in hulls]
  for i, piece in enumerate(pieces):
    print(f'hull {i}: {len(hulls[i])} vertices, {piece.volume * 1e6:.2f} cm^3')
  union = trimesh.boolean.union(pieces, engine='manifold') if len(pieces) > 1 else pieces[0]
  print(f'{name}: {len(hulls)} hulls; union {union.volume * 1e6:.2f} cm^3 = '
        f'{union.volume / mesh.volume:.1%} of the mesh volume {mesh.volume * 1e6:.2f} cm^3')
  return 0


def _masses(args: argparse.Namespace) -> int:
  from dexjax.objects.masses import mass_summary, object_masses, prior_summary  # Imported lazily: JAX, MuJoCo.
  from dexjax.objects.procedural import MAX_MASS
  from dexjax.objects.sets import expand_object_sources, load_object_set
  report = load_object_set(args.sources, scale=args.scale, recursive=args.recursive)
  top_level = set(expand_object_sources(args.sources))
  for r in report.rejected:
    if r.file in top_level:  # A source itself, not a file in a folder: bad input.
      raise ValueError(f'{r.file}: {r.reason}')
  rows = object_masses(report.loaded)
  summary = mass_summary([r.mass for r in rows]) if rows else None
  if args.json:
    rejected = [{'file': r.file, 'reason': r.reason} for r in report.rejected]
    print(json.dumps({'objects': [r.to_json() for r in rows], 'summary': summary, 'prior': prior_summary(),
                      'max_mass': MAX_MASS, 'rejected': rejected}))
  else:
    _print_masses(rows, summary, prior_summary(), MAX_MASS)
  for r in report.rejected:
    warnings.warn(f'rejected {r.file}: {r.reason}', stacklevel=1)
  return 0 if rows else report_failure(f"no object of {' '.join(args.sources)} could be loaded")


def _print_masses(rows: list[ObjectMass], summary: dict[str, float] | None, prior: dict[str, float],
                  max_mass: float) -> None:
  """One line per object, then the set's summary beside the prior's."""
  table = [(r.name, r.family or '-', r.material or '-', ' x '.join(f'{100 * e:.1f}' for e in r.extents),
            f'{r.volume * 1e6:.1f}', f'{r.density:.0f}', f'{r.mass:.3f}') for r in rows]
  header = ('name', 'family', 'material', 'extents (cm)', 'volume (cm^3)', 'density (kg/m^3)', 'mass (kg)')
  widths = [max(len(line[i]) for line in [header, *table]) for i in range(len(header))]
  for line in [header, *table]:
    print('  '.join(f'{cell:<{w}}' if i < 4 else f'{cell:>{w}}' for i, (cell, w) in enumerate(zip(line, widths))))
  if summary is not None:
    print(f"{summary['count']} objects: mean {summary['mean']:.3f} kg, median {summary['median']:.3f}, quartiles "
          f"{summary['q25']:.3f}-{summary['q75']:.3f}, min {summary['min']:.3f}, max {summary['max']:.3f}; "
          f"{summary['above_prior_mean']:.0%} above the prior's mean {prior['mean']:.2f} kg, "
          f"{summary['above_max_mass']:.0%} above MAX_MASS {max_mass} kg")
  print(f"prior (Gamma, mean {prior['mean']:.2f} kg, sd {prior['sd']:.3f} kg): median {prior['median']:.3f}, "
        f"quartiles {prior['q25']:.3f}-{prior['q75']:.3f}; {prior['above_prior_mean']:.0%} above its mean, "
        f"{prior['above_max_mass']:.0%} above {max_mass} kg")


def _pickable(args: argparse.Namespace) -> int:
  # Imported lazily: the benchmark's world (JAX, MuJoCo, the renderer) and the supervisor.
  from dexjax.bench.judges import analytic_judge, physics_judge
  from dexjax.bench.pickability import pickability_summary, set_pickability
  from dexjax.bench.runner import benchmark_config
  from dexjax.bench.supervisor_policy import supervisor_policy
  from dexjax.bench.world import PickingWorld
  from dexjax.compile_cache import persistent_compilation_cache
  from dexjax.objects.sets import check_object_sources
  check_object_sources(args.sources)  # a missing path or a malformed range: exit 2 before anything is built
  with persistent_compilation_cache(), PickingWorld(benchmark_config(args.sources), cache_dir=args.cache_dir) as world:
    for r in world.rejected:
      warnings.warn(f'rejected {r.file}: {r.reason}', stacklevel=1)
    if not world.names:
      return report_failure(f"no object of {' '.join(args.sources)} could be loaded")
    judges = {'analytic': analytic_judge(world), 'physics': physics_judge(world)}
    rows = set_pickability(world, supervisor_policy(world), judges, drops=args.drops, attempts=args.attempts,
                           seed=_seed(args), progress=None if args.json else _print_pickability)
  summary = pickability_summary(rows)
  if args.json:
    settings = {'sources': list(args.sources), 'drops': args.drops, 'attempts': args.attempts, 'seed': _seed(args)}
    print(json.dumps({'objects': [r.to_json() for r in rows], 'summary': summary, 'settings': settings}))
  else:
    print(f"{summary['pickable']} of {summary['objects']} objects picked alone; of {summary['drops']} drops "
          f"{summary['picked']:.0%} picked, {summary['first_attempt']:.0%} at the first attempt, the labels "
          f"accepting {summary['labels_pass']:.0%} of the first grasps; picked in no drop: "
          f"{', '.join(summary['not_pickable']) or 'none'}")
  return 0


def _seed(args: argparse.Namespace) -> int:
  return 0 if args.seed is None else args.seed


def _print_pickability(row: ObjectPickability) -> None:
  """One line per object as it is done."""
  failures = ', '.join(f'{k} {v}' for k, v in row.failures.items()) or '-'
  grippers = ', '.join(f'{k} {v}' for k, v in row.grippers.items()) or '-'
  print(f'{row.name:<24} {row.mass:6.3f} kg  picked {row.picked}/{row.drops} (first attempt {row.first_attempt}, '
        f'labels {row.labels_pass}, no grasp {row.no_grasp})  by {grippers}  failures: {failures}', flush=True)


def _preview(args: argparse.Namespace) -> int:
  if args.per_level is not None and args.per_level <= 0:
    raise ValueError(f'--per-level: expected an integer >= 1, got {args.per_level}')
  if args.seed is not None and args.seed < 0:
    raise ValueError(f'--seed: expected an integer >= 0, got {args.seed}')
  out = check_output_file(args.preview, option='--preview', owned=is_dexjax_png, overwrite=args.overwrite)
  from dexjax.objects.preview import save_contact_sheet  # Imported lazily: pulls in the generator.
  kwargs = {k: v for k, v in (('per_level', args.per_level), ('seed', args.seed)) if v is not None}
  save_contact_sheet(args.preview, levels=(1, 2, 3), **kwargs)
  stamp_png(out, 'python -m dexjax.objects --preview')
  print(f'wrote {args.preview}')
  return 0


def _check_args(args: argparse.Namespace) -> None:
  """Raises ValueError naming the option and the expected value, before any mesh is read."""
  checks = []
  if getattr(args, 'scale', None) is not None:
    checks.append(('--scale', math.isfinite(args.scale) and args.scale > 0,
                   'a finite number > 0 (metres per file unit, e.g. 0.001 for millimetres)', args.scale))
  if args.command == 'pickable':
    checks += [('--drops', 1 <= args.drops <= MAX_STATIC_COUNT, f'an integer in [1, {MAX_STATIC_COUNT}]', args.drops),
               ('--attempts', 1 <= args.attempts <= 75, 'an integer in [1, 75] (the seed\'s attempts per trial)',
                args.attempts),
               ('--seed', _seed(args) >= 0, 'an integer >= 0', args.seed)]
  if args.command == 'hulls':
    checks += [('--max-hulls', 1 <= args.max_hulls <= MAX_STATIC_COUNT, f'an integer in [1, {MAX_STATIC_COUNT}]',
                args.max_hulls),
               ('--max-vertices', 4 <= args.max_vertices <= MAX_STATIC_COUNT,
                f'an integer in [4, {MAX_STATIC_COUNT}]', args.max_vertices)]
  for option, ok, expected, value in checks:
    if not ok:
      raise ValueError(f'{option}: expected {expected}, got {value}')


@command
def main(argv: list[str] | None = None) -> int:
  parser = _parser()
  args = parser.parse_args(argv)
  if args.preview and args.command:
    raise ValueError(f'--preview cannot be combined with the {args.command!r} command')
  _check_args(args)
  if args.command == 'check':
    return _check(args)
  if args.command == 'hulls':
    return _hulls(args)
  if args.command == 'masses':
    return _masses(args)
  if args.command == 'pickable':
    return _pickable(args)
  if args.preview:
    return _preview(args)
  parser.print_usage(sys.stderr)
  raise ValueError('give a command (check, hulls, masses, pickable) or --preview OUT.png')


if __name__ == '__main__':
  sys.exit(main())
