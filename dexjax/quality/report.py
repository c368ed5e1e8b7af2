"""Grasp-quality reports for one object: sample or read grasps, evaluate them, and make JSON records.

This is the library side of ``python -m dexjax.quality``; the CLI only parses arguments and writes the file.
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Any

import jax
import numpy as np

from dexjax.config import as_dict, check_sections, load_yaml, override
from dexjax.config_rules import (MAX_FORCE, MAX_GRIPPER_SIZE, MAX_SAMPLES, ConfigError, check_fields, count_rule,
                                 number_rule, validate_perturbations)
from dexjax.geometry.object_model import ObjectModel
from dexjax.grasps import parallel_jaw_pose, suction_pose
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality.batched import evaluate_grasps
from dexjax.quality.grasp_json import (GraspFileError, grasp_record, parse_grasps, stack_parallel_jaw,
                                       stack_suction)
from dexjax.quality.grasp_quality import FAILURE_REASONS, QualityConfig
from dexjax.quality.gripper_geometry import check_collision_samples
from dexjax.quality.robust import Perturbations, parallel_jaw_perturbations, suction_perturbations
from dexjax.sampling.object_samplers import AntipodalSampler, sample_antipodal_grasps, sample_suction_grasps

_sample_pj = jax.jit(sample_antipodal_grasps, static_argnums=2)
_sample_suction = jax.jit(sample_suction_grasps, static_argnums=2)
_pj_pose = jax.jit(jax.vmap(parallel_jaw_pose))
_suction_pose = jax.jit(jax.vmap(suction_pose))

MAX_GRASP_VALUE: float = 1000.0
"""Largest magnitude of any number in a grasp file (metres for ``center`` and ``width``; directions are normalised,
so their scale is free within it). Beyond it the file is not in metres, and float32 (the solver's precision) no
longer resolves 0.1 mm."""

MAX_GRASP_DISTANCE: float = 10.0
"""Farthest a grasp ``center`` may lie from the object's bounding box, metres: farther, the grasp cannot touch the
object and the file is most likely in other units or another frame."""

MAX_TORQUE_SCALE: float = 1e6
"""Largest ``quality.torque_scale``, 1/m (torques counted as forces at a lever of at least 1 micrometre)."""

MAX_GRAVITY: float = 1000.0
"""Largest ``quality.gravity_acceleration``, m/s^2 (about 100 g)."""

_NUMERIC_FIELDS = ("center", "approach", "axis", "width")


@dataclasses.dataclass(frozen=True)
class ReportSettings:
  """Everything that parameterises a report (all recorded in its output); defaults are Dex-Net 4.0's.

  ``num_samples`` overrides the ``num_samples`` of both perturbation models.
  """

  parallel_jaw: ParallelJawGripper = ParallelJawGripper()
  suction: SuctionGripper = SuctionGripper()
  num_samples: int = 10
  threshold: float = 0.5
  config: QualityConfig = QualityConfig()
  parallel_jaw_perturbations: Perturbations = parallel_jaw_perturbations()
  suction_perturbations: Perturbations = suction_perturbations()

  def perturbations(self, gripper: str) -> Perturbations:
    p = self.parallel_jaw_perturbations if gripper == "parallel_jaw" else self.suction_perturbations
    return p.replace(num_samples=self.num_samples)

  def gripper(self, gripper: str) -> ParallelJawGripper | SuctionGripper:
    return self.parallel_jaw if gripper == "parallel_jaw" else self.suction


_GRIPPERS = ("parallel_jaw", "suction")


def settings_from_config(data: dict[str, Any], source: str) -> ReportSettings:
  """`ReportSettings` from a decoded config mapping (layout: ``configs/quality.yaml``); unset fields keep defaults.

  Raises:
    ConfigError: unknown section or field, wrong type, negative number, or a threshold outside [0, 1].
  """
  check_sections(data, ("num_samples", "threshold", "quality", "grippers", "perturbations"), source=source)
  s = ReportSettings()
  top = override(s, {k: data[k] for k in ("num_samples", "threshold") if k in data}, source=source, section="",
                 minimum=0)
  check_fields([count_rule("num_samples", top.num_samples, 1, MAX_SAMPLES, "Monte-Carlo draws")], top,
               source=source)
  if top.threshold > 1.0:
    raise ConfigError(source, "threshold", f"expected a number in [0, 1], got {top.threshold}")
  grippers = data.get("grippers") or {}
  perturbations = data.get("perturbations") or {}
  for name, section in (("grippers", grippers), ("perturbations", perturbations)):
    if not isinstance(section, dict):
      raise ConfigError(source, name, f"expected a mapping with keys {' and '.join(_GRIPPERS)}, got {section!r}")
    check_sections(section, _GRIPPERS, source=source, section=name)
  kw = dict(source=source, minimum=0.0)
  settings = dataclasses.replace(
      top,
      config=override(s.config, data.get("quality"), section="quality", **kw),
      parallel_jaw=override(s.parallel_jaw, grippers.get("parallel_jaw"), section="grippers.parallel_jaw", **kw),
      suction=override(s.suction, grippers.get("suction"), section="grippers.suction", **kw),
      parallel_jaw_perturbations=override(s.parallel_jaw_perturbations, perturbations.get("parallel_jaw"),
                                          section="perturbations.parallel_jaw", **kw),
      suction_perturbations=override(s.suction_perturbations, perturbations.get("suction"),
                                     section="perturbations.suction", **kw))
  return validate_settings(settings, source)


def validate_settings(settings: ReportSettings, source: str = "<settings>") -> ReportSettings:
  """Checks the rules that tie fields together (``min_width < max_width``, a friction range with low <= high,
  positive mass and cup size, ...) for both grippers and perturbation models; returns ``settings``.

  Raises:
    ConfigError: naming ``source``, the dotted field (``grippers.parallel_jaw.min_width``) and the expected value.
  """
  settings.parallel_jaw.validate(source, "grippers.parallel_jaw")
  settings.suction.validate(source, "grippers.suction")
  for name in _GRIPPERS:
    validate_perturbations(settings.perturbations(name), source=source, section=f"perturbations.{name}")
  q = settings.config
  check_fields([number_rule("tolerance", q.tolerance, 0, MAX_FORCE, "newtons", low_open=True),
                number_rule("torque_scale", q.torque_scale, 0, MAX_TORQUE_SCALE, "1/m", low_open=True),
                number_rule("gravity_acceleration", q.gravity_acceleration, 0, MAX_GRAVITY, "m/s^2"),
                number_rule("collision_tolerance", q.collision_tolerance, 0, MAX_GRIPPER_SIZE,
                            "metres a gripper solid may reach into an object")],
               q, source=source, section="quality")
  q.geometry.validate(source, "quality.geometry")
  check_collision_samples(settings.parallel_jaw, q.geometry, source, "quality.geometry")
  return settings


def load_settings(path: str | os.PathLike[str]) -> ReportSettings:
  """`ReportSettings` from a YAML config file (see `settings_from_config`)."""
  return settings_from_config(load_yaml(path), os.fspath(path))


def sample_grasps(key: jax.Array, model: ObjectModel, gripper: str, num_grasps: int,
                  settings: ReportSettings = ReportSettings()) -> list[tuple[str, dict[str, np.ndarray]]]:
  """Samples up to ``num_grasps`` valid grasps of one gripper type (4x candidates, first valid ones kept)."""
  budget = max(64, 4 * num_grasps)
  if gripper == "parallel_jaw":
    grasps, valid = _sample_pj(key, model, budget, settings.parallel_jaw, AntipodalSampler(), settings.config)
  else:
    grasps, valid = _sample_suction(key, model, budget, settings.suction)
  keep = np.flatnonzero(np.asarray(valid))[:num_grasps]
  fields = jax.tree.map(lambda x: np.asarray(x)[keep], grasps)
  return [(gripper, {k: v[i] for k, v in vars(fields).items()}) for i in range(len(keep))]


def evaluate_report(key: jax.Array, model: ObjectModel, grasps: list[tuple[str, dict[str, np.ndarray]]],
                    settings: ReportSettings = ReportSettings()) -> list[dict[str, Any]]:
  """Evaluates parsed grasps (any mix of grippers) and returns one JSON record per grasp, in input order.

  Each record repeats the grasp (``center``, ``approach``, ``axis``/``width`` for parallel jaws) with its 4x4
  ``pose``, ``nominal`` (0/1), ``nominal_failure`` (a `FAILURE_REASONS` name), ``robust_probability`` and
  ``robust`` (probability > threshold). Grasp i of each gripper type draws from ``fold_in(key_g, i)``.
  """
  records: list[dict[str, Any] | None] = [None] * len(grasps)
  for g_index, name in enumerate(("parallel_jaw", "suction")):
    idx = [i for i, (g, _) in enumerate(grasps) if g == name]
    if not idx:
      continue
    items = [grasps[i][1] for i in idx]
    batch = stack_parallel_jaw(items) if name == "parallel_jaw" else stack_suction(items)
    result = evaluate_grasps(jax.random.fold_in(key, g_index), model, batch, settings.gripper(name),
                             settings.perturbations(name), settings.config)
    poses = np.asarray((_pj_pose if name == "parallel_jaw" else _suction_pose)(batch))
    for j, i in enumerate(idx):
      rec = grasp_record(name, jax.tree.map(lambda x: x[j], batch), poses[j])
      rec["nominal"] = int(result.nominal[j])
      rec["nominal_failure"] = FAILURE_REASONS[int(result.nominal_failure[j])]
      rec["robust_probability"] = round(float(result.probability[j]), 6)
      rec["robust"] = int(result.probability[j] > settings.threshold)
      records[i] = rec
  return records  # type: ignore[return-value]


def read_grasp_file(data: Any, source: str, settings: ReportSettings = ReportSettings()):
  """Parses a decoded grasp JSON document (see `dexjax.quality.grasp_json`) and checks its values.

  Every number of ``center``, ``approach``, ``axis`` and ``width`` must be a JSON number (not a boolean, not a
  string), finite and at most `MAX_GRASP_VALUE` in magnitude; a parallel-jaw ``width`` must lie in the gripper's
  [``min_width``, ``max_width``] (``settings.parallel_jaw``). See `check_grasps_near_object` for the distance to
  the object, which needs the object.

  Returns:
    One ``(gripper, fields)`` per grasp in file order (`dexjax.quality.grasp_json.parse_grasps`).

  Raises:
    GraspFileError: naming the file, the grasp index, the field and the expected value.
  """
  _check_numbers(data, source)
  grasps = parse_grasps(data, source, default_width=settings.parallel_jaw.max_width)
  _check_widths(grasps, source, settings.parallel_jaw)
  return grasps


def _check_numbers(data: Any, source: str) -> None:
  """Checks the numbers of each grasp's numeric fields before they are converted (where ``true`` would become 1.0
  and 1e400 an overflow); the structure (a list of 3 numbers, ...) is `parse_grasps`'s to check."""
  if not isinstance(data, dict) or not isinstance(data.get("grasps"), list):
    return
  for i, entry in enumerate(data["grasps"]):
    if not isinstance(entry, dict):
      continue
    for field in _NUMERIC_FIELDS:
      value = entry.get(field)
      items = value if isinstance(value, list) else [value] if isinstance(value, (bool, int, float)) else []
      for item in items:
        problem = _number_problem(item)
        if problem is not None:
          raise GraspFileError(f"{source}: grasps[{i}]: field '{field}' {problem}")


def _number_problem(item: Any) -> str | None:
  """What is wrong with one number of a grasp field, in words (None: a plausible number; nested lists pass)."""
  if isinstance(item, bool):
    return f"holds the boolean {str(item).lower()}; expected a number"
  if isinstance(item, str):
    return f"holds the string {item[:40]!r}; expected a number"
  if not isinstance(item, (int, float)):
    return None
  if isinstance(item, float) and not math.isfinite(item):
    return (f"holds a non-finite number ({item}: NaN, Infinity or beyond the float range); expected finite numbers "
            f"of magnitude at most {MAX_GRASP_VALUE:g} (metres)")
  if abs(item) > MAX_GRASP_VALUE:
    small = isinstance(item, float) or abs(item) < 1e300
    shown = f"{item:.4g}" if small else f"an integer of about {int(item.bit_length() * 0.30103)} digits"
    return f"holds {shown}; expected numbers of magnitude at most {MAX_GRASP_VALUE:g} (metres)"
  return None


def _check_widths(grasps: list[tuple[str, dict[str, np.ndarray]]], source: str, gripper: ParallelJawGripper) -> None:
  """Refuses a parallel-jaw ``width`` outside the gripper's [min_width, max_width]."""
  for i, (name, fields) in enumerate(grasps):
    if name == "parallel_jaw" and not gripper.min_width <= float(fields["width"]) <= gripper.max_width:
      raise GraspFileError(
          f"{source}: grasps[{i}]: field 'width' is {float(fields['width']):g}; expected an opening in "
          f"[min_width, max_width] = [{gripper.min_width:g}, {gripper.max_width:g}] metres of the parallel-jaw "
          "gripper (grippers.parallel_jaw of --config)")


def check_grasps_near_object(grasps: list[tuple[str, dict[str, np.ndarray]]], bounds: Any, source: str) -> None:
  """Refuses a grasp whose ``center`` lies more than `MAX_GRASP_DISTANCE` from the object's bounding box.

  Args:
    grasps: parsed grasps (`read_grasp_file`), in file order.
    bounds: (2, 3) [min, max] corners of the object's bounding box, metres (`ObjectModel.bounds`).
    source: the grasp file's name, for the message.

  Raises:
    GraspFileError: naming the file, the grasp index, the distance and the bound.
  """
  low, high = np.asarray(bounds, np.float64)
  for i, (_, fields) in enumerate(grasps):
    center = np.asarray(fields["center"], np.float64)
    distance = float(np.linalg.norm(np.maximum(0.0, np.maximum(low - center, center - high))))
    if distance > MAX_GRASP_DISTANCE:
      raise GraspFileError(
          f"{source}: grasps[{i}]: field 'center' is {np.round(center, 6).tolist()}, {distance:.3g} m from the "
          f"object's bounding box; expected a point within {MAX_GRASP_DISTANCE:g} m of the object (object frame, "
          "metres)")


def report_parameters(settings: ReportSettings, seed: int, grippers: list[str]) -> dict[str, Any]:
  """The parameters block of a report: seed, Monte-Carlo model, thresholds, gripper and solver settings."""
  return {
      "seed": seed,
      "num_samples": settings.num_samples,
      "threshold": settings.threshold,
      "quality": as_dict(settings.config),
      "grippers": {g: as_dict(settings.gripper(g)) for g in grippers},
      "perturbations": {g: as_dict(settings.perturbations(g)) for g in grippers},
  }


def object_summary(model: ObjectModel, source: str) -> dict[str, Any]:
  """Source and mass properties of the object, for the report."""
  return {"source": source, "volume_m3": float(model.volume),
          "center_of_mass": np.asarray(model.center_of_mass).round(7).tolist(),
          "bounds": np.asarray(model.bounds).round(7).tolist()}
