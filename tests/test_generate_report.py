"""Generation reports: row summaries (one-shot, accumulated, merged, as text) and the shard picture."""

from __future__ import annotations

import json

import matplotlib.image
import numpy as np
import pytest
import scipy.ndimage

from dexjax.data import read_shard, write_shard
from dexjax.generate.report import (RowStats, format_summary, generation_png_size, merge_summaries,
                                    grasp_crops, save_generation_png, select_crop_rows, summarize_rows)

H, W, FX = 120, 160, 200.0


def _rows(gripper, reward, policy, failure, probability, image_index=None, center=None, angle=None):
  m = len(gripper)
  return {
    "gripper": np.asarray(gripper, np.int8),
    "center": np.asarray(center if center is not None else np.full((m, 2), 40.0), np.float32),
    "angle": np.asarray(angle if angle is not None else np.zeros(m), np.float32),
    "grasp_depth": np.full(m, 0.7, np.float32),
    "approach_angle": np.full(m, 0.2, np.float32),
    "grasp_pose": np.broadcast_to(np.eye(4, dtype=np.float32), (m, 4, 4)).copy(),
    "reward": np.asarray(reward, np.int8),
    "robust_probability": np.asarray(probability, np.float32),
    "failure": np.asarray(failure, np.int8),
    "target_slot": np.zeros(m, np.int8),
    "policy": np.asarray(policy, np.int8),
    "image_index": np.asarray(image_index if image_index is not None else np.zeros(m), np.int32),
  }


# 6 rows: 4 parallel jaw (2 positive, 1 supervisor), 2 suction (1 positive, 1 supervisor and positive).
SMALL = _rows(gripper=[0, 0, 0, 0, 1, 1], reward=[1, 0, 1, 0, 1, 0], policy=[0, 0, 1, 0, 1, 0],
              failure=[0, 1, 0, 5, 0, 3], probability=[0.9, 0.1, 0.8, 0.4, 0.7, 0.0])


def test_summary_counts_match_hand_computed_example():
  summary = summarize_rows(SMALL, seconds=2.0)
  json.dumps(summary, allow_nan=False)  # plain JSON
  assert (summary["rows"], summary["positives"]) == (6, 3)
  assert summary["positive_rate"] == pytest.approx(0.5)
  assert summary["rows_per_s"] == pytest.approx(3.0)
  jaw, suction = summary["grippers"]["parallel_jaw"], summary["grippers"]["suction"]
  assert (jaw["rows"], jaw["positives"], jaw["supervisor_rows"], jaw["supervisor_positives"]) == (4, 2, 1, 1)
  assert jaw["positive_rate"] == pytest.approx(0.5)
  assert jaw["mean_robust_probability"] == pytest.approx((0.9 + 0.1 + 0.8 + 0.4) / 4)
  assert jaw["failures"] == {"none": 2, "collision_object": 1, "collision_bin": 0, "no_object": 0,
                             "multiple_objects": 0, "not_robust": 1}
  assert (suction["rows"], suction["positives"], suction["supervisor_rows"]) == (2, 1, 1)
  assert suction["mean_robust_probability"] == pytest.approx(0.35)
  assert suction["failures"]["no_object"] == 1 and suction["failures"]["none"] == 1


def test_summary_of_no_rows_and_bad_codes():
  empty = summarize_rows({k: v[:0] for k, v in SMALL.items()})
  assert empty["rows"] == 0 and empty["positive_rate"] is None
  assert empty["grippers"]["suction"]["mean_robust_probability"] is None
  bad = dict(SMALL, failure=np.array([0, 1, 0, 9, 0, 3], np.int8))
  with pytest.raises(ValueError, match="'failure'"):
    summarize_rows(bad)


def test_accumulator_and_merge_equal_summary_of_concatenation():
  rng = np.random.default_rng(0)
  m = 50
  more = _rows(gripper=rng.integers(0, 2, m), reward=rng.integers(0, 2, m), policy=rng.integers(0, 2, m),
               failure=rng.integers(0, 6, m), probability=rng.uniform(size=m))
  both = {k: np.concatenate([SMALL[k], more[k]]) for k in SMALL}
  expected = summarize_rows(both)
  accumulated = RowStats().add(SMALL).add(more).to_dict()
  merged = merge_summaries(summarize_rows(SMALL), summarize_rows(more))
  for got in (accumulated, merged):
    assert got["rows"] == expected["rows"] == 56 and got["positives"] == expected["positives"]
    for name, entry in expected["grippers"].items():
      for key, value in entry.items():
        assert got["grippers"][name][key] == (pytest.approx(value) if isinstance(value, float) else value)
  text = format_summary(RowStats().add(both).to_dict(seconds=4.0))
  assert "parallel_jaw" in text and "failure: not_robust" in text and "56 rows in 4.0 s (14.00 rows/s)" in text


def _shard(tmp_path, rows, num_images=1):
  depth = np.full((num_images, H, W), 0.7, np.float32)
  depth[:, 31:50, 91:110] = 0.6  # a raised 19 x 19 square centred on pixel (u, v) = (100, 40)
  images = {
    "depth": depth,
    "mask": np.full((num_images, H, W), -1, np.int32),
    "camera_intrinsics": np.tile(np.array([FX, FX, W / 2, H / 2], np.float32), (num_images, 1)),
    "camera_rotation": np.broadcast_to(np.eye(3, dtype=np.float32), (num_images, 3, 3)).copy(),
    "camera_translation": np.zeros((num_images, 3), np.float32),
    "heap_id": np.arange(num_images, dtype=np.int64),
    "object_ids": np.zeros((num_images, 1), np.int32),
    "object_poses": np.zeros((num_images, 1, 7), np.float32),
    "object_names": np.full((num_images, 1), "box"), "object_friction": np.full((num_images, 1), 0.8, np.float32),
    "object_mass": np.full((num_images, 1), 0.2, np.float32),
  }
  path = tmp_path / "shard-000000.npz"
  write_shard(path, images, rows, {"config_fingerprint": "f", "seed": 0, "index": 0})
  return read_shard(path)


def test_png_size_grasps_drawn_and_no_rows(tmp_path):
  centers = [[100, 40], [30, 80], [60, 60], [120, 90], [100, 40], [20, 20]]
  rows = dict(SMALL, center=np.asarray(centers, np.float32), image_index=np.array([0, 0, 0, 0, 0, 1], np.int32))
  shard = _shard(tmp_path, rows, num_images=2)
  no_grasps = _shard(tmp_path / "empty", {k: v[:0] for k, v in rows.items()}, num_images=2)
  with_png, without_png = tmp_path / "with.png", tmp_path / "without.png"
  shown = save_generation_png(with_png, shard, 0, num_crops=4, crop_size=32)
  assert len(shown) == 4 and set(rows["image_index"][shown]) == {0}
  assert len(select_crop_rows(rows, 0, 4)) == 4
  assert len(save_generation_png(without_png, no_grasps, 0, num_crops=4, crop_size=32)) == 0
  a, b = matplotlib.image.imread(with_png), matplotlib.image.imread(without_png)
  assert with_png.stat().st_size > 1000
  assert a.shape[:2] == b.shape[:2] == generation_png_size((H, W), 4)
  assert generation_png_size((H, W), 4)[1] > generation_png_size((H, W), 0)[1] > 100
  # Only the grasp overlays and the titles differ; green (reward 1) pixels exist only where grasps are drawn.
  assert np.abs(a - b).max() > 0.5
  green = lambda img: ((img[..., 1] > 0.6) & (img[..., 0] < 0.4) & (img[..., 2] < 0.5)).sum()
  assert green(a) > 20 and green(b) == 0
  with pytest.raises(IndexError, match=r"shard-000000\.npz.*'image_index'.*\[0, 2\).*got 2"):
    save_generation_png(tmp_path / "bad.png", shard, 2)


def test_crop_choice_is_mixed_and_deterministic():
  # Rows on image 0: jaw positives 0, 2 (2 supervisor), jaw negatives 1, 3, suction positive 4, negative 5.
  chosen = select_crop_rows(SMALL, 0, 5)
  assert list(chosen) == [2, 4, 1, 5, 0]  # jaw 1 (supervisor first), suction 1, jaw 0, suction 0, then again
  assert list(select_crop_rows(SMALL, 0, 100)) == [2, 4, 1, 5, 0, 3]
  assert len(select_crop_rows(SMALL, 1, 4)) == 0


def test_crops_are_centred_on_the_grasp(tmp_path):
  shard = _shard(tmp_path, SMALL)
  depth = shard.images["depth"][0]
  centers = np.array([[100.0, 40.0], [100.0, 40.0], [30.0, 80.0]], np.float32)
  crops = grasp_crops(depth, centers, np.array([0.0, 0.7, 0.0], np.float32), crop_size=48)
  assert crops.shape == (3, 48, 48)
  for crop in crops[:2]:  # the square, axis-aligned and rotated, centred on crop_size // 2
    raised = np.argwhere(crop < 0.65)
    assert 320 < len(raised) < 400
    assert np.allclose(raised.mean(axis=0), [24, 24], atol=0.5)
  assert not (crops[2] < 0.65).any()  # a grasp away from the square does not see it
  # In the figure the crop of a row at (100, 40) shows the square (black) around the jaw marker (green).
  rows = dict(SMALL, center=np.tile(np.array([100.0, 40.0], np.float32), (6, 1)))
  png = tmp_path / "centred.png"
  save_generation_png(png, _shard(tmp_path / "centred", rows), 0, num_crops=1, crop_size=48)
  right = matplotlib.image.imread(png)[:, generation_png_size((H, W), 0)[1]:, :3]
  labels, _ = scipy.ndimage.label(right.max(axis=-1) < 0.05)
  black = np.argwhere(labels == np.argmax(np.bincount(labels.ravel())[1:]) + 1)  # the largest black blob
  green = np.argwhere((right[..., 1] > 0.6) & (right[..., 0] < 0.4) & (right[..., 2] < 0.5))
  assert len(black) > 500 and len(green) > 10
  box_centre = (black.min(axis=0) + black.max(axis=0)) / 2
  pixel = (black.max(axis=0) - black.min(axis=0)).mean() / 19  # figure pixels per crop pixel
  assert np.allclose(green.mean(axis=0), box_centre, atol=0.5 * pixel)
