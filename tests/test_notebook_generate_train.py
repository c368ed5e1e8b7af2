"""``notebooks/generate_train.ipynb`` in a real Jupyter kernel: a tiny dataset (8 images of 3 objects), one epoch of a
tiny GQ-CNN per gripper, and 4 images of 3 unseen objects to evaluate on."""

from __future__ import annotations

import os

import numpy as np
import pytest

from dexjax.quality import REWARD_FAILURES

IMAGES, ACTIONS, EVAL_IMAGES, BATCH = 8, 50, 4, 32
SMALL = {"OBJECTS": ["procedural:L1/0:3"], "NUM_IMAGES": IMAGES, "IMAGES_PER_SHARD": 4, "ACTIONS_PER_GRIPPER": ACTIONS,
         "EVAL_OBJECTS": ["procedural:L1/0:3@31"], "EVAL_IMAGES": EVAL_IMAGES, "EPOCHS": 1, "BATCH_SIZE": BATCH,
         "CONV_FILTERS": [8, 8, 8], "FC_SIZE": 16, "NUM_SHOWN": 64}
GRIPPERS = ("parallel_jaw", "suction")
VALUES = {
    "workdir": "workdir",
    "summary": "summary",
    "eval_summary": "eval_summary",
    "rows_per_image": "rows_per_image",
    "stats": "stats",
    "rows": "{k: rows[k] for k in ('gripper', 'reward', 'robust_probability', 'failure')}",
    "label_agreement": "label_agreement",
    "train_stats": "json.load(open(os.path.join(run_dir, 'stats.json')))",
    "records": "read_records(run_dir)",
    "result": "result",
    "run_files": "sorted(os.listdir(run_dir))",
    "saved": "{g: {d: sorted(os.listdir(os.path.join(run_dir, g, d))) for d in ('best', 'checkpoints')} "
             "for g in GRIPPER_NAMES}",
    "metrics": "{f'{name}/{gripper}': m for (name, gripper), m in metrics.items()}",
    "same_as_evaluate": "same_as_evaluate",
    "suction_predictions": "predict_all(load(run_dir, gripper='suction'), eval_dir)",
    "shown": "{f'{name}/{gripper}': p for (name, gripper), p in shown.items()}",
}


def _balanced_accuracy(scores, labels):
  predicted, labels = scores > 0.5, labels == 1
  rates = [np.mean(predicted[labels])] if labels.any() else []
  rates += [np.mean(~predicted[~labels])] if (~labels).any() else []
  return float(np.mean(rates))


@pytest.mark.slow  # compiles the labeller (~40 s) and builds 6 objects' caches
def test_generate_train_notebook(run_notebook, tmp_path, monkeypatch):
  """Rows = images x actions per gripper; labels are the thresholded robust probability; one epoch per gripper with
  its checkpoint and best model; metrics in [0, 1]; the loaded model's predictions reproduce evaluate_model's
  metrics; the four figures are drawn; files only under the notebook's temporary directory."""
  temp = tmp_path / "tmp"  # the kernel's tempfile.mkdtemp() directories: pytest removes them, even after a failure
  temp.mkdir()
  monkeypatch.setenv("TMPDIR", str(temp))
  run = run_notebook("generate_train.ipynb", SMALL, VALUES)
  v = run.values
  workdir = v["workdir"]
  assert os.path.dirname(workdir) == str(temp)
  assert sorted(os.listdir(tmp_path)) == ["generate_train.ipynb", "tmp", "values.pkl"]  # nothing in the working dir

  # Generation: 2 shards of 4 images, ACTIONS rows per gripper and image, the preview written.
  summary = v["summary"]
  assert summary["shards"]["written"] == 2 and not summary["shards"]["failed"]
  assert summary["images"] == IMAGES and summary["rows"] == IMAGES * 2 * ACTIONS
  assert all(summary["grippers"][g]["rows"] == IMAGES * ACTIONS for g in GRIPPERS)
  assert summary["preview"].startswith(workdir) and os.path.getsize(summary["preview"]) > 10_000
  assert v["rows_per_image"].shape == (IMAGES, 2) and np.all(v["rows_per_image"] == ACTIONS)
  stats = v["stats"]  # summarize_rows of the shards read back equals the run's own count
  for g in GRIPPERS:
    assert stats["grippers"][g]["rows"] == summary["grippers"][g]["rows"]
    assert stats["grippers"][g]["positives"] == summary["grippers"][g]["positives"] > 0

  # Labels: 0/1; 1 exactly when nothing failed; where the robust test decided, p > 0.5.
  rows = v["rows"]
  reward, p, failure = rows["reward"], rows["robust_probability"], rows["failure"]
  assert set(np.unique(reward)) == {0, 1}
  np.testing.assert_array_equal(reward == 1, failure == REWARD_FAILURES.index("none"))
  decided = np.isin(failure, [REWARD_FAILURES.index("none"), REWARD_FAILURES.index("not_robust")])
  np.testing.assert_array_equal(reward[decided] == 1, p[decided] > 0.5)
  assert np.all((p >= 0) & (p <= 1)) and v["label_agreement"] == 1.0

  # Training: one epoch per gripper, every row in the training or the validation split, whole batches only.
  assert {"config.yaml", "stats.json", "metrics.jsonl", "curves.png", "summary.json", *GRIPPERS} <= set(v["run_files"])
  records = v["records"]
  assert sorted((r["gripper"], r["epoch"]) for r in records) == [(g, 1) for g in GRIPPERS]
  for r in records:
    g, train_rows = r["gripper"], v["train_stats"][r["gripper"]]["train_rows"]
    assert train_rows + r["val_examples"] == IMAGES * ACTIONS
    assert r["step"] == train_rows // BATCH
    assert v["saved"][g] == {"best": [str(r["step"])], "checkpoints": [str(r["step"])]}
    assert v["result"]["grippers"][g]["epoch"] == 1
    for key in ("val_accuracy", "val_balanced_accuracy", "val_average_precision"):
      assert r[key] is None or 0.0 <= r[key] <= 1.0, (g, key, r[key])
    assert np.isfinite(r["train_loss"]) and np.isfinite(r["val_loss"])

  # Evaluation on the unseen set: every row of each gripper, metrics in [0, 1], for this run and the shipped models.
  eval_summary = v["eval_summary"]
  assert eval_summary["rows"] == EVAL_IMAGES * 2 * ACTIONS
  for key, m in v["metrics"].items():
    g = key.split("/")[1]
    counts = eval_summary["grippers"][g]
    assert (m["examples"], m["positives"]) == (counts["rows"], counts["positives"]), key
    for name in ("accuracy", "balanced_accuracy", "average_precision"):
      assert m[name] is None or 0.0 <= m[name] <= 1.0, (key, name)
  for g in GRIPPERS:  # crops in the wrong frame or scale would put the shipped models at chance
    assert v["metrics"][f"shipped/{g}"]["balanced_accuracy"] > 0.6, g

  # The loaded model as a quality function: its predictions are what evaluate_model scored.
  assert v["same_as_evaluate"] == {g: True for g in GRIPPERS}
  scores, labels = v["suction_predictions"]
  suction = v["metrics"]["this run/suction"]
  assert scores.shape == labels.shape == (EVAL_IMAGES * ACTIONS,) and np.all((scores >= 0) & (scores <= 1))
  assert int(labels.sum()) == suction["positives"]
  assert abs(_balanced_accuracy(scores, labels) - suction["balanced_accuracy"]) < 1e-9
  for key, p in v["shown"].items():
    assert p.shape == (SMALL["NUM_SHOWN"],) and np.all((p >= 0) & (p <= 1)), key
  assert not np.allclose(v["shown"]["this run/suction"], v["shown"]["shipped/suction"])

  assert run.images() == 4  # preview, network inputs, learning curves, prediction histograms
  assert "metrics equal evaluate_model's: True" in run.stdout()
