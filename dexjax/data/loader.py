"""Streaming, shuffled, leak-free train/validation batches from a directory of shards (or several: their union).

Split rule (`split_images`): membership is decided per image by a seeded hash, so it is the same in every shard,
every epoch and every process, and needs no pass over the dataset.

* ``by="heap"``: a heap is in validation if hash(heap_id) < val_fraction; all images of a heap (and all their
  rows) follow their heap, so no heap is in both sets.
* ``by="object"``: objects are split first (object id in validation if hash(object_id) < val_fraction); then
  images follow their objects: an image with only training objects is training, an image with *any*
  validation object is validation (images mixing both kinds go to validation, never to training). So no
  training row ever shows a validation object; validation heaps may also contain training objects.

Rows are never split individually: rows of one image are always in the same set.

`iterate_rows` reads one shard at a time, in a seeded random order, and mixes rows in a bounded shuffle buffer;
memory holds at most ``shuffle_buffer + batch_size`` rows, one shard, and the depth images the buffered rows
point at. Call it again with another ``seed`` for the next epoch.

Several datasets (a sequence of directories, e.g. the rounds of on-policy synthesis and the set they started from)
are read as one: their shards are mixed in one random order, each row says which dataset it came from
(``dataset_index``, its position in the sequence), and a heap is keyed by (dataset, heap id) so that heaps of
different datasets sharing an id are split independently; objects are keyed by id alone, so an object is in one
split in every dataset.
"""

from __future__ import annotations

import os
from pathlib import Path
from collections.abc import Iterator, Sequence

import numpy as np

from dexjax.data.manifest import load_manifest
from dexjax.data.shards import ROW_SCHEMA, read_shard, shard_path

TRAIN, VAL = 0, 1
_SPLITS = {"train": TRAIN, "val": VAL}
_DATASET_STRIDE = 1 << 40  # heap key of dataset d: heap_id + d * stride (heap ids stay far below it)
_M1, _M2, _GOLDEN = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB), np.uint64(0x9E3779B97F4A7C15)


def _unit_hash(keys: np.ndarray, seed: int) -> np.ndarray:
  """Splitmix64 of (key, seed) mapped to [0, 1), elementwise; same shape as ``keys`` (integers)."""
  x = np.asarray(keys, np.int64).view(np.uint64) + np.uint64((seed + 1) * int(_GOLDEN) % 2**64)
  x = (x ^ (x >> np.uint64(30))) * _M1
  x = (x ^ (x >> np.uint64(27))) * _M2
  x = x ^ (x >> np.uint64(31))
  return (x >> np.uint64(11)).astype(np.float64) / float(2**53)


def split_images(heap_ids: np.ndarray, object_ids: np.ndarray, by: str = "heap", val_fraction: float = 0.1,
                 seed: int = 0) -> np.ndarray:
  """Train/validation label of each image: `TRAIN` (0) or `VAL` (1); see the module docstring for the rule.

  Args:
    heap_ids: (N,) int, the images' heap ids.
    object_ids: (N, P) int, the images' object ids, -1 for empty slots (ignored).
    by: ``"heap"`` or ``"object"``.
    val_fraction: expected fraction of heaps (or objects) in validation, in [0, 1].
    seed: split seed; keep it fixed across epochs and runs that must agree.

  Returns:
    (N,) int8 labels.
  """
  if not 0.0 <= val_fraction <= 1.0:
    raise ValueError(f"split_images: field 'val_fraction': expected a value in [0, 1], got {val_fraction}")
  if by == "heap":
    is_val = _unit_hash(np.asarray(heap_ids), seed) < val_fraction
  elif by == "object":
    object_ids = np.asarray(object_ids)
    is_val = ((_unit_hash(object_ids, seed) < val_fraction) & (object_ids >= 0)).any(axis=1)
  else:
    raise ValueError(f"split_images: field 'by': expected 'heap' or 'object', got {by!r}")
  return np.where(is_val, VAL, TRAIN).astype(np.int8)


def list_shards(out_dir: str | os.PathLike) -> list[Path]:
  """Finished shards of ``out_dir`` in index order: those in the manifest, else every ``shard-*.npz`` file."""
  manifest = load_manifest(out_dir)
  if manifest is not None:
    return [shard_path(out_dir, i) for i in sorted(manifest.shards)]
  return sorted(Path(out_dir).glob("shard-[0-9]*.npz"))


DataDirs = str | os.PathLike | Sequence[str | os.PathLike]


def dataset_dirs(data: DataDirs) -> tuple[Path, ...]:
  """The dataset directories of ``data``: one directory, or a sequence of them (read as their union).

  Raises:
    ValueError: an empty sequence.
  """
  dirs = (Path(data),) if isinstance(data, (str, os.PathLike)) else tuple(Path(d) for d in data)
  if not dirs:
    raise ValueError("data: expected a dataset directory or a non-empty list of them, got an empty list")
  return dirs


def require_shards(data: DataDirs, hint: str = "") -> tuple[Path, ...]:
  """`dataset_dirs` of ``data``, each checked to be a directory holding finished shards.

  Raises:
    FileNotFoundError: naming the first directory that is not one or holds no shards, then ``hint`` (what to do).
  """
  dirs = dataset_dirs(data)
  for directory in dirs:
    if not directory.is_dir() or not list_shards(directory):
      raise FileNotFoundError(f"{os.fspath(directory)}: no dataset shards (shard-*.npz)"
                              + (f"; {hint}" if hint else ""))
  return dirs


def dataset_label(data: DataDirs) -> str:
  """``data``'s directories for messages: ``"a"``, or ``"a + b + c"`` for a union."""
  return " + ".join(os.fspath(d) for d in dataset_dirs(data))


def dataset_shards(data: DataDirs) -> list[tuple[int, Path]]:
  """(dataset index, shard path) of the finished shards of every dataset of ``data`` (`list_shards` of each)."""
  return [(d, path) for d, directory in enumerate(dataset_dirs(data)) for path in list_shards(directory)]


def _select_rows(shard, split: int, by: str, val_fraction: float, split_seed: int, dataset: int = 0) -> np.ndarray:
  """Indices of the shard's rows whose image is in ``split`` (heaps keyed by (``dataset``, heap id))."""
  heaps = np.asarray(shard.images["heap_id"], np.int64) + dataset * _DATASET_STRIDE
  labels = split_images(heaps, shard.images["object_ids"], by, val_fraction, split_seed)
  return np.flatnonzero(labels[shard.rows["image_index"]] == split)


class _Buffer:
  """Shuffle buffer: row fields as arrays, plus the depth images (keyed by (shard slot, image)) rows point at."""

  def __init__(self):
    self.rows: dict[str, np.ndarray] | None = None
    self.depths: dict[tuple[int, int], np.ndarray] = {}

  def __len__(self) -> int:
    return 0 if self.rows is None else len(self.rows["image_index"])

  def add(self, shard, slot: int, index: np.ndarray, dataset: int = 0) -> None:
    """Appends the rows ``index`` of ``shard`` (of dataset ``dataset``, read as slot ``slot``) and their images."""
    new = {k: shard.rows[k][index] for k in ROW_SCHEMA}
    new["dataset_index"] = np.full(len(index), dataset, np.int32)
    new["shard_index"] = np.full(len(index), shard.meta["index"], np.int32)
    new["row_index"] = index.astype(np.int32)
    new["_slot"] = np.full(len(index), slot, np.int32)
    for image in np.unique(new["image_index"]):
      self.depths[(slot, int(image))] = shard.images["depth"][image].copy()  # a copy frees the shard
    self.rows = new if self.rows is None else {k: np.concatenate([self.rows[k], new[k]]) for k in new}

  def take(self, index: np.ndarray, stack_images: bool = True) -> dict[str, np.ndarray]:
    """Removes the rows ``index`` and returns them as a batch with their depth images gathered (stacked, or
    as an object array of references)."""
    batch = {k: v[index] for k, v in self.rows.items()}
    self.rows = {k: np.delete(v, index, axis=0) for k, v in self.rows.items()}
    slots = batch.pop("_slot")
    images = [self.depths[(int(s), int(i))] for s, i in zip(slots, batch["image_index"])]
    if stack_images:
      batch["depth"] = np.stack(images)
    else:
      batch["depth"] = np.empty(len(images), object)
      for k, image in enumerate(images):
        batch["depth"][k] = image
    return batch

  def prune(self) -> None:
    """Drops images that no buffered row points at."""
    live = set(zip(self.rows["_slot"].tolist(), self.rows["image_index"].tolist())) if len(self) else set()
    self.depths = {k: v for k, v in self.depths.items() if k in live}


def iterate_rows(out_dir: DataDirs, split: str = "train", batch_size: int = 64, seed: int = 0,
                 shuffle_buffer: int = 10_000, by: str = "heap", val_fraction: float = 0.1, split_seed: int = 0,
                 drop_remainder: bool = False, stack_images: bool = True) -> Iterator[dict[str, np.ndarray]]:
  """Streams one epoch of shuffled batches of the rows of ``split``.

  Args:
    out_dir: directory with shards (and usually a manifest, see `list_shards`), or a sequence of them (their
      union, see the module docstring).
    split: ``"train"`` or ``"val"``.
    batch_size: rows per batch; the last batch is smaller unless ``drop_remainder``.
    seed: shuffle seed (shard order and row order); use a new one per epoch.
    shuffle_buffer: rows kept for mixing; larger mixes rows of more shards.
    by, val_fraction, split_seed: the split, see `split_images`.
    drop_remainder: drop the last, partial batch.
    stack_images: ``depth`` as one (B, H, W) array (a copy of each row's image); False: a (B,) object array of
      references to the images (no copy; rows of one image share it), for consumers that read small windows.

  Yields:
    Dicts of NumPy arrays with leading axis B: every `ROW_SCHEMA` field, ``depth`` (B, H, W) float32 (the
    row's depth image, metres), ``dataset_index``, ``shard_index`` and ``row_index`` (B,) int32 (where the row
    came from: its dataset's position in ``out_dir``, 0 for one directory; its shard; its index in the shard).
  """
  if split not in _SPLITS:
    raise ValueError(f"iterate_rows: field 'split': expected 'train' or 'val', got {split!r}")
  if batch_size < 1 or shuffle_buffer < 0:
    raise ValueError(f"iterate_rows: expected batch_size >= 1 and shuffle_buffer >= 0, got {batch_size}, "
                     f"{shuffle_buffer}")
  rng = np.random.default_rng(seed)
  paths = dataset_shards(out_dir)
  buffer = _Buffer()
  for slot, path_index in enumerate(rng.permutation(len(paths))):
    dataset, path = paths[path_index]
    shard = read_shard(path)
    buffer.add(shard, slot, _select_rows(shard, _SPLITS[split], by, val_fraction, split_seed, dataset), dataset)
    del shard
    while len(buffer) >= shuffle_buffer + batch_size:
      yield buffer.take(rng.choice(len(buffer), batch_size, replace=False), stack_images)
    buffer.prune()
  yield from _drain(buffer, rng, batch_size, drop_remainder, stack_images)


def _drain(buffer: _Buffer, rng: np.random.Generator, batch_size: int, drop_remainder: bool,
           stack_images: bool) -> Iterator[dict[str, np.ndarray]]:
  """Yields the rest of the buffer in random order."""
  while len(buffer) >= batch_size or (len(buffer) and not drop_remainder):
    yield buffer.take(rng.choice(len(buffer), min(batch_size, len(buffer)), replace=False), stack_images)


def row_groups(out_dir: DataDirs, shard_index: np.ndarray, image_index: np.ndarray, target_slot: np.ndarray,
               by: str = "object", dataset_index: np.ndarray | None = None) -> np.ndarray:
  """A group key (N,) str per row, given where the rows came from (as `iterate_rows` yields them).

  ``by="heap"``: the row's heap (``"heap:<id>"``; ``"heap:<dataset>/<id>"`` when ``out_dir`` holds several
  datasets); ``by="object"``: the object its grasp contacts (``"object:<name>"``, one key in every dataset), or
  its heap for a row that contacts none. Rows with one key are not independent samples
  (`dexjax.train.bootstrap_intervals` resamples them together). Reads only the shards' image fields.
  ``dataset_index`` (N,): each row's dataset (default: all 0).
  """
  if by not in ("heap", "object"):
    raise ValueError(f"row_groups: field 'by': expected 'heap' or 'object', got {by!r}")
  dirs = dataset_dirs(out_dir)
  shard_index, image_index = np.asarray(shard_index), np.asarray(image_index)
  target_slot = np.asarray(target_slot)
  dataset_index = np.zeros_like(shard_index) if dataset_index is None else np.asarray(dataset_index)
  keys = np.empty(len(shard_index), object)
  for dataset, shard in sorted(set(zip(dataset_index.tolist(), shard_index.tolist()))):
    sel = np.flatnonzero((shard_index == shard) & (dataset_index == dataset))
    prefix = f"{dataset}/" if len(dirs) > 1 else ""
    with np.load(shard_path(dirs[dataset], shard)) as arrays:
      heaps = arrays["heap_id"][image_index[sel]]
      names = arrays["object_names"][image_index[sel], np.maximum(target_slot[sel], 0)]
    for k, heap, name, slot in zip(sel, heaps, names, target_slot[sel]):
      keys[k] = f"object:{name}" if by == "object" and slot >= 0 and name else f"heap:{prefix}{heap}"
  return keys.astype(str)


__all__ = ["TRAIN", "VAL", "DataDirs", "dataset_dirs", "dataset_label", "dataset_shards", "iterate_rows",
           "list_shards", "require_shards", "row_groups", "split_images"]
