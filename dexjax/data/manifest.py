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


#: Fields of a run manifest (`Manifest.to_json`; ``format_version`` too since it was added).
MANIFEST_FIELDS = ("config_fingerprint", "seed", "num_shards", "shards")

_NOT_A_MANIFEST = ("not a dexjax run manifest ({}); expected the manifest.json python -m dexjax.generate writes "
                   "(a JSON object with " + ", ".join(MANIFEST_FIELDS) + ")")


def _manifest_problem(data: Any) -> str | None:
  """What keeps the decoded JSON ``data`` from being a run manifest, or None."""
  if not isinstance(data, dict):
    return f"a JSON {type(data).__name__}, not an object"
  missing = [f for f in MANIFEST_FIELDS if f not in data]
  if missing:
    return f"no field {', '.join(repr(f) for f in missing)}"
  shards = data["shards"]
  record_fields = {f.name for f in dataclasses.fields(ShardRecord)}
  if not isinstance(shards, list) or not all(isinstance(r, dict) and "index" in r and set(r) <= record_fields
                                             for r in shards):
    return "field 'shards' is not a list of shard records"
  return None


class _NotAManifest(ShardError):
  """The file is not a readable run manifest; ``problem`` says why (without the file name)."""

  def __init__(self, path: Path, problem: str):
    super().__init__(f"manifest '{path}': {problem}")
    self.problem = problem


def _read_manifest(path: Path) -> Manifest:
  """The `Manifest` in the file ``path``; `ShardError` naming it if it is unreadable or not a run manifest."""
  from dexjax.config import ConfigError, parse_json  # pylint: disable=g-import-not-at-top (refuses deep nesting)
  try:
    data = parse_json(path.read_text(encoding="utf-8"), os.fspath(path), expected=None)
  except UnicodeDecodeError as err:
    raise _NotAManifest(path, _NOT_A_MANIFEST.format(f"byte {err.start} is not UTF-8 text")) from None
  except ConfigError as err:
    raise _NotAManifest(path, _NOT_A_MANIFEST.format(f"{err.field + ': ' if err.field else ''}{err.problem}")) from None
  problem = _manifest_problem(data)
  if problem is not None:
    raise _NotAManifest(path, _NOT_A_MANIFEST.format(problem))
  try:
    records = {r["index"]: ShardRecord(**r) for r in data["shards"]}
    return Manifest(data["config_fingerprint"], data["seed"], data["num_shards"], records)
  except (ValueError, KeyError, TypeError) as err:
    raise _NotAManifest(path, f"unreadable ({type(err).__name__}: {err})") from None


def load_manifest(out_dir: str | os.PathLike) -> Manifest | None:
  """Reads ``out_dir/manifest.json``; None if it does not exist; `ShardError` naming the file if it is unreadable
  or not a run manifest (e.g. a user's own ``manifest.json``)."""
  path = Path(out_dir) / MANIFEST_NAME
  try:
    return _read_manifest(path)
  except FileNotFoundError:
    return None


def manifest_problem(path: str | os.PathLike) -> str | None:
  """None if the file ``path`` is a readable run manifest, else why not, with what was expected (without the
  file name): checked before a run writes anything next to it, e.g. its ``manifest.lock``."""
  try:
    _read_manifest(Path(path))
  except _NotAManifest as err:
    return err.problem
  return None


def _save_manifest(out_dir: Path, manifest: Manifest) -> None:
  """Atomically replaces ``out_dir/manifest.json``."""
  atomic_write_text(out_dir / MANIFEST_NAME, manifest.to_json())


def _check_run(where: str, found: tuple, expected: tuple) -> None:
  if found != expected:
    raise ConfigMismatchError(
        f"{where}: expected (config_fingerprint, seed) {expected}, got {found}: this directory holds another "
        "run; use a new --out directory")


def open_manifest(out_dir: str | os.PathLike, fingerprint: str, seed: int, num_shards: int, *,
                  replace_foreign: bool = False) -> Manifest:
  """Loads the manifest of ``out_dir``, creating it if absent; raises `ConfigMismatchError` for another run.

  A run may grow: a larger ``num_shards`` than recorded extends it (shard i does not depend on the count); a
  smaller one raises `ConfigMismatchError` (the directory already promises more shards). A ``manifest.json``
  that is not a run manifest (`manifest_problem`) raises `ShardError`, or with ``replace_foreign`` (a command's
  ``--overwrite``) is replaced by a new one.
  """
  out_dir = Path(out_dir)
  out_dir.mkdir(parents=True, exist_ok=True)
  with _manifest_lock(out_dir):
    try:
      manifest = load_manifest(out_dir)
    except _NotAManifest:
      if not replace_foreign:
        raise
      manifest = None
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
