"""The rules a configuration's values obey: the documented limits of every field, and the checks that tie fields
together (``min_width < max_width``, a friction range with ``low <= high``, ``min_count <= max_count``).

A rule is a row ``(field, holds, expected)`` of a table that `check_fields` applies, raising a `ConfigError` that
names the file, the dotted field, the expected value and the value found. Each parameter class keeps its own table
(``validate`` of the grippers and of `dexjax.quality.GripperGeometry`); the tables of the classes that live in
modules of their own (`dexjax.quality.Perturbations`, `dexjax.sim.HeapDistribution`, `dexjax.sim.Bin`,
`dexjax.sim.SettleSettings`) and of a whole generation run are here.

**Limits** (docs/errors.md, "Limits of config values"). Every number has an upper bound, so that a typo or a wrong
unit (``1e9``, ``1e308``) is refused before any work instead of exhausting the memory, running for days or
producing nonsense:

* physical sizes: a gripper's lengths at most `MAX_GRIPPER_SIZE` (1 m: it grasps objects of 5 mm - 1 m), a bin's
  at most `MAX_BIN_SIZE` (10 m), forces at most `MAX_FORCE` (1e5 N, about 10 tonnes-force), masses at most
  `MAX_MASS` (1000 kg), Coulomb friction coefficients at most `MAX_FRICTION` (2; the seed truncates to [0, 1]);
* counts that size arrays or loops: static counts of a gripper model (polygon vertices, cone edges, ray steps,
  samples along a line) at most `MAX_STATIC_COUNT` (1024), Monte-Carlo draws at most `MAX_SAMPLES` (10,000),
  grasps per object or image at most `MAX_GRASPS` (10,000), physics steps per heap at most `MAX_SETTLE_STEPS`
  (100,000: 400 s of simulated time at the 4 ms step), objects per heap at most `MAX_HEAP_OBJECTS` (100), images
  per shard at most `MAX_IMAGES_PER_SHARD` (10,000), signed-distance grids at most `MAX_GRID_SIZE` (512) voxels
  per side (0.5 GB).

This module uses the standard library only (the array stack is not imported).
"""

from __future__ import annotations

import math
import numbers
from typing import Any


class ConfigError(ValueError):
  """A configuration file or value is invalid; the message names the file, the field and the expected value."""

  def __init__(self, source: str, field: str, problem: str):
    self.source, self.field, self.problem = source, field, problem
    where = f"{source}: {field}" if field else source
    super().__init__(f"{where}: {problem}")


MAX_GRIPPER_SIZE = 1.0
"""Largest length of a gripper, metres (jaw opening, finger and palm sizes, cup radius and height, tool shaft)."""

MAX_BIN_SIZE = 10.0
"""Largest size of the bin (floor, wall height and thickness) and drop height of a heap, metres."""

MAX_FORCE = 1e5
"""Largest force, newtons (grip force, vacuum pull, wrench tolerance, disturbance); also bounds the cup's elastic
limit (N / rad) and bellows stiffness (N m / rad)."""

MAX_MASS = 1000.0
"""Largest mean object mass, kg."""

MAX_FRICTION = 2.0
"""Largest Coulomb friction coefficient (rubber on rough surfaces reaches 1-1.5; the seed truncates to [0, 1])."""

MAX_STATIC_COUNT = 1024
"""Largest static count of a gripper model (ring vertices, cone edges, ray steps, line samples): each sizes the
arrays of every grasp evaluated."""

MAX_SAMPLES = 10_000
"""Largest number of Monte-Carlo draws M of a robust quality (the seed uses 10 and 25)."""

MAX_GRASPS = 10_000
"""Largest number of grasps sampled per object or image (the seed uses 100)."""

MAX_SETTLE_STEPS = 100_000
"""Largest number of physics steps per heap (the seed uses 500)."""

MAX_SOLVER_ITERATIONS = 1000
"""Largest number of constraint-solver (or line-search) iterations per physics step."""

MAX_HEAP_OBJECTS = 100
"""Largest number of objects in one heap (the seed uses at most 10)."""

MAX_IMAGES_PER_SHARD = 10_000
"""Largest number of images per dataset shard or per heap."""

MAX_GRID_SIZE = 512
"""Largest signed-distance grid resolution per axis: a 512^3 float32 grid is 0.5 GB (Dex-Net's SDFGen used 100)."""

Rule = tuple[str, bool, str]
"""(field, holds, expected): one row of a `check_fields` table."""


def check_fields(rules: list[Rule], params: Any, *, source: str, section: str = "") -> Any:
  """Returns ``params`` if every rule holds; else raises `ConfigError` for the first that does not, naming
  ``source``, the dotted field ``section.field``, the expected value and the value found in ``params``."""
  for field, holds, expected in rules:
    if not holds:
      where = f"{section}.{field}" if section else field
      raise ConfigError(source, where, f"expected {expected}, got {_field_value(params, field)!r}")
  return params


def _field_value(params: Any, field: str) -> Any:
  """The value of ``field`` (``name`` or ``name[i]``) of ``params``, as plain Python."""
  name, _, index = field.partition("[")
  value = getattr(params, name, None)
  if index:
    value = value[int(index.rstrip("]"))]
  try:
    return float(value) if not isinstance(value, (int, str, tuple, type(None))) else value
  except TypeError:
    return value


def number_or_nan(value: Any) -> float:
  """``value`` as a float; NaN for anything that is not a concrete finite number (a tracer, None, a string)."""
  try:
    x = float(value)
  except (TypeError, ValueError):
    return math.nan
  return x if math.isfinite(x) else math.nan


def _shown(x: float) -> str:
  """``x`` as written in a message: 0.0005, 1024, 100,000 (thousands separated from 10,000 on)."""
  return f"{x:,g}" if abs(x) >= 10_000 else f"{x:g}"


def number_rule(field: str, value: Any, low: float, high: float, unit: str, *, low_open: bool = False) -> Rule:
  """The rule "``value`` is a finite number >= low (> low with ``low_open``) and <= high", e.g.
  ``number_rule('cup_radius', r, 0, MAX_GRIPPER_SIZE, 'metres', low_open=True)``; ``unit`` is said in brackets."""
  x = number_or_nan(value)
  holds = (x > low if low_open else x >= low) and x <= high
  return field, holds, f"a number {'>' if low_open else '>='} {_shown(low)} and <= {_shown(high)} ({unit})"


def count_rule(field: str, value: Any, low: int, high: int, what: str = "") -> Rule:
  """The rule "``value`` is an integer (not a bool) in [low, high]"; ``what`` (e.g. 'physics steps per heap')
  is said in brackets."""
  holds = isinstance(value, numbers.Integral) and not isinstance(value, bool) and low <= value <= high
  return field, holds, f"an integer in [{_shown(low)}, {_shown(high)}]" + (f" ({what})" if what else "")


def _range_rules(name: str, pair: Any, what: str) -> list[Rule]:
  """Rules of a non-negative (low, high) pair: both finite, 0 <= low <= high."""
  low, high = number_or_nan(pair[0]), number_or_nan(pair[1])
  return [(f"{name}[0]", low >= 0, f"a finite number >= 0 ({what})"),
          (f"{name}[1]", high >= low, f"a finite number >= {name}[0] = {pair[0]} (low <= high; {what})")]


def friction_rules(params: Any) -> list[Rule]:
  """Rules of a truncated-normal Coulomb friction (``friction_mean``, ``friction_variance``, ``friction_range``):
  0 <= low <= high <= `MAX_FRICTION`, low < high when the variance is > 0, and the mean inside the range (a mean
  outside it would only ever give the nearest bound)."""
  low, high = number_or_nan(params.friction_range[0]), number_or_nan(params.friction_range[1])
  return [
      *_range_rules("friction_range", params.friction_range, "the friction truncation interval"),
      ("friction_range[1]", high <= MAX_FRICTION,
       f"a number <= {MAX_FRICTION:g} (MAX_FRICTION: a Coulomb friction coefficient)"),
      ("friction_range", number_or_nan(params.friction_variance) == 0 or high > low,
       "low < high when friction_variance > 0 (a truncated normal needs an interval)"),
      ("friction_mean", low <= number_or_nan(params.friction_mean) <= high,
       f"a number in friction_range = [{low:g}, {high:g}] (the Coulomb friction's mean lies in its truncation "
       "interval)"),
  ]


def perturbation_rules(p: Any) -> list[Rule]:
  """Rules of a `dexjax.quality.Perturbations` (mass, friction, noise, gravity cone, draws)."""
  axis = p.gravity_axis
  return [
      number_rule("mass_mean", p.mass_mean, 0, MAX_MASS, "kg", low_open=True),
      ("mass_variance", number_or_nan(p.mass_variance) > 0, "a number > 0 (kg^2; the mass is Gamma distributed)"),
      *friction_rules(p),
      number_rule("position_sigma", p.position_sigma, 0, MAX_GRIPPER_SIZE, "metres"),
      number_rule("rotation_sigma", p.rotation_sigma, 0, math.pi, "radians"),
      number_rule("disturbance_sigma", p.disturbance_sigma, 0, MAX_FORCE, "newtons and newton metres"),
      ("gravity_cone_angle", 0 <= number_or_nan(p.gravity_cone_angle) <= math.pi, "an angle in [0, pi] (radians)"),
      ("gravity_axis", axis is None or (len(axis) == 3 and not any(math.isnan(number_or_nan(a)) for a in axis)
                                        and any(number_or_nan(a) != 0 for a in axis)),
       "null or 3 finite numbers, not all zero"),
      count_rule("num_samples", p.num_samples, 1, MAX_SAMPLES, "Monte-Carlo draws"),
  ]


def validate_perturbations(p: Any, *, source: str = "Perturbations", section: str = "") -> Any:
  """`check_fields` with `perturbation_rules`; returns ``p``."""
  return check_fields(perturbation_rules(p), p, source=source, section=section)


def validate_heap_distribution(h: Any, *, source: str = "HeapDistribution", section: str = "heap") -> Any:
  """Rules of a `dexjax.sim.HeapDistribution` (object counts, drop region, friction); returns ``h``."""
  rules = [
      number_rule("count_mean", h.count_mean, 0, MAX_HEAP_OBJECTS, "objects", low_open=True),
      count_rule("min_count", h.min_count, 1, MAX_HEAP_OBJECTS, "objects"),
      ("max_count", isinstance(h.max_count, int) and h.min_count <= h.max_count <= MAX_HEAP_OBJECTS,
       f"an integer in [min_count = {h.min_count}, {MAX_HEAP_OBJECTS}] (objects; MAX_HEAP_OBJECTS)"),
      ("count_truncation", h.count_truncation in ("condition", "clip"), "'condition' or 'clip'"),
      ("count_law", h.count_law in ("poisson", "uniform"), "'poisson' or 'uniform'"),
      number_rule("drop_height", h.drop_height, 0, MAX_BIN_SIZE, "metres above the bin floor", low_open=True),
      number_rule("drop_half_width", h.drop_half_width, 0, MAX_BIN_SIZE, "metres"),
      number_rule("drop_center[0]", h.drop_center[0], -MAX_BIN_SIZE, MAX_BIN_SIZE, "metres"),
      number_rule("drop_center[1]", h.drop_center[1], -MAX_BIN_SIZE, MAX_BIN_SIZE, "metres"),
      *friction_rules(h),
  ]
  return check_fields(rules, h, source=source, section=section)


def bin_rules(b: Any) -> list[Rule]:
  """Rules of a `dexjax.sim.Bin`: every size in (0, `MAX_BIN_SIZE`] metres."""
  return [number_rule(field, value, 0, MAX_BIN_SIZE, "metres", low_open=True)
          for field, value in (("inner_size[0]", b.inner_size[0]), ("inner_size[1]", b.inner_size[1]),
                               ("wall_height", b.wall_height), ("wall_thickness", b.wall_thickness))]


def settle_rules(s: Any) -> list[Rule]:
  """Upper bounds of the counts of a `dexjax.sim.SettleSettings` (its own ``validate`` checks the rest)."""
  return [
      count_rule("max_steps", s.max_steps, 1, MAX_SETTLE_STEPS,
                 f"physics steps per heap; {MAX_SETTLE_STEPS:,} steps of {s.timestep:g} s simulate "
                 f"{MAX_SETTLE_STEPS * number_or_nan(s.timestep):,g} s"),
      count_rule("chunk_steps", s.chunk_steps, 1, MAX_SETTLE_STEPS, "physics steps between speed checks"),
      count_rule("solver_iterations", s.solver_iterations, 1, MAX_SOLVER_ITERATIONS, "per physics step"),
      count_rule("ls_iterations", s.ls_iterations, 1, MAX_SOLVER_ITERATIONS, "per physics step"),
      count_rule("mjx_batch_size", s.mjx_batch_size, 1, MAX_IMAGES_PER_SHARD, "heaps per compiled call"),
  ]


def _generation_counts(config: Any) -> list[tuple[str, Any, list[Rule]]]:
  """(section, params, rules) of the counts of a generation run that size arrays or loops."""
  pj, suction = config.parallel_jaw_sampler, config.suction_sampler
  supervisor, dataset = config.supervisor, config.dataset
  return [
      ("dataset", dataset, [count_rule("images_per_shard", dataset.images_per_shard, 1, MAX_IMAGES_PER_SHARD),
                            count_rule("images_per_heap", dataset.images_per_heap, 1, MAX_IMAGES_PER_SHARD)]),
      ("reward", config.reward, [("threshold", 0 <= number_or_nan(config.reward.threshold) <= 1,
                                  "a probability in [0, 1]"),
                                 count_rule("num_samples", config.reward.num_samples, 1, MAX_SAMPLES,
                                            "Monte-Carlo draws")]),
      ("samplers.parallel_jaw", pj, [count_rule("num_grasps", pj.num_grasps, 1, MAX_GRASPS, "grasps per image"),
                                     count_rule("num_edges", pj.num_edges, 1, 100 * MAX_STATIC_COUNT, "edge pixels"),
                                     count_rule("depth_samples", pj.depth_samples, 1, MAX_STATIC_COUNT),
                                     count_rule("depth_window", pj.depth_window, 0, MAX_STATIC_COUNT, "pixels"),
                                     count_rule("downsample", pj.downsample, 1, MAX_STATIC_COUNT, "pixels"),
                                     number_rule("friction", pj.friction, 0, MAX_FRICTION, "Coulomb friction")]),
      ("samplers.suction", suction, [count_rule("num_grasps", suction.num_grasps, 1, MAX_GRASPS,
                                                "grasps per image")]),
      ("supervisor", supervisor, [count_rule("num_grasps", supervisor.num_grasps, 1, MAX_GRASPS, "per object"),
                                  count_rule("max_checked", supervisor.max_checked, 1, MAX_GRASPS, "per image"),
                                  count_rule("num_samples", supervisor.num_samples, 1, MAX_SAMPLES,
                                             "Monte-Carlo draws")]),
      ("policy", config.policy, [count_rule("actions_per_gripper", config.policy.actions_per_gripper, 1,
                                            MAX_GRASPS)]),
  ]


def validate_generate_config(config: Any, source: str = "<config>") -> Any:
  """Rules of a `dexjax.generate.GenerateConfig` that its sections' own checks leave out (heap counts and friction,
  the bin's sizes and the settling steps, both grippers and their perturbation models, the reward, samplers,
  supervisor and policy counts); returns ``config``.

  Raises:
    ConfigError: naming ``source``, the dotted field and the expected value.
  """
  validate_heap_distribution(config.heap, source=source, section="heap")
  check_fields(bin_rules(config.bin), config.bin, source=source, section="bin")
  check_fields(settle_rules(config.settle), config.settle, source=source, section="settle")
  settings = config.grippers
  settings.parallel_jaw.validate(source, "grippers.parallel_jaw")
  settings.suction.validate(source, "grippers.suction")
  for name in ("parallel_jaw", "suction"):
    validate_perturbations(settings.perturbations(name), source=source, section=f"perturbations.{name}")
  for section, params, rules in _generation_counts(config):
    check_fields(rules, params, source=source, section=section)
  return config
