"""Shards (atomic, deterministic, resumable) and the streaming loader (complete epochs, leak-free splits)."""

from __future__ import annotations

import os
import re
import zipfile

import numpy as np
import pytest

from dexjax.data import loader, shards
from dexjax.data import (ConfigMismatchError, ShardError, config_fingerprint, file_sha256, finish_shard,
                         iterate_rows, load_manifest, open_manifest, parse_shard_assignment, pending_shards,
                         read_shard, row_groups, shard_path, shard_seed, shard_seed_sequence, split_images, write_shard)

CONFIG = {"images_per_shard": 4, "rows_per_image": 5, "size": [6, 7]}
FP = config_fingerprint(CONFIG)
SEED = 7


def _content(seed: int, index: int, num_images: int = 4, rows_per_image: int = 5, size=(6, 7), slots: int = 3):
  """A fake shard whose content is a function of (seed, index): two images per heap, 12 objects in all."""
  rng = np.random.default_rng(shard_seed_sequence(seed, index))
  n, m = num_images, num_images * rows_per_image
  object_ids = rng.integers(0, 12, (n, slots)).astype(np.int32)
  object_ids[:, -1] = -1
  images = {
    "depth": rng.uniform(0.5, 0.8, (n, *size)).astype(np.float32),
    "mask": rng.integers(0, slots, (n, *size)).astype(np.int32),
    "camera_intrinsics": rng.uniform(100, 500, (n, 4)).astype(np.float32),
    "camera_rotation": np.broadcast_to(np.eye(3, dtype=np.float32), (n, 3, 3)).copy(),
    "camera_translation": rng.normal(size=(n, 3)).astype(np.float32),
    "heap_id": (index * 100 + np.arange(n) // 2).astype(np.int64),
    "object_ids": object_ids,
    "object_poses": rng.normal(size=(n, slots, 7)).astype(np.float32),
    "object_names": np.where(object_ids >= 0, np.char.add("obj", object_ids.astype(str)), ""),
    "object_friction": np.where(object_ids >= 0, 0.8, 0.0).astype(np.float32),
    "object_mass": np.where(object_ids >= 0, 0.2, 0.0).astype(np.float32),
  }
  rows = {
    "gripper": rng.integers(0, 2, m).astype(np.int8),
    "center": rng.uniform(0, 6, (m, 2)).astype(np.float32),
    "angle": rng.uniform(-np.pi, np.pi, m).astype(np.float32),
    "grasp_depth": rng.uniform(0.5, 0.8, m).astype(np.float32),
    "approach_angle": rng.uniform(0, 1, m).astype(np.float32),
    "grasp_pose": rng.normal(size=(m, 4, 4)).astype(np.float32),
    "reward": rng.integers(0, 2, m).astype(np.int8),
    "robust_probability": rng.uniform(0, 1, m).astype(np.float32),
    "failure": rng.integers(0, 3, m).astype(np.int8),
    "target_slot": rng.integers(-1, slots, m).astype(np.int8),
    "policy": (rng.uniform(size=m) < 0.1).astype(np.int8),
    "image_index": np.repeat(np.arange(n), rows_per_image).astype(np.int32),
  }
  return images, rows


def _finish(out_dir, index, fingerprint=FP, seed=SEED):
  images, rows = _content(seed, index)
  return finish_shard(out_dir, index, images, rows, {"config_fingerprint": fingerprint, "seed": seed})


def _dataset(out_dir, num_shards=5, seed=SEED):
  open_manifest(out_dir, FP, seed, num_shards)
  for index in range(num_shards):
    _finish(out_dir, index, seed=seed)


def test_round_trip_keeps_every_array_and_meta(tmp_path):
  images, rows = _content(SEED, 3)
  write_shard(shard_path(tmp_path, 3), images, rows, {"config_fingerprint": FP, "seed": SEED, "index": 3})
  shard = read_shard(tmp_path / "shard-000003.npz")
  for name in images:
    np.testing.assert_array_equal(shard.images[name], images[name])
    assert shard.images[name].dtype == images[name].dtype
  for name in rows:
    np.testing.assert_array_equal(shard.rows[name], rows[name])
  assert shard.meta == {"config_fingerprint": FP, "seed": SEED, "index": 3, "num_images": 4, "num_rows": 20,
                        "format_version": shards.FORMAT_VERSION}


def test_same_config_seed_index_gives_identical_bytes(tmp_path):
  for run in ("a", "b"):
    _dataset(tmp_path / run, num_shards=2)
  assert (tmp_path / "a/shard-000001.npz").read_bytes() == (tmp_path / "b/shard-000001.npz").read_bytes()
  assert (tmp_path / "a/shard-000000.npz").read_bytes() != (tmp_path / "a/shard-000001.npz").read_bytes()
  with zipfile.ZipFile(tmp_path / "a/shard-000001.npz") as zf:
    assert {info.date_time for info in zf.infolist()} == {(1980, 1, 1, 0, 0, 0)}
  assert shard_seed(SEED, 1) == shard_seed(SEED, 1) != shard_seed(SEED, 2)
  assert config_fingerprint({"b": 1, "a": [1, 2]}) == config_fingerprint({"a": [1, 2], "b": 1})
  assert config_fingerprint({"a": 1}) != config_fingerprint({"a": 2})


@pytest.mark.parametrize("field, value, expected", [
  ("depth", np.zeros((3, 2), np.float32), "field 'depth': expected shape (N, H, W)"),
  ("mask", np.zeros((4, 6, 7), np.float32), "field 'mask': expected dtype int32, got float32"),
  ("object_poses", np.zeros((4, 2, 7), np.float32), "field 'object_poses': expected shape (N, P, 7) with N=4, P=3"),
])
def test_write_rejects_bad_images_naming_file_and_field(tmp_path, field, value, expected):
  images, rows = _content(SEED, 0)
  images[field] = value
  with pytest.raises(ShardError, match=r"shard '.*shard-000000\.npz': " + re.escape(expected)):
    write_shard(shard_path(tmp_path, 0), images, rows, {"config_fingerprint": FP, "seed": SEED, "index": 0})
  assert not shard_path(tmp_path, 0).exists()


def test_write_rejects_row_pointing_past_the_images(tmp_path):
  images, rows = _content(SEED, 0)
  rows["image_index"][-1] = 4
  with pytest.raises(ShardError, match=r"field 'image_index': expected values in \[0, 4\), got \[0, 4\]"):
    write_shard(shard_path(tmp_path, 0), images, rows, {"config_fingerprint": FP, "seed": SEED, "index": 0})


def test_interrupted_write_leaves_no_shard_and_rerun_finishes_it(tmp_path, monkeypatch):
  open_manifest(tmp_path, FP, SEED, 3)
  stale = tmp_path / "shard-000001.npz.tmp-999999999"  # a writer killed mid-write (pid no longer running)
  stale.write_bytes(b"PK\x03\x04 half a zip")

  def killed(*args):
    raise KeyboardInterrupt
  monkeypatch.setattr(shards.os, "replace", killed)
  with pytest.raises(KeyboardInterrupt):
    _finish(tmp_path, 2)
  monkeypatch.undo()
  assert sorted(p.name for p in tmp_path.iterdir()) == ["manifest.json", "manifest.lock", stale.name]
  assert pending_shards(tmp_path, 3, FP) == [0, 1, 2]
  _finish(tmp_path, 1)
  assert not stale.exists()
  assert pending_shards(tmp_path, 3, FP) == [0, 2]


def test_resume_lists_unfinished_shards_per_worker(tmp_path):
  open_manifest(tmp_path, FP, SEED, 5)
  for index in (0, 2, 3):
    _finish(tmp_path, index)
  assert pending_shards(tmp_path, 5, FP, seed=SEED) == [1, 4]
  assert pending_shards(tmp_path, 5, FP, assignment=parse_shard_assignment("1/2")) == [1]
  assert pending_shards(tmp_path, 5, FP, assignment=(0, 2)) == [4]
  manifest = load_manifest(tmp_path)
  assert sorted(manifest.shards) == [0, 2, 3]
  record = manifest.shards[2]
  assert (record.num_images, record.num_rows) == (4, 20)
  assert record.sha256 == file_sha256(shard_path(tmp_path, 2))


def test_pending_records_a_valid_shard_missing_from_the_manifest(tmp_path):
  open_manifest(tmp_path, FP, SEED, 2)
  images, rows = _content(SEED, 1)
  write_shard(shard_path(tmp_path, 1), images, rows, {"config_fingerprint": FP, "seed": SEED, "index": 1})
  assert pending_shards(tmp_path, 2, FP) == [0]
  assert sorted(load_manifest(tmp_path).shards) == [1]


def test_corrupt_shard_is_reported_and_listed_again(tmp_path):
  _dataset(tmp_path, num_shards=3)
  path = shard_path(tmp_path, 2)
  path.write_bytes(path.read_bytes()[:-300])
  with pytest.raises(ShardError, match=r"shard '.*shard-000002\.npz': corrupt or truncated"):
    read_shard(path)
  with pytest.warns(RuntimeWarning, match="shard-000002.npz"):
    assert pending_shards(tmp_path, 3, FP) == [2]
  _finish(tmp_path, 2)
  assert pending_shards(tmp_path, 3, FP) == []


def test_a_run_may_grow_but_not_shrink(tmp_path):
  _dataset(tmp_path, num_shards=2)
  assert open_manifest(tmp_path, FP, SEED, 4).num_shards == 4
  assert pending_shards(tmp_path, 4, FP) == [2, 3] and sorted(load_manifest(tmp_path).shards) == [0, 1]
  with pytest.raises(ConfigMismatchError, match="field 'num_shards': expected at least 4"):
    open_manifest(tmp_path, FP, SEED, 3)


def test_recorded_shards_of_the_recorded_size_are_not_reread_unless_verified(tmp_path, monkeypatch):
  _dataset(tmp_path, num_shards=3)
  assert load_manifest(tmp_path).shards[1].size == shard_path(tmp_path, 1).stat().st_size
  data = bytearray(shard_path(tmp_path, 1).read_bytes())
  data[len(data) // 2] ^= 0xFF  # same size, corrupt content (bit rot, not a torn write)
  shard_path(tmp_path, 1).write_bytes(bytes(data))
  import dexjax.data.manifest as manifest_module
  reads = []
  real = manifest_module.read_shard
  monkeypatch.setattr(manifest_module, "read_shard", lambda path: reads.append(path) or real(path))
  assert pending_shards(tmp_path, 3, FP) == [] and reads == []
  with pytest.warns(RuntimeWarning, match="shard-000001.npz"):
    assert pending_shards(tmp_path, 3, FP, verify=True) == [1]
  assert len(reads) == 3


def test_other_config_in_the_directory_raises(tmp_path):
  open_manifest(tmp_path, FP, SEED, 2)
  _finish(tmp_path, 0)
  other = config_fingerprint(dict(CONFIG, size=[8, 8]))
  with pytest.raises(ConfigMismatchError, match="new --out directory"):
    open_manifest(tmp_path, other, SEED, 2)
  with pytest.raises(ConfigMismatchError, match="new --out directory"):
    pending_shards(tmp_path, 2, other)
  os.remove(tmp_path / "manifest.json")
  with pytest.raises(ConfigMismatchError, match=r"shard '.*shard-000000\.npz'"):
    pending_shards(tmp_path, 2, other)


@pytest.mark.parametrize("text", ["2/2", "1", "a/3", "-1/2", "0/0"])
def test_parse_shard_assignment_rejects_bad_text(text):
  with pytest.raises(ValueError, match="--shard: expected 'i/N'"):
    parse_shard_assignment(text)


def _rows_seen(out_dir, split, seed, **kwargs):
  batches = list(iterate_rows(out_dir, split, batch_size=3, seed=seed, shuffle_buffer=7, **kwargs))
  assert all(len(b["reward"]) == 3 for b in batches[:-1])
  return batches, [(s, r) for b in batches for s, r in zip(b["shard_index"].tolist(), b["row_index"].tolist())]


def test_loader_yields_every_row_once_per_epoch_in_seeded_order(tmp_path):
  _dataset(tmp_path, num_shards=5)
  batches, train = _rows_seen(tmp_path, "train", seed=0, val_fraction=0.3)
  _, val = _rows_seen(tmp_path, "val", seed=0, val_fraction=0.3)
  assert len(train) == len(set(train)) and len(val) == len(set(val))
  assert set(train).isdisjoint(val) and len(train) + len(val) == 5 * 20 and len(val) > 0
  assert _rows_seen(tmp_path, "train", seed=0, val_fraction=0.3)[1] == train
  other = _rows_seen(tmp_path, "train", seed=1, val_fraction=0.3)[1]
  assert sorted(other) == sorted(train) and other != train
  shard = read_shard(shard_path(tmp_path, 3))
  for batch in batches:
    for k, (s, r) in enumerate(zip(batch["shard_index"], batch["row_index"])):
      if s == 3:
        np.testing.assert_array_equal(batch["grasp_pose"][k], shard.rows["grasp_pose"][r])
        np.testing.assert_array_equal(batch["depth"][k], shard.images["depth"][shard.rows["image_index"][r]])


def _heap_and_objects(out_dir, rows):
  """Heap id and object ids of the image of each (shard, row)."""
  loaded = {s: read_shard(shard_path(out_dir, s)) for s in {s for s, _ in rows}}
  image = [(loaded[s], loaded[s].rows["image_index"][r]) for s, r in rows]
  return ({int(sh.images["heap_id"][i]) for sh, i in image},
          {int(o) for sh, i in image for o in sh.images["object_ids"][i] if o >= 0})


def test_heap_split_never_shares_a_heap(tmp_path):
  _dataset(tmp_path, num_shards=4)
  train_heaps, _ = _heap_and_objects(tmp_path, _rows_seen(tmp_path, "train", 0, val_fraction=0.4)[1])
  val_heaps, _ = _heap_and_objects(tmp_path, _rows_seen(tmp_path, "val", 0, val_fraction=0.4)[1])
  assert train_heaps and val_heaps and train_heaps.isdisjoint(val_heaps)


def test_object_split_keeps_validation_objects_out_of_training(tmp_path):
  _dataset(tmp_path, num_shards=4)
  kwargs = {"by": "object", "val_fraction": 0.25, "split_seed": 3}
  _, train_objects = _heap_and_objects(tmp_path, _rows_seen(tmp_path, "train", 0, **kwargs)[1])
  val_objects = {o for o in range(12) if split_images([0], [[o]], "object", 0.25, 3)[0] == loader.VAL}
  assert train_objects and val_objects and train_objects.isdisjoint(val_objects)
  labels = split_images(np.zeros(3), np.array([[min(val_objects), -1], [min(train_objects), -1],
                                               [min(train_objects), min(val_objects)]]), "object", 0.25, 3)
  assert labels.tolist() == [loader.VAL, loader.TRAIN, loader.VAL]


def test_row_groups_name_the_contacted_object_or_else_the_heap(tmp_path):
  _dataset(tmp_path, num_shards=3)
  batches, _ = _rows_seen(tmp_path, "train", seed=0, val_fraction=0.0)
  rows = {k: np.concatenate([b[k] for b in batches]) for k in ("shard_index", "image_index", "target_slot",
                                                                "row_index")}
  by_object = row_groups(tmp_path, rows["shard_index"], rows["image_index"], rows["target_slot"])
  by_heap = row_groups(tmp_path, rows["shard_index"], rows["image_index"], rows["target_slot"], by="heap")
  kinds = set()
  for k, (s, r) in enumerate(zip(rows["shard_index"], rows["row_index"])):
    shard = read_shard(shard_path(tmp_path, int(s)))
    image, slot = shard.rows["image_index"][r], shard.rows["target_slot"][r]
    heap = f"heap:{shard.images['heap_id'][image]}"
    name = shard.images["object_names"][image, slot] if slot >= 0 else ""
    assert by_heap[k] == heap
    assert by_object[k] == (f"object:{name}" if name else heap)
    kinds.add((slot >= 0, bool(name)))
  assert kinds == {(True, True), (True, False), (False, False)}  # an object, an empty slot, no contact
  with pytest.raises(ValueError, match="'by': expected 'heap' or 'object'"):
    row_groups(tmp_path, rows["shard_index"], rows["image_index"], rows["target_slot"], by="image")


def test_several_datasets_are_read_as_their_union_with_heaps_split_per_dataset(tmp_path):
  a, b = tmp_path / "a", tmp_path / "b"
  _dataset(a, num_shards=5)
  _dataset(b, num_shards=3, seed=SEED + 1)  # same heap ids as a's first three shards, other content
  seen = {}
  for split in ("train", "val"):
    batches = list(iterate_rows([a, b], split, batch_size=3, seed=0, shuffle_buffer=7, val_fraction=0.5))
    seen[split] = [(d, s, r) for x in batches for d, s, r in zip(x["dataset_index"].tolist(),
                                                                  x["shard_index"].tolist(), x["row_index"].tolist())]
    for x in batches:
      for k, (d, s, r) in enumerate(zip(x["dataset_index"], x["shard_index"], x["row_index"])):
        shard = read_shard(shard_path((a, b)[d], int(s)))
        np.testing.assert_array_equal(x["grasp_pose"][k], shard.rows["grasp_pose"][r])
        np.testing.assert_array_equal(x["depth"][k], shard.images["depth"][shard.rows["image_index"][r]])
  train, val = set(seen["train"]), set(seen["val"])
  assert len(train) == len(seen["train"]) and len(val) == len(seen["val"]) and train.isdisjoint(val)
  assert len(train) + len(val) == (5 + 3) * 20
  assert {d for d, _, _ in train} == {d for d, _, _ in val} == {0, 1}
  # dataset 0 is split as on its own; dataset 1's heaps (same ids) are split independently of dataset 0's
  alone = {(s, r) for x in iterate_rows(a, "val", batch_size=3, seed=0, shuffle_buffer=7, val_fraction=0.5)
           for s, r in zip(x["shard_index"].tolist(), x["row_index"].tolist())}
  assert {(s, r) for d, s, r in val if d == 0} == alone
  val_heaps = [{h for h in _heap_and_objects(directory, [(s, r) for d, s, r in val if d == k])[0]}
               for k, directory in enumerate((a, b))]
  train_heaps = [{h for h in _heap_and_objects(directory, [(s, r) for d, s, r in train if d == k])[0]}
                 for k, directory in enumerate((a, b))]
  assert val_heaps[0] & train_heaps[1]  # one heap id, in validation in a and in training in b
  rows = [np.array(c) for c in zip(*sorted(train))]
  images = [read_shard(shard_path((a, b)[d], s)).rows["image_index"][r] for d, s, r in sorted(train)]
  slots = np.full(len(images), -1)
  groups = row_groups([a, b], rows[1], np.array(images), slots, by="heap", dataset_index=rows[0])
  assert {g.split("/")[0] for g in groups} == {"heap:0", "heap:1"}
  assert len(set(groups)) == len(train_heaps[0]) + len(train_heaps[1])
  with pytest.raises(ValueError, match="non-empty list"):
    list(iterate_rows([], "train"))
