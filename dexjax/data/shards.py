"""Dataset shards: deterministic, atomically written ``.npz`` files plus a ``manifest.json`` that lets runs resume.

A shard holds the images of some heaps (image-level arrays, leading axis N) and the grasp actions labelled on
them (row-level arrays, leading axis M, each row pointing at its image by ``image_index``). Its content is a
function of (config, seed, shard index) only: draw its randomness from `shard_seed_sequence`, and the bytes of
the file are identical on every rerun (fixed member order, fixed zip timestamps, canonical JSON meta).

Writes go to ``<shard>.tmp-<pid>`` and are moved into place with `os.replace`, so a killed writer never leaves
a visible, half-written shard, and a failed write (disk full) raises an `OSError` naming the shard. The run
manifest and resuming (``--shard i/N``) live in `dexjax.data.manifest`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import zipfile
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from dexjax.config import ConfigError, parse_json

FORMAT_VERSION = 3  # 2: images store the heap state's per-object friction; 3: and each object's mass
MANIFEST_NAME = "manifest.json"
_META_KEY = "__meta__"
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)  # fixed member timestamp, so identical content gives identical bytes

#: Image-level fields, leading axis N (images): name -> (dtype, trailing shape). ``"H"``/``"W"`` are the image
#: size and ``"P"`` the heap's object slots (padded with id -1 and name ""); each is the same for every field
#: of a shard. Dtype ``"U"`` means any fixed-width unicode string.
IMAGE_SCHEMA: dict[str, tuple[str, tuple]] = {
  "depth": ("float32", ("H", "W")),               # metres along the optical axis
  "mask": ("int32", ("H", "W")),                  # dexjax.render.DepthImage.mask: slot, -1 bin, -2 invalid
  "camera_intrinsics": ("float32", (4,)),         # fx, fy, cx, cy in pixels
  "camera_rotation": ("float32", (3, 3)),         # camera-to-world rotation
  "camera_translation": ("float32", (3,)),        # camera origin in the world frame, metres
  "heap_id": ("int64", ()),                       # dataset-wide heap id; several images may share a heap
  "object_ids": ("int32", ("P",)),                # dataset-wide object ids, -1 for empty slots
  "object_poses": ("float32", ("P", 7)),          # x, y, z (metres), qw, qx, qy, qz in the world frame
  "object_names": ("U", ("P",)),                  # object keys, "" for empty slots
  "object_friction": ("float32", ("P",)),         # Coulomb friction of each object (heap state), 0 for empty
  "object_mass": ("float32", ("P",)),             # each object's simulated mass, kg (the labels' law), 0 for empty
}

#: Row-level fields (one grasp action each), leading axis M: name -> (dtype, trailing shape).
ROW_SCHEMA: dict[str, tuple[str, tuple]] = {
  "gripper": ("int8", ()),                        # GRIPPER_NAMES code
  "center": ("float32", (2,)),                    # grasp centre in the image, pixels (column u, row v)
  "angle": ("float32", ()),                       # in-image grasp axis angle, radians
  "grasp_depth": ("float32", ()),                 # depth of the grasp centre from the camera, metres
  "approach_angle": ("float32", ()),              # angle between approach axis and optical axis, radians
  "grasp_pose": ("float32", (4, 4)),              # gripper-to-world homogeneous transform, metres
  "reward": ("int8", ()),                         # S(x, u): 1 when collision-free, one object, robust
  "robust_probability": ("float32", ()),          # robust quality in [0, 1]
  "failure": ("int8", ()),                        # dexjax.quality.REWARD_FAILURES code, 0 for none
  "target_slot": ("int8", ()),                    # heap slot of the contacted object, -1 for none
  "policy": ("int8", ()),                         # POLICY_NAMES code: which part of tau chose the action
  "image_index": ("int32", ()),                   # index of the row's image in this shard, in [0, N)
}

#: Row ``gripper`` codes (index = code).
GRIPPER_NAMES = ("parallel_jaw", "suction")
#: Row ``policy`` codes: uniform over the image's candidates, or the algorithmic supervisor.
POLICY_NAMES = ("candidate", "supervisor")


class ShardError(Exception):
  """A shard or manifest is missing, corrupt, or does not match the schema; the message names the file."""


class ConfigMismatchError(ShardError):
  """An output directory holds shards or a manifest of another config or seed."""


@dataclasses.dataclass(frozen=True)
class Shard:
  """One shard as read from disk.

  Attributes:
    path: the ``.npz`` file.
    images: `IMAGE_SCHEMA` field -> array with leading axis N.
    rows: `ROW_SCHEMA` field -> array with leading axis M.
    meta: the JSON meta (format_version, config_fingerprint, seed, index, num_images, num_rows, and extras).
  """

  path: Path
  images: dict[str, np.ndarray]
  rows: dict[str, np.ndarray]
  meta: dict[str, Any]


def shard_path(out_dir: str | os.PathLike, index: int) -> Path:
  """Path of shard ``index`` in ``out_dir``: ``out_dir/shard-{index:06d}.npz``."""
  return Path(out_dir) / f"shard-{index:06d}.npz"


def config_fingerprint(config: Mapping[str, Any]) -> str:
  """First 16 hex digits of the sha256 of ``config`` as canonical JSON (sorted keys, no spaces, no NaN)."""
  try:
    text = json.dumps(config, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)
  except (TypeError, ValueError) as err:
    raise ValueError(f"config: expected plain JSON values (dict, list, str, int, finite float), {err}") from err
  return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def shard_seed_sequence(seed: int, index: int) -> np.random.SeedSequence:
  """Seed sequence of shard ``index`` of a run with ``seed``; use ``np.random.default_rng`` on it or spawn it."""
  if seed < 0 or index < 0:
    raise ValueError(f"shard seed: expected seed >= 0 and index >= 0, got seed={seed}, index={index}")
  return np.random.SeedSequence([seed, index])


def shard_seed(seed: int, index: int) -> int:
  """A 63-bit integer seed for shard ``index`` (e.g. for ``jax.random.key``), a function of (seed, index)."""
  return int(shard_seed_sequence(seed, index).generate_state(1, np.uint64)[0] >> np.uint64(1))


def _fail(path, field: str, problem: str) -> ShardError:
  return ShardError(f"shard '{path}': field '{field}': {problem}")


def _check_fields(path, arrays: Mapping[str, np.ndarray], schema: dict, axis: str) -> int:
  """Checks names, dtypes and shapes of ``arrays`` against ``schema``; returns the leading size (N or M)."""
  if set(arrays) != set(schema):
    missing, extra = sorted(set(schema) - set(arrays)), sorted(set(arrays) - set(schema))
    raise _fail(path, ",".join(missing + extra), f"expected fields {sorted(schema)}, missing {missing}, extra {extra}")
  sizes: dict[str, int] = {}
  for name, (dtype, trailing) in schema.items():
    arr = arrays[name]
    ok = arr.dtype.kind == "U" if dtype == "U" else arr.dtype == np.dtype(dtype)
    if not ok:
      raise _fail(path, name, f"expected dtype {dtype}, got {arr.dtype}")
    expected = (axis,) + tuple(trailing)
    if arr.ndim != len(expected) or not all(_dim_ok(want, got, sizes) for want, got in zip(expected, arr.shape)):
      known = ", ".join(f"{k}={v}" for k, v in sizes.items() if k in expected)
      raise _fail(path, name, f"expected shape ({', '.join(map(str, expected))})"
                  + (f" with {known}" if known else "") + f", got {arr.shape}")
  return sizes[axis]


def _dim_ok(want: int | str, got: int, sizes: dict[str, int]) -> bool:
  """An integer dimension must match exactly; a named one must match its first occurrence in the shard."""
  if isinstance(want, str):
    return sizes.setdefault(want, got) == got
  return want == got


def _check_image_index(path, image_index: np.ndarray, num_images: int) -> None:
  if image_index.size and (image_index.min() < 0 or image_index.max() >= num_images):
    raise _fail(path, "image_index", f"expected values in [0, {num_images}), got [{image_index.min()}, "
                f"{image_index.max()}]")


def _validate(path, images, rows) -> tuple[int, int]:
  """Validates both field groups; returns (num_images, num_rows)."""
  images = {k: np.asarray(v) for k, v in images.items()}
  rows = {k: np.asarray(v) for k, v in rows.items()}
  num_images = _check_fields(path, images, IMAGE_SCHEMA, "N")
  num_rows = _check_fields(path, rows, ROW_SCHEMA, "M")
  _check_image_index(path, rows["image_index"], num_images)
  return num_images, num_rows


def _write_npz(file, arrays: dict[str, np.ndarray]) -> None:
  """Writes ``arrays`` as an npz (deflated, members in the given order) with fixed timestamps."""
  with zipfile.ZipFile(file, mode="w", compression=zipfile.ZIP_DEFLATED) as zf:
    for name, arr in arrays.items():
      info = zipfile.ZipInfo(name + ".npy", date_time=_ZIP_DATE)
      info.compress_type = zipfile.ZIP_DEFLATED
      info.external_attr = 0o644 << 16
      with zf.open(info, "w", force_zip64=True) as fid:
        np.lib.format.write_array(fid, np.asarray(arr, order="C"), allow_pickle=False)


def _remove_stale_temps(path: Path) -> None:
  """Deletes ``<path>.tmp-<pid>`` files whose writer is no longer running on this host."""
  for tmp in path.parent.glob(path.name + ".tmp-*"):
    pid = tmp.name.rsplit("-", 1)[-1]
    if pid.isdigit() and int(pid) != os.getpid() and not _pid_alive(int(pid)):
      tmp.unlink(missing_ok=True)


def _pid_alive(pid: int) -> bool:
  try:
    os.kill(pid, 0)
  except ProcessLookupError:
    return False
  except PermissionError:
    return True
  return True


def write_shard(path: str | os.PathLike, images: Mapping[str, np.ndarray], rows: Mapping[str, np.ndarray],
                meta: Mapping[str, Any]) -> dict[str, Any]:
  """Validates and atomically writes one shard; returns the stored meta.

  Args:
    path: destination, usually `shard_path` (out_dir, index).
    images: every `IMAGE_SCHEMA` field, exact dtypes, leading axis N.
    rows: every `ROW_SCHEMA` field, exact dtypes, leading axis M; ``image_index`` in [0, N).
    meta: JSON values; must hold ``config_fingerprint`` (str), ``seed`` and ``index`` (int). ``num_images``,
      ``num_rows`` and ``format_version`` are added.
  """
  path = Path(path)
  for key in ("config_fingerprint", "seed", "index"):
    if key not in meta:
      raise _fail(path, "meta", f"expected key '{key}', got keys {sorted(meta)}")
  num_images, num_rows = _validate(path, images, rows)
  full = dict(meta, num_images=num_images, num_rows=num_rows, format_version=FORMAT_VERSION)
  arrays = {k: np.asarray(images[k]) for k in IMAGE_SCHEMA} | {k: np.asarray(rows[k]) for k in ROW_SCHEMA}
  arrays[_META_KEY] = np.array(json.dumps(full, sort_keys=True, separators=(",", ":")))
  path.parent.mkdir(parents=True, exist_ok=True)
  _remove_stale_temps(path)
  tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
  try:
    _write_npz(tmp, arrays)
    os.replace(tmp, path)
  except OSError as err:  # disk full, permission denied: name the shard (the temporary file is removed below)
    if err.errno is None or err.filename not in (None, os.fspath(tmp)):
      raise
    raise type(err)(err.errno, err.strerror, os.fspath(path)) from err
  finally:
    tmp.unlink(missing_ok=True)
  return full


def _load_members(path: Path) -> dict[str, np.ndarray]:
  """Reads every member (so zip CRCs are checked); any read failure becomes a `ShardError`."""
  try:
    with open(path, "rb") as file, np.load(file, allow_pickle=False) as npz:  # our handle: closed on errors too
      return {name: npz[name] for name in npz.files}
  except FileNotFoundError:
    raise ShardError(f"shard '{path}': file not found") from None
  except Exception as err:  # BadZipFile, zlib.error, EOFError, ValueError, OSError: all mean a bad file
    raise ShardError(f"shard '{path}': corrupt or truncated file ({type(err).__name__}: {err})") from err


def _parse_meta(path: Path, arrays: dict[str, np.ndarray]) -> dict[str, Any]:
  if _META_KEY not in arrays:
    raise _fail(path, _META_KEY, "expected a JSON meta string, got no such member")
  text = arrays.pop(_META_KEY)
  try:
    meta = parse_json(str(text.item()), _META_KEY, expected=None)  # nesting and duplicate keys refused too
  except ConfigError as err:
    raise _fail(path, _META_KEY, f"expected JSON, got {err.field + ': ' if err.field else ''}{err.problem}") from err
  if not isinstance(meta, dict):
    raise _fail(path, _META_KEY, f"expected a JSON object, got a {type(meta).__name__}")
  if meta.get("format_version") != FORMAT_VERSION:
    raise _fail(path, "format_version", f"expected {FORMAT_VERSION}, got {meta.get('format_version')}")
  return meta


def read_shard(path: str | os.PathLike) -> Shard:
  """Reads and validates a shard (schema, counts against the meta, ``image_index`` range); raises `ShardError`."""
  path = Path(path)
  arrays = _load_members(path)
  meta = _parse_meta(path, arrays)
  images = {k: arrays[k] for k in IMAGE_SCHEMA if k in arrays}
  rows = {k: v for k, v in arrays.items() if k not in IMAGE_SCHEMA}
  num_images, num_rows = _validate(path, images, rows)
  if (num_images, num_rows) != (meta.get("num_images"), meta.get("num_rows")):
    raise _fail(path, "num_images/num_rows", f"expected ({meta.get('num_images')}, {meta.get('num_rows')}) "
                f"from the meta, got ({num_images}, {num_rows})")
  return Shard(path=path, images=images, rows=rows, meta=meta)
