"""``python -m dexjax.quality``: robust grasp quality of sampled or given grasps on one object.

  python -m dexjax.quality MESH --gripper parallel_jaw|suction --num-grasps N --seed S --out OUT.json
  python -m dexjax.quality MESH --grasps IN.json --seed S --out OUT.json

MESH is a mesh file (OBJ, STL, PLY, GLB, OFF) or a built-in object such as ``builtin:box``. Exit code 0 on
success, 1 when no valid grasp could be sampled (nothing is written), 2 for bad input (docs/errors.md); OUT is
checked before any computing and an existing file is only replaced if it is an earlier report (or --overwrite).
Given grasps are checked: JSON numbers (no booleans) of magnitude <= 1000, a width within the gripper's
[min_width, max_width], a center within 10 m of the object. The report is strict JSON (NaN written as null).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time

import jax

from dexjax.cli import FAILURE_EXIT, add_overwrite_flag, atomic_write, check_output_file, command, owned_json
from dexjax import config_rules
from dexjax.config import plain_json
from dexjax.objects import load_object_model
from dexjax.objects.builtin import check_object_spec
from dexjax.quality.grasp_json import GraspFileError, load_grasp_json
from dexjax.quality.report import (ReportSettings, check_grasps_near_object, evaluate_report, load_settings,
                                   object_summary, read_grasp_file, report_parameters, sample_grasps)

#: Top-level keys of a report: an existing file with all of them is this command's own output (replaced freely).
REPORT_KEYS = ('object', 'parameters', 'grasps')


def _parser() -> argparse.ArgumentParser:
  p = argparse.ArgumentParser(prog="python -m dexjax.quality", description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument("mesh", help="mesh file or builtin:NAME (e.g. builtin:box)")
  src = p.add_mutually_exclusive_group(required=True)
  src.add_argument("--gripper", choices=["parallel_jaw", "suction"], help="sample grasps for this gripper")
  src.add_argument("--grasps", help="JSON file of grasps to evaluate instead of sampling")
  p.add_argument("--num-grasps", type=int, default=20, help="grasps to sample (default 20)")
  p.add_argument("--seed", type=int, default=0)
  p.add_argument("--out", required=True, help="output JSON path (its directory must exist)")
  add_overwrite_flag(p)
  p.add_argument("--scale", type=float, default=1.0, help="mesh unit scale, e.g. 0.001 for millimetres")
  p.add_argument("--grid-size", type=int, default=100,
                 help="signed distance grid resolution per axis (default 100, as Dex-Net)")
  p.add_argument("--config", help="YAML file of gripper, perturbation and solver parameters "
                 "(layout: configs/quality.yaml; default: Dex-Net 4.0's values)")
  p.add_argument("--samples", type=int, help="Monte-Carlo samples M (10 rewards, 25 supervisor; overrides --config)")
  p.add_argument("--threshold", type=float,
                 help="robust label threshold (0.5 rewards, 0.75 supervisor; overrides --config)")
  return p


MAX_GRID_SIZE = config_rules.MAX_GRID_SIZE
"""Largest ``--grid-size``: a 512^3 float32 signed distance grid is 0.5 GB (Dex-Net's SDFGen used 100)."""

MAX_NUM_GRASPS = 100_000
"""Largest ``--num-grasps`` of one run (all are evaluated together; split larger sets over runs)."""

MAX_SAMPLES = config_rules.MAX_SAMPLES
"""Largest ``--samples`` (Monte-Carlo draws M per grasp; the seed uses 10 and 25), as a config's ``num_samples``."""

MAX_GRASP_SAMPLES = 10_000_000
"""Largest number of grasps x samples of one run (the robust quality's working set grows with it)."""


def _check_arguments(args: argparse.Namespace) -> None:
  """Raises ValueError naming the option and the expected value (sizes bounded, so that none exhausts memory)."""
  grasps = f"an integer in [1, {MAX_NUM_GRASPS}]"
  checks = [("--grid-size", 16 <= args.grid_size <= MAX_GRID_SIZE, f"an integer in [16, {MAX_GRID_SIZE}]",
             args.grid_size),
            ("--num-grasps", 1 <= args.num_grasps <= MAX_NUM_GRASPS, grasps, args.num_grasps),
            ("--samples", args.samples is None or 1 <= args.samples <= MAX_SAMPLES,
             f"an integer in [1, {MAX_SAMPLES}]", args.samples),
            ("--samples", args.samples is None or args.samples * args.num_grasps <= MAX_GRASP_SAMPLES,
             f"at most {MAX_GRASP_SAMPLES:,} grasp samples with --num-grasps {args.num_grasps}", args.samples),
            ("--threshold", args.threshold is None or 0.0 <= args.threshold <= 1.0, "a probability in [0, 1]",
             args.threshold),
            ("--scale", math.isfinite(args.scale) and args.scale > 0, "a finite number > 0", args.scale)]
  for option, ok, expected, value in checks:
    if not ok:
      raise ValueError(f"{option}: expected {expected}, got {value}")


def _strict_json(report: dict) -> str:
  """The report as strict JSON: NaN and infinities (which JSON lacks) become null."""
  return json.dumps(plain_json(report, nan_to_none=True), indent=1, allow_nan=False)


@command
def main(argv: list[str] | None = None) -> int:
  args = _parser().parse_args(argv)
  _check_arguments(args)
  check_object_spec(args.mesh)
  out_path = check_output_file(args.out, owned=owned_json(*REPORT_KEYS), overwrite=args.overwrite)
  settings = load_settings(args.config) if args.config else ReportSettings()
  overrides = {k: v for k, v in (("num_samples", args.samples), ("threshold", args.threshold)) if v is not None}
  settings = dataclasses.replace(settings, **overrides)
  grasps = None
  if args.grasps:
    grasps = read_grasp_file(load_grasp_json(args.grasps), args.grasps, settings)
    if not grasps:
      raise GraspFileError(f"{args.grasps}: 'grasps' is empty; expected at least one grasp")
  model = load_object_model(args.mesh, scale=args.scale, grid_size=args.grid_size)
  if grasps is not None:
    check_grasps_near_object(grasps, model.bounds, args.grasps)
  key = jax.random.key(args.seed)
  start = time.perf_counter()
  if grasps is None:
    grasps = sample_grasps(jax.random.fold_in(key, 1), model, args.gripper, args.num_grasps, settings)
    if not grasps:
      extent = float((model.bounds[1] - model.bounds[0]).max())
      print(f"error: no valid {args.gripper} grasp found on {args.mesh} (largest extent {extent:.3g} m); nothing "
            f"written to {args.out}", file=sys.stderr)
      return FAILURE_EXIT
    if len(grasps) < args.num_grasps:
      print(f"warning: only {len(grasps)} of {args.num_grasps} sampled {args.gripper} grasps were valid",
            file=sys.stderr)
  records = evaluate_report(jax.random.fold_in(key, 2), model, grasps, settings)
  grippers = sorted({g for g, _ in grasps})
  report = {"object": object_summary(model, args.mesh), "parameters": report_parameters(settings, args.seed, grippers),
            "grasps": records}
  atomic_write(out_path, lambda f: f.write(_strict_json(report).encode("utf-8")))
  robust = sum(r["robust"] for r in records)
  print(f"{len(records)} grasps on {args.mesh}: {robust} robust (p > {settings.threshold}); "
        f"{time.perf_counter() - start:.1f} s; wrote {args.out}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
