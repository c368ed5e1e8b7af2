"""Grasp-quality reports for one object: sample or read grasps, evaluate them, and make JSON records.

This is the library side of ``python -m dexjax.quality``; the CLI only parses arguments and writes the file.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import jax
import numpy as np

from dexjax.config import (ConfigError, as_dict, check_fields, check_sections, load_yaml, override,
                           validate_perturbations)
from dexjax.geometry.object_model import ObjectModel
from dexjax.grasps import parallel_jaw_pose, suction_pose
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality.batched import evaluate_grasps
from dexjax.quality.grasp_json import grasp_record, parse_grasps, stack_parallel_jaw, stack_suction
from dexjax.quality.grasp_quality import FAILURE_REASONS, QualityConfig
from dexjax.quality.robust import Perturbations, parallel_jaw_perturbations, suction_perturbations
from dexjax.sampling.object_samplers import AntipodalSampler, sample_antipodal_grasps, sample_suction_grasps

_sample_pj = jax.jit(sample_antipodal_grasps, static_argnums=2)
_sample_suction = jax.jit(sample_suction_grasps, static_argnums=2)
_pj_pose = jax.jit(jax.vmap(parallel_jaw_pose))
_suction_pose = jax.jit(jax.vmap(suction_pose))


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
  if top.num_samples < 1:
    raise ConfigError(source, "num_samples", f"expected an integer >= 1, got {top.num_samples}")
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
  check_fields([("tolerance", settings.config.tolerance > 0, "a number > 0 (newtons)"),
                ("torque_scale", settings.config.torque_scale > 0, "a number > 0 (1/m)"),
                ("gravity_acceleration", settings.config.gravity_acceleration >= 0, "a number >= 0 (m/s^2)"),
                ("collision_tolerance", settings.config.collision_tolerance >= 0,
                 "a number >= 0 (metres a gripper solid may reach into an object)")],
               settings.config, source=source, section="quality")
  settings.config.geometry.validate(source, "quality.geometry")
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
  """Parses a decoded grasp JSON document (see `dexjax.quality.grasp_json`)."""
  return parse_grasps(data, source, default_width=settings.parallel_jaw.max_width)


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
