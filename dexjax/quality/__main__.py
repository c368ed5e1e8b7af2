"""``python -m dexjax.quality``: robust grasp quality of sampled or given grasps on one object.

  python -m dexjax.quality MESH --gripper parallel_jaw|suction --num-grasps N --seed S --out OUT.json
  python -m dexjax.quality MESH --grasps IN.json --seed S --out OUT.json

MESH is a mesh file (OBJ, STL, PLY, GLB, OFF) or a built-in object such as ``builtin:box``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time

import jax

from dexjax.config import ConfigError
from dexjax.geometry.mesh_io import MeshError
from dexjax.objects import load_object_model
from dexjax.quality.grasp_json import GraspFileError
from dexjax.quality.report import (ReportSettings, evaluate_report, load_settings, object_summary,
                                   read_grasp_file, report_parameters, sample_grasps)


def _parser() -> argparse.ArgumentParser:
  p = argparse.ArgumentParser(prog="python -m dexjax.quality", description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument("mesh", help="mesh file or builtin:NAME (e.g. builtin:box)")
  src = p.add_mutually_exclusive_group(required=True)
  src.add_argument("--gripper", choices=["parallel_jaw", "suction"], help="sample grasps for this gripper")
  src.add_argument("--grasps", help="JSON file of grasps to evaluate instead of sampling")
  p.add_argument("--num-grasps", type=int, default=20, help="grasps to sample (default 20)")
  p.add_argument("--seed", type=int, default=0)
  p.add_argument("--out", required=True, help="output JSON path")
  p.add_argument("--scale", type=float, default=1.0, help="mesh unit scale, e.g. 0.001 for millimetres")
  p.add_argument("--grid-size", type=int, default=100,
                 help="signed distance grid resolution per axis (default 100, as Dex-Net)")
  p.add_argument("--config", help="YAML file of gripper, perturbation and solver parameters "
                 "(layout: configs/quality.yaml; default: Dex-Net 4.0's values)")
  p.add_argument("--samples", type=int, help="Monte-Carlo samples M (10 rewards, 25 supervisor; overrides --config)")
  p.add_argument("--threshold", type=float,
                 help="robust label threshold (0.5 rewards, 0.75 supervisor; overrides --config)")
  return p


def main(argv: list[str] | None = None) -> int:
  args = _parser().parse_args(argv)
  if args.grid_size < 16:
    print(f"error: --grid-size must be at least 16, got {args.grid_size}", file=sys.stderr)
    return 2
  if args.num_grasps <= 0 or (args.samples is not None and args.samples <= 0) or (
      args.threshold is not None and not 0.0 <= args.threshold <= 1.0):
    print("error: --num-grasps and --samples must be positive and --threshold within [0, 1]", file=sys.stderr)
    return 2
  try:
    settings = load_settings(args.config) if args.config else ReportSettings()
  except ConfigError as e:
    print(f"error: {e}", file=sys.stderr)
    return 2
  overrides = {k: v for k, v in (("num_samples", args.samples), ("threshold", args.threshold)) if v is not None}
  settings = dataclasses.replace(settings, **overrides)
  try:
    model = load_object_model(args.mesh, scale=args.scale, grid_size=args.grid_size)
    key = jax.random.key(args.seed)
    start = time.perf_counter()
    if args.grasps:
      with open(args.grasps) as f:
        try:
          data = json.load(f)
        except json.JSONDecodeError as e:
          raise GraspFileError(f"{args.grasps}: not valid JSON ({e})") from None
      grasps = read_grasp_file(data, args.grasps, settings)
    else:
      grasps = sample_grasps(jax.random.fold_in(key, 1), model, args.gripper, args.num_grasps, settings)
      if len(grasps) < args.num_grasps:
        print(f"warning: only {len(grasps)} of {args.num_grasps} sampled {args.gripper} grasps were valid",
              file=sys.stderr)
    records = evaluate_report(jax.random.fold_in(key, 2), model, grasps, settings)
  except (MeshError, GraspFileError, OSError, ValueError) as e:
    print(f"error: {e}", file=sys.stderr)
    return 1
  grippers = sorted({g for g, _ in grasps}) or ([args.gripper] if args.gripper else [])
  out = {"object": object_summary(model, args.mesh), "parameters": report_parameters(settings, args.seed, grippers),
         "grasps": records}
  with open(args.out, "w") as f:
    json.dump(out, f, indent=1)
  robust = sum(r["robust"] for r in records)
  print(f"{len(records)} grasps on {args.mesh}: {robust} robust (p > {settings.threshold}); "
        f"{time.perf_counter() - start:.1f} s; wrote {args.out}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
