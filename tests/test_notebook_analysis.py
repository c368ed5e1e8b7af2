"""``notebooks/analysis.ipynb`` (Fig. S1 on the shipped models) in a real Jupyter kernel, few images and examples."""

from __future__ import annotations


def test_analysis_notebook(run_notebook):
  """Filters, top-activating crops and a t-SNE per layer for both grippers, and the notebook's verdict on the seed's
  finding."""
  one_per_level = ["procedural:L1/0:1@21", "procedural:L2/0:1@21", "procedural:L3/0:1@21"]
  small = {"OBJECTS": one_per_level, "NUM_IMAGES": 16, "NUM_TSNE": 150, "TOP_K": 3}
  values = {"layers": "layers", "names": "list(names)", "verdict": "verdict"}
  run = run_notebook("analysis.ipynb", small, values)
  assert run.images() == 6  # (A), (B), (C) for each gripper
  layers, names = run.values["layers"], run.values["names"]
  assert set(layers) == {"parallel_jaw", "suction"}
  for gripper, result in layers.items():
    assert list(result) == names
    assert all(0.0 <= r["separation"] <= 1.0 and r["embedding"].shape == (150, 2) for r in result.values())
    assert result["output"]["separation"] > 0.6, gripper  # the logits separate what the network predicts well
  assert set(run.values["verdict"]) == {"parallel_jaw", "suction"}
