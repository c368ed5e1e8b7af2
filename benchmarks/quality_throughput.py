"""Robust grasp-quality throughput (M = 10) for both grippers, dexjax vs. the original's way, one JSON object.

  python benchmarks/quality_throughput.py [--object builtin:box] [--baseline-grasps 50] [--repeats 3]
                                          [--solver-batch 10000]

dexjax: one ``jax.jit(jax.vmap(robust_*_quality))`` call per batch of 1,000 and 10,000 grasps (median of
``--repeats`` timed calls after compilation; the timed calls alternate with the baselines' repeats).

Baselines, measured in the same run on the first ``--baseline-grasps`` grasps of the same batch
(`_numpy_baseline.py`): per grasp and per Monte-Carlo sample, NumPy contact finding on the same distance grid
(Dex-Net's way: one grasp, one sample, one solve at a time), then one wrench-resistance solve per sample with

* ``cvxopt`` -- Dex-Net's own solver and settings: a cvxopt QP per problem, progress output silenced and
  cvxopt's default tolerances (abstol 1e-7, reltol 1e-6, feastol 1e-7), exactly as Dex-Net's
  ``quality.py`` configures it (nothing tightened);
* ``nnls`` -- a stronger plain baseline: the same problem lifted to a non-negative least-squares problem as
  dexjax poses it (``lift_bounded_groups``: one slack per force-limit group) and solved by
  ``scipy.optimize.nnls`` (compiled Lawson--Hanson, float64), one problem at a time.

Both baselines run on the same random draws (a NumPy generator seeded per repeat), interleaved repeat by
repeat; ``baseline_*_grasps_per_s`` is the median over ``--repeats``. Keys ending in ``_ratio`` are the median
over repeats of dexjax grasps/s divided by a baseline's grasps/s in the same repeat (``*_over_cvxopt_ratio``,
``*_over_nnls_ratio``). ``mean_probability_*``
is a cross-check of the three implementations (dexjax has its own random draws, so expect Monte-Carlo
noise; the two baselines share theirs, so they differ only where their solvers decide differently).

``solver_only``: the wrench problems the baselines solved in their first repeat, solved again by each solver
alone: cvxopt with its defaults (``cvxopt_default``), cvxopt with tightened tolerances 1e-10
(``cvxopt_tight``, an accuracy reference only, not a baseline), ``scipy.optimize.nnls`` per problem in a
Python loop, and dexjax's ``jax.jit(jax.vmap(nnls))`` on the lifted float32 systems tiled to
``--solver-batch`` problems. Reported: problems/s (median of ``--repeats``), each solver's decision
(residual <= ``QualityConfig.tolerance``, 1 mN) agreement with ``scipy.optimize.nnls`` in float64, and the
largest residual difference. This isolates the solver from the contact work. The self-check that the lifted
NNLS equals the cvxopt QP is ``solver_only.<gripper>.max_abs_residual_diff_cvxopt_tight_vs_nnls``.

``two_cpu_devices`` (skip with ``--no-devices``): the same dexjax function on the same batches, split over two
CPU devices (a child process started with ``XLA_FLAGS=--xla_force_host_platform_device_count=2``; the batch is
split by `dexjax.quality.split_over_devices`, as `dexjax.quality.evaluate_grasps` does with several devices):
grasps/s at batch 1,000 and 10,000 (median of ``--repeats``), and whether the probabilities equal the one-device
run's bit for bit.

Without cvxopt, dexjax, the ``nnls`` baseline and the solvers other than cvxopt are measured all the same; the
cvxopt figures and every ratio against them are null, and ``baseline_missing.cvxopt`` says why.

The machine is shared and noisy: compare ratios measured in the same run, not absolute figures.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import time

import jax
import numpy as np
import scipy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from _machine import describe  # noqa: E402
from _optional import version  # noqa: E402

import _numpy_baseline as baseline  # noqa: E402

from dexjax.grippers import ParallelJawGripper, SuctionGripper  # noqa: E402
from dexjax.objects import load_object_model  # noqa: E402
from dexjax.quality import (QualityConfig, nnls, parallel_jaw_perturbations, robust_parallel_jaw_quality,  # noqa: E402
                            robust_suction_quality, split_over_devices, suction_perturbations)
from dexjax.sampling import sample_antipodal_grasps, sample_suction_grasps  # noqa: E402

_TIGHT = {"abstol": 1e-10, "reltol": 1e-10, "feastol": 1e-10}


def _tile(grasps, valid, n):
  idx = np.flatnonzero(np.asarray(valid))
  idx = np.resize(idx, n)
  return jax.tree.map(lambda x: np.asarray(x)[idx], grasps)


def _baseline_pass(name, obj, batch, m, gripper, pert, cfg, solver, seed, problems=None):
  """(seconds, probabilities (m,)) of the baseline on the first ``m`` grasps of ``batch``."""
  rng = np.random.default_rng(seed)
  probs = []
  start = time.perf_counter()
  for i in range(m):
    g = jax.tree.map(lambda x: np.asarray(x, np.float64)[i], batch)
    if name == "parallel_jaw":
      probs.append(baseline.parallel_jaw_robust(obj, g.center, g.axis, g.approach, float(g.width), gripper, pert,
                                                cfg, rng, solver=solver, problems=problems))
    else:
      probs.append(baseline.suction_robust(obj, g.center, g.approach, gripper, pert, cfg, rng, solver=solver,
                                           problems=problems))
  return time.perf_counter() - start, np.array(probs)


def _solve_all(problems, solver):
  """(seconds, residuals) of solving every problem one at a time with ``solver``."""
  start = time.perf_counter()
  res = np.array([p.residual(solver) for p in problems])
  return time.perf_counter() - start, res


def solver_only(problems, repeats: int, batch: int, tol: float) -> dict:
  """Problems/s and decision agreement of the solvers alone on the baselines' wrench problems."""
  if not problems:
    return {"problems": 0}
  a = np.stack([p.a for p in problems]).astype(np.float32)
  b = np.stack([p.b for p in problems]).astype(np.float32)
  idx = np.resize(np.arange(len(problems)), batch)
  fn = jax.jit(jax.vmap(lambda aa, bb: nnls(aa, bb).residual))
  with_cvxopt = baseline.cvxopt is not None
  rates = {"cvxopt_default": [], "cvxopt_tight": [], "scipy_nnls": [], "dexjax_nnls_batched": []}
  residuals = {}
  a_batch, b_batch = a[idx], b[idx]
  jax.block_until_ready(fn(a_batch, b_batch))  # compile
  for _ in range(repeats):
    t = time.perf_counter()
    jax.block_until_ready(fn(a_batch, b_batch))
    rates["dexjax_nnls_batched"].append(batch / (time.perf_counter() - t))
    if with_cvxopt:
      _time_cvxopt(problems, rates, residuals)
    seconds, residuals["scipy_nnls"] = _solve_all(problems, "nnls")
    rates["scipy_nnls"].append(len(problems) / seconds)
  residuals["dexjax_nnls_batched"] = np.asarray(fn(a, b), np.float64)
  ref = residuals["scipy_nnls"] <= tol
  out = {"problems": len(problems), "shape": list(problems[0].a.shape), "dexjax_batch": batch,
         "positive_fraction_scipy_nnls": round(float(ref.mean()), 4)}
  for key, r in rates.items():
    out[f"{key}_problems_per_s"] = round(float(np.median(r)), 1) if r else None
  for key in rates:
    r = residuals.get(key)
    if key != "scipy_nnls":  # None: cvxopt missing
      agreement = None if r is None else round(float(np.mean((r <= tol) == ref)), 4)
      out[f"decision_agreement_{key}_vs_scipy_nnls"] = agreement
      difference = None if r is None else float(np.max(np.abs(r - residuals["scipy_nnls"])))
      out[f"max_abs_residual_diff_{key}_vs_nnls"] = difference
  for key in ("scipy_nnls", "cvxopt_default"):
    out[f"dexjax_batched_over_{key}_ratio"] = _median_ratio(rates["dexjax_nnls_batched"], rates[key], 2)
  return out


def _time_cvxopt(problems, rates: dict, residuals: dict) -> None:
  """One repeat of cvxopt alone on ``problems``, with its default and with tightened tolerances."""
  cvxopt = baseline.cvxopt
  defaults = dict(cvxopt.solvers.options)
  seconds, residuals["cvxopt_default"] = _solve_all(problems, "cvxopt")
  rates["cvxopt_default"].append(len(problems) / seconds)
  cvxopt.solvers.options.update(_TIGHT)
  try:
    seconds, residuals["cvxopt_tight"] = _solve_all(problems, "cvxopt")
  finally:
    cvxopt.solvers.options.clear()
    cvxopt.solvers.options.update(defaults)
  rates["cvxopt_tight"].append(len(problems) / seconds)


def _median_ratio(numerator: list, denominator: list, digits: int) -> float | None:
  """Median of the per-repeat ratios, or None when the denominator was not measured (a missing baseline)."""
  if not denominator:
    return None
  return round(float(np.median(np.array(numerator) / np.array(denominator))), digits)


def _setups():
  return {
      "parallel_jaw": (ParallelJawGripper(), parallel_jaw_perturbations(10), robust_parallel_jaw_quality,
                       sample_antipodal_grasps),
      "suction": (SuctionGripper(), suction_perturbations(10), robust_suction_quality, sample_suction_grasps),
  }


def _dexjax_inputs(model, gripper, sampler):
  """The benchmark's batches of 1,000 and 10,000 grasps: (keys, grasps) per size."""
  grasps, valid = jax.jit(sampler, static_argnums=2)(jax.random.key(0), model, 4096, gripper)
  return {n: (jax.random.split(jax.random.key(n), n), _tile(grasps, valid, n)) for n in (1000, 10000)}


def _digest(probabilities) -> str:
  return hashlib.sha256(np.asarray(probabilities, np.float32).tobytes()).hexdigest()[:16]


def devices_child(object_name: str, repeats: int) -> None:
  """Child process with several CPU devices: grasps/s of the batch split over them, and result digests."""
  model, cfg = load_object_model(object_name), QualityConfig()
  out = {"devices": len(jax.local_devices())}
  for name, (gripper, pert, robust, sampler) in _setups().items():
    fn = jax.jit(split_over_devices(jax.vmap(lambda k, g: robust(k, model, g, gripper, pert, cfg).probability)))
    entry = {}
    for n, inp in _dexjax_inputs(model, gripper, sampler).items():
      entry[f"digest_{n}"] = _digest(jax.block_until_ready(fn(*inp)))
      rates = []
      for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*inp))
        rates.append(n / (time.perf_counter() - t))
      entry[f"batch_{n}_grasps_per_s"] = round(float(np.median(rates)), 1)
    out[name] = entry
  print(json.dumps(out))


def _run_devices_child(object_name: str, repeats: int, devices: int = 2) -> dict:
  env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}", JAX_PLATFORMS="cpu")
  cmd = [sys.executable, os.path.abspath(__file__), "--devices-child", "--object", object_name,
         "--repeats", str(repeats)]
  done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
  return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
  ap = argparse.ArgumentParser()
  ap.add_argument("--object", default="builtin:box")
  ap.add_argument("--baseline-grasps", type=int, default=50)
  ap.add_argument("--repeats", type=int, default=3)
  ap.add_argument("--solver-batch", type=int, default=10000)
  ap.add_argument("--no-devices", action="store_true", help="skip the two-CPU-device measurement")
  ap.add_argument("--devices-child", action="store_true", help=argparse.SUPPRESS)
  args = ap.parse_args()
  if args.devices_child:
    devices_child(args.object, args.repeats)
    return

  model = load_object_model(args.object)
  obj = baseline.NumpyObject(model)
  cfg = QualityConfig()
  result = {"object": args.object, "num_samples": 10, "baseline_grasps": args.baseline_grasps,
            "repeats": args.repeats, "machine": describe(), "cvxopt": version("cvxopt"),
            "scipy": scipy.__version__,
            "baselines": {
                "cvxopt": "per grasp and sample: NumPy contacts + cvxopt QP, cvxopt default tolerances, progress "
                          "silenced (Dex-Net's settings)",
                "nnls": "per grasp and sample: NumPy contacts + the lifted NNLS by scipy.optimize.nnls"}}
  if baseline.CVXOPT_MISSING:
    result["baseline_missing"] = {"cvxopt": baseline.CVXOPT_MISSING}
  solvers = baseline.available_solvers()
  digests = {}
  for name, (gripper, pert, robust, sampler) in _setups().items():
    fn = jax.jit(jax.vmap(lambda k, g: robust(k, model, g, gripper, pert, cfg).probability))
    inputs = _dexjax_inputs(model, gripper, sampler)
    probs = np.asarray(jax.block_until_ready(fn(*inputs[1000])))  # compiles batch 1,000
    digests[name] = {n: _digest(probs if n == 1000 else jax.block_until_ready(fn(*inputs[n]))) for n in inputs}
    batch = inputs[1000][1]
    # Repeats interleave dexjax's timed calls with both baselines on the first grasps of the same batch (the
    # same draws for both baselines per repeat), so each repeat's ratios share the machine's load.
    m = args.baseline_grasps
    rates = {1000: [], 10000: [], "cvxopt": [], "nnls": []}
    base_probs = {"cvxopt": [], "nnls": []}
    problems = []
    for rep in range(args.repeats):
      for n in (1000, 10000):
        t = time.perf_counter()
        jax.block_until_ready(fn(*inputs[n]))
        rates[n].append(n / (time.perf_counter() - t))
      for solver in solvers:
        seconds, p = _baseline_pass(name, obj, batch, m, gripper, pert, cfg, solver, seed=rep,
                                    problems=problems if rep == 0 and solver == "nnls" else None)
        rates[solver].append(m / seconds)
        base_probs[solver].append(p)
    entry = {f"batch_{n}_grasps_per_s": round(float(np.median(rates[n])), 1) for n in (1000, 10000)}
    for solver in ("cvxopt", "nnls"):
      entry[f"baseline_{solver}_grasps_per_s"] = round(float(np.median(rates[solver])), 2) if rates[solver] else None
      for n in (1000, 10000):
        entry[f"batch_{n}_over_{solver}_ratio"] = _median_ratio(rates[n], rates[solver], 1)
    entry["nnls_over_cvxopt_ratio"] = _median_ratio(rates["nnls"], rates["cvxopt"], 2)
    # Same grasps: dexjax with its own draws, the baselines with theirs (shared between the two).
    entry["mean_probability_dexjax"] = round(float(np.mean(probs[:m])), 3)
    for solver in ("cvxopt", "nnls"):
      entry[f"mean_probability_baseline_{solver}"] = (round(float(np.mean(base_probs[solver])), 3)
                                                      if base_probs[solver] else None)
    entry["grasp_probability_max_abs_diff_cvxopt_vs_nnls"] = round(
        float(np.max(np.abs(np.concatenate(base_probs["cvxopt"]) - np.concatenate(base_probs["nnls"])))), 3
    ) if base_probs["cvxopt"] else None
    entry["solver_only"] = solver_only(problems, args.repeats, args.solver_batch, cfg.tolerance)
    result[name] = entry
  if not args.no_devices:
    child = _run_devices_child(args.object, args.repeats)
    for name in digests:
      two = child[name]
      result[name]["two_cpu_devices"] = {
          **{f"batch_{n}_grasps_per_s": two[f"batch_{n}_grasps_per_s"] for n in (1000, 10000)},
          **{f"batch_{n}_over_one_device_ratio": round(two[f"batch_{n}_grasps_per_s"]
                                                        / result[name][f"batch_{n}_grasps_per_s"], 2)
             for n in (1000, 10000)},
          "same_probabilities_as_one_device": all(two[f"digest_{n}"] == digests[name][n] for n in (1000, 10000))}
  print(json.dumps(result))


if __name__ == "__main__":
  main()
