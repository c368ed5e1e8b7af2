"""The notebooks run top to bottom (code cells executed in order, at a smaller batch size)."""

from __future__ import annotations

import matplotlib
import numpy as np


def test_grasp_quality_notebook_runs(cache_dir, monkeypatch, notebook_code):
  monkeypatch.setenv("DEXJAX_CACHE", str(cache_dir))
  matplotlib.use("Agg")
  src = notebook_code("grasp_quality.ipynb", {"N = 2000": "N = 64"})
  scope: dict = {}
  exec(compile(src, "grasp_quality.ipynb", "exec"), scope)
  p = scope["p_suction"]
  finite = p[~np.isnan(p)]
  assert p.shape == (64,) and finite.size > 32 and np.all((finite >= 0) & (finite <= 1))
  probs = scope["probs"]
  assert float(probs[0]) >= 0.5 and float(probs[-1]) <= 0.2  # light objects hold, past the payload they drop


def test_policy_notebook_runs(cache_dir, monkeypatch, notebook_code):
  """Every policy plans a grasp on an object of the rendered heap; the CEM keeps m + 1 rounds of samples; a noisy
  image with holes is prepared (inpainted, background-segmented) and planned on. Small CEM and candidate counts."""
  import jax
  from scipy import ndimage

  monkeypatch.setenv("DEXJAX_CACHE", str(cache_dir))
  monkeypatch.delenv("DEXJAX_MODEL", raising=False)  # the shipped models
  matplotlib.use("Agg")
  small = {"NUM_SEED = 250": "NUM_SEED = 40", "NUM_RESAMPLE = 50": "NUM_RESAMPLE = 16",
           "NUM_ITERATIONS = 3": "NUM_ITERATIONS = 1", "NUM_CANDIDATES = 400": "NUM_CANDIDATES = 48"}
  src = notebook_code("policy.ipynb", small)
  scope: dict = {}
  exec(compile(src, "policy.ipynb", "exec"), scope)

  objects = scope["objects"]
  assert objects.shape == (500, 500) and 0.01 < objects.mean() < 0.5

  def pixel(action):
    u, v = np.floor(np.asarray(action.center) + 0.5).astype(int)
    return v, u

  actions = scope["actions"]
  assert set(actions) == set(scope["POLICY_NAMES"])
  for name, action in actions.items():
    assert bool(action.valid), name
    # Grasps are centred on the mask (here the rendered objects); see the notebook's note on parallel-jaw centres.
    assert objects[pixel(action)], f"{name}: grasp centre {np.asarray(action.center)} is not on an object"
    assert np.isfinite(float(action.probability)) and 0.0 <= float(action.probability) <= 1.0, name
    assert np.all(np.isfinite(np.asarray(action.pose))), name
  ambidextrous = actions["ambidextrous"]
  per_gripper = ambidextrous.per_gripper
  assert np.all(np.asarray(per_gripper.valid))  # one CEM plan per gripper
  assert float(ambidextrous.probability) == float(np.max(per_gripper.probability))  # the argmax over grippers
  assert actions["parallel_jaw"].gripper_name == "parallel_jaw" and actions["suction"].gripper_name == "suction"

  m = scope["CEM"].num_iterations
  samples = scope["samples"]
  assert m == 1 and samples["valid"].shape == (2, m + 1, 40)  # (grippers, rounds, max(n, c))
  counts = samples["valid"].sum(axis=-1)
  assert np.all(counts[:, 0] > 0) and np.all((counts[:, 1:] > 0) & (counts[:, 1:] <= 16)), counts
  picture = scope["picture"]  # save_plan_png: one panel per round (m + 1) and the plan
  assert picture.ndim == 3 and picture.shape[1] > 2 * picture.shape[0]

  info, real_obs, real_action = scope["info"], scope["real_obs"], scope["real_action"]
  assert info["segmentation"] == "background" and info["invalid_fraction"] > 0.04
  depth, mask = np.asarray(real_obs.depth), np.asarray(real_obs.mask)
  assert np.all(np.isfinite(depth) & (depth > 0))  # holes inpainted
  assert not np.any(mask & (scope["noisy"] <= 0))  # no grasp centred on a hole
  assert (mask & objects).sum() > 0.9 * mask.sum() and (mask & objects).sum() > 0.5 * objects.sum()
  assert bool(real_action.valid) and mask[pixel(real_action)]
  assert ndimage.binary_dilation(objects, iterations=2)[pixel(real_action)]
  assert jax.tree.structure(real_obs) == jax.tree.structure(scope["obs"])


def test_analysis_notebook_runs(cache_dir, monkeypatch, notebook_code):
  """Fig. S1 on the shipped models: filters, top-activating crops and a t-SNE per layer for both grippers, and the
  notebook's verdict on the seed's finding. Few images and examples."""
  monkeypatch.setenv("DEXJAX_CACHE", str(cache_dir))
  matplotlib.use("Agg")
  small = {"NUM_IMAGES = 48": "NUM_IMAGES = 16", "NUM_TSNE = 1000": "NUM_TSNE = 150", "TOP_K = 8": "TOP_K = 3"}
  src = notebook_code("analysis.ipynb", small)
  shown = []
  scope: dict = {"display": shown.append}
  exec(compile(src, "analysis.ipynb", "exec"), scope)
  assert len(shown) == 6  # (A), (B), (C) for each gripper
  assert all(isinstance(fig, matplotlib.figure.Figure) for fig in shown)
  layers, names = scope["layers"], scope["names"]
  assert set(layers) == {"parallel_jaw", "suction"}
  for gripper, result in layers.items():
    assert list(result) == list(names)
    assert all(0.0 <= r["separation"] <= 1.0 and r["embedding"].shape == (150, 2) for r in result.values())
    assert result["output"]["separation"] > 0.6, gripper  # the logits separate what the network predicts well
  assert set(scope["verdict"]) == {"parallel_jaw", "suction"}


def test_benchmark_notebook_runs(cache_dir, monkeypatch, notebook_code):
  """A tiny benchmark: both judges on every attempt, the table, the figures and the judges' confusion counts."""
  monkeypatch.setenv("DEXJAX_CACHE", str(cache_dir))
  matplotlib.use("Agg")
  small = {"PER_TRIAL = 6": "PER_TRIAL = 2", "TRIALS = 2": "TRIALS = 1", "MAX_ATTEMPTS = 12": "MAX_ATTEMPTS = 3",
           'POLICIES = ["ambidextrous", "suction_heuristic", "random"]': 'POLICIES = ["ambidextrous", "random"]'}
  src = notebook_code("benchmark.ipynb", small)
  scope: dict = {}
  exec(compile(src, "benchmark.ipynb", "exec"), scope)
  results, records = scope["results"], scope["records"]
  assert set(results["policies"]) == {"ambidextrous", "random"}
  assert sum(scope["confusion"].values()) == len(records) == sum(e["attempts"] for e in results["policies"].values())
  assert set(scope["figures"]) == {"reliability.png", "per_object.png", "difficulty.png"}
  assert all(r["verdicts"].keys() == {"analytic", "physics"} for r in records)
