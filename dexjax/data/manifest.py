"""The run manifest: ``out_dir/manifest.json`` with finished shards, resume and ``--shard i/N`` assignment.

The manifest records the run's config fingerprint, seed and shard count and, for every finished shard, its
counts and the sha256 of its bytes; it is updated atomically under a file lock after each shard. The shard
files stay the source of truth: `pending_shards` re-validates them, adds valid shards the manifest misses, and
lists missing or corrupt ones as still to do; a shard or manifest of another config raises
`ConfigMismatchError` (use a new output directory).
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import hashlib
import json
import os
import re
import warnings
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from dexjax.data.shards import (FORMAT_VERSION, MANIFEST_NAME, ConfigMismatchError, ShardError, read_shard,
                                shard_path, write_shard)
from dexjax.geometry.cache import atomic_write_text


def file_sha256(path: str | os.PathLike) -> str:
  """Hex sha256 of a file's bytes."""
  digest = hashlib.sha256()
  with open(path, "rb") as f:
    for block in iter(lambda: f.read(1 << 20), b""):
      digest.update(block)
  return digest.hexdigest()


@dataclasses.dataclass(frozen=True)
class ShardRecord:
  """A finished shard as listed in the manifest: file name (relative to out_dir), counts and sha256 of its bytes."""

  index: int
  file: str
  num_images: int
  num_rows: int
  sha256: str
  size: int = -1  # bytes; -1 in manifests written before sizes were recorded


@dataclasses.dataclass(frozen=True)
class Manifest:
  """Contents of ``out_dir/manifest.json``: the run's config fingerprint, seed, shard count and finished shards."""

  config_fingerprint: str
  seed: int
  num_shards: int
  shards: Mapping[int, ShardRecord] = dataclasses.field(default_factory=dict)

  def to_json(self) -> str:
    data = dataclasses.asdict(self) | {"format_version": FORMAT_VERSION}
    data["shards"] = [dataclasses.asdict(self.shards[i]) for i in sorted(self.shards)]
    return json.dumps(data, sort_keys=True, indent=1)


def load_manifest(out_dir: str | os.PathLike) -> Manifest | None:
  """Reads ``out_dir/manifest.json``; None if it does not exist; `ShardError` if it is unreadable."""
  path = Path(out_dir) / MANIFEST_NAME
  try:
    data = json.loads(path.read_text())
    records = {r["index"]: ShardRecord(**r) for r in data["shards"]}
    return Manifest(data["config_fingerprint"], data["seed"], data["num_shards"], records)
  except FileNotFoundError:
    return None
  except (ValueError, KeyError, TypeError, RecursionError) as err:
    raise ShardError(f"manifest '{path}': unreadable ({type(err).__name__}: {err})") from err


def _save_manifest(out_dir: Path, manifest: Manifest) -> None:
  """Atomically replaces ``out_dir/manifest.json``."""
  atomic_write_text(out_dir / MANIFEST_NAME, manifest.to_json())


def _check_run(where: str, found: tuple, expected: tuple) -> None:
  if found != expected:
    raise ConfigMismatchError(
        f"{where}: expected (config_fingerprint, seed) {expected}, got {found}: this directory holds another "
        "run; use a new --out directory")


def open_manifest(out_dir: str | os.PathLike, fingerprint: str, seed: int, num_shards: int) -> Manifest:
  """Loads the manifest of ``out_dir``, creating it if absent; raises `ConfigMismatchError` for another run.

  A run may grow: a larger ``num_shards`` than recorded extends it (shard i does not depend on the count); a
  smaller one raises `ConfigMismatchError` (the directory already promises more shards).
  """
  out_dir = Path(out_dir)
  out_dir.mkdir(parents=True, exist_ok=True)
  with _manifest_lock(out_dir):
    manifest = load_manifest(out_dir)
    if manifest is None:
      manifest = Manifest(fingerprint, seed, num_shards)
      _save_manifest(out_dir, manifest)
    _check_run(f"manifest '{out_dir / MANIFEST_NAME}'", (manifest.config_fingerprint, manifest.seed),
               (fingerprint, seed))
    if manifest.num_shards < num_shards:
      manifest = dataclasses.replace(manifest, num_shards=num_shards)
      _save_manifest(out_dir, manifest)
  if manifest.num_shards != num_shards:
    raise ConfigMismatchError(f"manifest '{out_dir / MANIFEST_NAME}': field 'num_shards': expected at least "
                              f"{manifest.num_shards} (this run's size), got {num_shards}; ask for at least as "
                              "many images or use a new --out directory")
  return manifest


@contextlib.contextmanager
def _manifest_lock(out_dir: Path):
  """Exclusive ``flock`` on ``out_dir/manifest.lock``: serialises read-modify-write among workers of one host."""
  with open(out_dir / "manifest.lock", "a") as file:
    fcntl.flock(file, fcntl.LOCK_EX)
    yield  # closing the file releases the lock


def record_shard(out_dir: str | os.PathLike, index: int, meta: Mapping[str, Any] | None = None) -> ShardRecord:
  """Adds the finished shard ``index`` (counts and sha256 of its file) to the manifest, atomically.

  ``meta``: the shard's meta as `write_shard` returned it (the file is then hashed, not read and validated
  again); None reads and validates the file.
  """
  out_dir = Path(out_dir)
  path = shard_path(out_dir, index)
  meta = read_shard(path).meta if meta is None else meta
  record = ShardRecord(index, path.name, meta["num_images"], meta["num_rows"], file_sha256(path),
                       path.stat().st_size)
  with _manifest_lock(out_dir):
    manifest = load_manifest(out_dir)
    if manifest is None:
      raise ShardError(f"manifest '{out_dir / MANIFEST_NAME}': file not found; call open_manifest first")
    _check_run(f"shard '{path}'", (meta["config_fingerprint"], meta["seed"]),
               (manifest.config_fingerprint, manifest.seed))
    _save_manifest(out_dir, dataclasses.replace(manifest, shards={**manifest.shards, index: record}))
  return record


def finish_shard(out_dir: str | os.PathLike, index: int, images: Mapping[str, np.ndarray],
                 rows: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> ShardRecord:
  """`write_shard` to `shard_path` (out_dir, index), then `record_shard`; ``meta`` needs the fingerprint and seed."""
  stored = write_shard(shard_path(out_dir, index), images, rows, dict(meta, index=index))
  return record_shard(out_dir, index, stored)


def _shard_status(out_dir: Path, index: int, fingerprint: str, seed: int | None) -> bool:
  """True if shard ``index`` is finished and valid; False (with a warning if corrupt) if it must be (re)done."""
  path = shard_path(out_dir, index)
  if not path.exists():
    return False
  try:
    meta = read_shard(path).meta
  except ShardError as err:
    warnings.warn(f"{err}; it will be regenerated", RuntimeWarning, stacklevel=3)
    return False
  found = (meta.get("config_fingerprint"), meta.get("seed") if seed is not None else None)
  _check_run(f"shard '{path}'", found, (fingerprint, seed))
  if meta.get("index") != index:
    raise ShardError(f"shard '{path}': field 'index': expected {index} (from the file name), got {meta.get('index')}")
  return True


def pending_shards(out_dir: str | os.PathLike, num_shards: int, fingerprint: str,
                   assignment: tuple[int, int] = (0, 1), seed: int | None = None, verify: bool = False) -> list[int]:
  """Shard indices worker i of N still has to write (round robin: ``index % N == i``), ascending.

  A shard is done if its file reads and validates and its meta matches ``fingerprint`` (and ``seed`` if given);
  a corrupt file is warned about and listed again; a valid shard of another config raises `ConfigMismatchError`.
  Valid shards missing from the manifest (a run killed between writing and recording) are recorded. A shard the
  manifest lists with its file's current size is taken as done without reading it (shards are renamed into
  place complete, so a size match rules out a torn write), unless ``verify``: then every file is read.
  """
  worker, num_workers = assignment
  if not 0 <= worker < num_workers:
    raise ValueError(f"assignment: expected (i, N) with 0 <= i < N, got {assignment}")
  out_dir = Path(out_dir)
  manifest = load_manifest(out_dir)
  if manifest is not None:
    _check_run(f"manifest '{out_dir / MANIFEST_NAME}'", (manifest.config_fingerprint,
               manifest.seed if seed is not None else None), (fingerprint, seed))
  pending = []
  for index in range(worker, num_shards, num_workers):
    record = manifest.shards.get(index) if manifest is not None else None
    if not verify and record is not None and record.size >= 0 and _size(shard_path(out_dir, index)) == record.size:
      continue
    if not _shard_status(out_dir, index, fingerprint, seed):
      pending.append(index)
    elif manifest is not None and index not in manifest.shards:
      record_shard(out_dir, index)
  return pending


def _size(path: Path) -> int:
  try:
    return path.stat().st_size
  except FileNotFoundError:
    return -2


_ASSIGNMENT = re.compile(r"\s*(\d+)\s*/\s*(\d+)\s*")


def parse_shard_assignment(text: str) -> tuple[int, int]:
  """Parses ``--shard i/N`` (worker i of N, 0-based) into ``(i, N)``; ``0 <= i < N`` is required."""
  match = _ASSIGNMENT.fullmatch(text)
  if match is None:
    raise ValueError(f"--shard: expected 'i/N' with integers 0 <= i < N (e.g. '0/4'), got {text!r}")
  worker, num_workers = int(match[1]), int(match[2])
  if not 0 <= worker < num_workers:
    raise ValueError(f"--shard: expected 'i/N' with 0 <= i < N, got i={worker}, N={num_workers} in {text!r}")
  return worker, num_workers
