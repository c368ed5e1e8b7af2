"""Robust grasp-quality throughput (M = 10) for both grippers, dexjax vs. the original's way, one JSON object.

  python benchmarks/quality_throughput.py [--object builtin:box] [--baseline-grasps 20] [--repeats 3]

dexjax: one ``jax.jit(jax.vmap(robust_*_quality))`` call per batch of 1,000 and 10,000 grasps (median of
``--repeats`` timed calls after compilation). Baseline, measured in the same run: per grasp and per sample,
NumPy contact finding on the same grid and a cvxopt QP, as Dex-Net did (`_numpy_baseline.py`). Keys ending in
``_ratio`` are dexjax grasps/s divided by baseline grasps/s. The machine is shared and noisy: compare ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import jax
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import _numpy_baseline as baseline  # noqa: E402

from dexjax.grippers import ParallelJawGripper, SuctionGripper  # noqa: E402
from dexjax.objects import load_object_model  # noqa: E402
from dexjax.quality import (QualityConfig, parallel_jaw_perturbations, robust_parallel_jaw_quality,  # noqa: E402
                            robust_suction_quality, suction_perturbations)
from dexjax.sampling import sample_antipodal_grasps, sample_suction_grasps  # noqa: E402


def _tile(grasps, valid, n):
  idx = np.flatnonzero(np.asarray(valid))
  idx = np.resize(idx, n)
  return jax.tree.map(lambda x: np.asarray(x)[idx], grasps)


def _time(fn, *args, repeats):
  jax.block_until_ready(fn(*args))  # compile + warm up
  times = []
  for _ in range(repeats):
    t = time.perf_counter()
    jax.block_until_ready(fn(*args))
    times.append(time.perf_counter() - t)
  return float(np.median(times))


def main() -> None:
  ap = argparse.ArgumentParser()
  ap.add_argument("--object", default="builtin:box")
  ap.add_argument("--baseline-grasps", type=int, default=20)
  ap.add_argument("--repeats", type=int, default=3)
  args = ap.parse_args()

  model = load_object_model(args.object)
  obj = baseline.NumpyObject(model)
  cfg = QualityConfig()
  key = jax.random.key(0)
  result = {"object": args.object, "num_samples": 10, "device": str(jax.devices()[0]),
            "cpu_count": os.cpu_count(), "python": platform.python_version(), "jax": jax.__version__}
  setups = {
      "parallel_jaw": (ParallelJawGripper(), parallel_jaw_perturbations(10), robust_parallel_jaw_quality,
                       sample_antipodal_grasps),
      "suction": (SuctionGripper(), suction_perturbations(10), robust_suction_quality, sample_suction_grasps),
  }
  for name, (gripper, pert, robust, sampler) in setups.items():
    grasps, valid = jax.jit(sampler, static_argnums=2)(key, model, 4096, gripper)
    fn = jax.jit(jax.vmap(lambda k, g: robust(k, model, g, gripper, pert, cfg).probability))
    entry = {}
    for n in (1000, 10000):
      batch = _tile(grasps, valid, n)
      keys = jax.random.split(jax.random.key(n), n)
      seconds = _time(fn, keys, batch, repeats=args.repeats)
      entry[f"batch_{n}_grasps_per_s"] = round(n / seconds, 1)
      if n == 1000:
        probs = np.asarray(fn(keys, batch))
    # Baseline on the first grasps of the same batch.
    rng = np.random.default_rng(0)
    m = args.baseline_grasps
    start = time.perf_counter()
    base_probs = []
    for i in range(m):
      g = jax.tree.map(lambda x: np.asarray(x, np.float64)[i], batch)
      if name == "parallel_jaw":
        base_probs.append(baseline.parallel_jaw_robust(obj, g.center, g.axis, g.approach, float(g.width), gripper,
                                                       pert, cfg, rng))
      else:
        base_probs.append(baseline.suction_robust(obj, g.center, g.approach, gripper, pert, cfg, rng))
    base_rate = m / (time.perf_counter() - start)
    entry["baseline_grasps_per_s"] = round(base_rate, 2)
    entry["baseline"] = "per grasp and sample: NumPy contacts + cvxopt QP"
    entry["batch_1000_speedup_ratio"] = round(entry["batch_1000_grasps_per_s"] / base_rate, 1)
    entry["batch_10000_speedup_ratio"] = round(entry["batch_10000_grasps_per_s"] / base_rate, 1)
    # Same grasps, independent draws: mean probabilities should be close (a sanity check, not a test).
    entry["mean_probability_dexjax"] = round(float(np.mean(probs[:m])), 3)
    entry["mean_probability_baseline"] = round(float(np.mean(base_probs)), 3)
    result[name] = entry
  print(json.dumps(result))


if __name__ == "__main__":
  main()
