"""Reading and writing grasps in dexjax's JSON form (object frame, metres).

Input::

  {"grasps": [{"gripper": "suction", "center": [x, y, z], "approach": [ax, ay, az]},
              {"gripper": "parallel_jaw", "center": [x, y, z], "axis": [x, y, z], "approach": [ax, ay, az],
               "width": 0.05}]}

``approach`` is the unit direction in which the gripper moves toward the object (for suction, into the
surface), ``axis`` the unit direction in which the jaws close; ``width`` (optional) defaults to the gripper's
maximum opening. Directions are normalised on reading; a parallel-jaw approach is made perpendicular to the
axis. Every problem is reported with the file, the grasp index, the field and what was expected.
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np

from dexjax.config import ConfigError, parse_json
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp

GRIPPER_NAMES = ("parallel_jaw", "suction")


class GraspFileError(ValueError):
  """A grasp file that cannot be used; the message names the file, grasp index, field and expectation."""


def _vector(entry: dict, field: str, where: str, *, unit: bool) -> np.ndarray:
  if field not in entry:
    raise GraspFileError(f"{where}: missing field '{field}' (expected a list of 3 numbers)")
  value = entry[field]
  try:
    arr = np.asarray(value, dtype=np.float64)
  except (TypeError, ValueError):
    raise GraspFileError(f"{where}: field '{field}' is {value!r}, expected a list of 3 numbers") from None
  if arr.shape != (3,) or not np.all(np.isfinite(arr)):
    raise GraspFileError(f"{where}: field '{field}' is {value!r}, expected 3 finite numbers")
  if unit:
    norm = np.linalg.norm(arr)
    if norm < 1e-9:
      raise GraspFileError(f"{where}: field '{field}' is the zero vector, expected a unit direction")
    arr = arr / norm
  return arr


def load_grasp_json(path: str | os.PathLike[str]) -> Any:
  """The decoded JSON document of the grasp file ``path`` (validate it with `parse_grasps`).

  Raises:
    GraspFileError: the file is not UTF-8 text, not valid JSON or nested deeper than
      `dexjax.config.MAX_NESTING` levels (naming the file, and the line and column where known).
    OSError: the file cannot be read (missing, a directory, no permission).
  """
  name = os.fspath(path)
  try:
    with open(name, encoding="utf-8") as f:
      text = f.read()
  except UnicodeDecodeError as e:
    raise GraspFileError(f"{name}: not a text file (byte {e.start} is not UTF-8); expected grasp JSON") from None
  try:
    return parse_json(text, name, expected='{"grasps": [...]}')
  except ConfigError as e:
    raise GraspFileError(str(e)) from None


def parse_grasps(data: Any, source: str, *, default_width: float) -> list[tuple[str, dict[str, np.ndarray]]]:
  """Validates a decoded grasp JSON document.

  Args:
    data: the decoded JSON object.
    source: file name used in error messages.
    default_width: parallel-jaw opening used when a grasp gives no ``width``, metres.

  Returns:
    One ``(gripper, fields)`` per grasp in file order; fields hold float64 arrays
    (``center``, ``approach`` and for parallel jaws ``axis`` and ``width``).

  Raises:
    GraspFileError: naming the file, the grasp index, the field and the expected value.
  """
  if not isinstance(data, dict) or not isinstance(data.get("grasps"), list):
    raise GraspFileError(f"{source}: expected an object with a list under 'grasps'")
  out = []
  for i, entry in enumerate(data["grasps"]):
    where = f"{source}: grasps[{i}]"
    if not isinstance(entry, dict):
      raise GraspFileError(f"{where}: expected an object, got {type(entry).__name__}")
    gripper = entry.get("gripper")
    if gripper not in GRIPPER_NAMES:
      raise GraspFileError(f"{where}: field 'gripper' is {gripper!r}, expected one of {list(GRIPPER_NAMES)}")
    fields = {"center": _vector(entry, "center", where, unit=False),
              "approach": _vector(entry, "approach", where, unit=True)}
    if gripper == "parallel_jaw":
      axis = _vector(entry, "axis", where, unit=True)
      approach = fields["approach"] - np.dot(fields["approach"], axis) * axis
      if np.linalg.norm(approach) < 1e-6:
        raise GraspFileError(f"{where}: 'approach' is parallel to 'axis', expected a direction perpendicular to it")
      fields["axis"] = axis
      fields["approach"] = approach / np.linalg.norm(approach)
      width = entry.get("width", default_width)
      if not isinstance(width, (int, float)) or not math.isfinite(width) or width <= 0:
        raise GraspFileError(f"{where}: field 'width' is {width!r}, expected a positive number of metres")
      fields["width"] = np.float64(width)
    out.append((gripper, fields))
  return out


def stack_parallel_jaw(items: list[dict[str, np.ndarray]]) -> ParallelJawGrasp:
  """Stacks parsed parallel-jaw fields into a batched `ParallelJawGrasp` (float32)."""
  f = lambda k: np.asarray([it[k] for it in items], np.float32)
  return ParallelJawGrasp(center=f("center"), axis=f("axis"), approach=f("approach"), width=f("width"))


def stack_suction(items: list[dict[str, np.ndarray]]) -> SuctionGrasp:
  """Stacks parsed suction fields into a batched `SuctionGrasp` (float32)."""
  f = lambda k: np.asarray([it[k] for it in items], np.float32)
  return SuctionGrasp(center=f("center"), approach=f("approach"))


def grasp_record(gripper: str, grasp: ParallelJawGrasp | SuctionGrasp, pose: np.ndarray) -> dict[str, Any]:
  """JSON-ready record of one (unbatched) grasp in the input form, plus its 4 x 4 gripper pose."""
  rec: dict[str, Any] = {"gripper": gripper, "center": np.asarray(grasp.center).round(7).tolist()}
  if gripper == "parallel_jaw":
    rec["axis"] = np.asarray(grasp.axis).round(7).tolist()
  rec["approach"] = np.asarray(grasp.approach).round(7).tolist()
  if gripper == "parallel_jaw":
    rec["width"] = round(float(grasp.width), 7)
  rec["pose"] = np.asarray(pose).round(7).tolist()
  return rec
