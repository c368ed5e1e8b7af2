"""YAML configuration files mapped onto frozen parameter dataclasses, with errors that name file and field.

A config file is a mapping whose sections override fields of parameter dataclasses (`ParallelJawGripper`,
`Perturbations`, ...). Every value is checked against the type of the field's default: a float field takes a
finite number, an integer field an integer, a tuple field a list of the same length, a bool field a bool.
Anything else (an unknown section or field, a string where a number belongs, a NaN) raises `ConfigError`
naming the file, the dotted field path and what was expected. Range checks (e.g. "positive") are the
caller's, through ``minimum``.
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Any, Mapping

import yaml


class ConfigError(ValueError):
  """A configuration file or value is invalid; the message names the file, the field and the expected value."""

  def __init__(self, source: str, field: str, problem: str):
    self.source, self.field, self.problem = source, field, problem
    where = f"{source}: {field}" if field else source
    super().__init__(f"{where}: {problem}")


def load_yaml(path: str | os.PathLike[str]) -> dict[str, Any]:
  """Reads a YAML mapping from ``path`` (an empty file is an empty mapping)."""
  path = os.fspath(path)
  try:
    with open(path) as f:
      data = yaml.safe_load(f)
  except OSError as e:
    raise ConfigError(path, "", f"cannot read the file ({e.strerror})") from None
  except yaml.YAMLError as e:
    raise ConfigError(path, "", f"not valid YAML ({e})") from None
  if data is None:
    return {}
  if not isinstance(data, dict):
    raise ConfigError(path, "", f"expected a mapping of sections at the top level, got {type(data).__name__}")
  return data


def _coerce(default: Any, value: Any, source: str, field: str, minimum: float | None) -> Any:
  """``value`` converted to the type of ``default``, or a `ConfigError`."""
  if isinstance(default, bool):
    if not isinstance(value, bool):
      raise ConfigError(source, field, f"expected true or false, got {value!r}")
    return value
  if isinstance(default, int):
    if isinstance(value, bool) or not isinstance(value, int):
      raise ConfigError(source, field, f"expected an integer, got {value!r}")
    if minimum is not None and value < minimum:
      raise ConfigError(source, field, f"expected an integer >= {minimum:g}, got {value}")
    return value
  if isinstance(default, float):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
      raise ConfigError(source, field, f"expected a finite number, got {value!r}")
    if minimum is not None and value < minimum:
      raise ConfigError(source, field, f"expected a number >= {minimum:g}, got {value}")
    return float(value)
  if isinstance(default, tuple):
    if not isinstance(value, (list, tuple)) or len(value) != len(default):
      raise ConfigError(source, field, f"expected a list of {len(default)} values, got {value!r}")
    return tuple(_coerce(d, v, source, f"{field}[{i}]", minimum) for i, (d, v) in enumerate(zip(default, value)))
  if isinstance(default, str):
    if not isinstance(value, str):
      raise ConfigError(source, field, f"expected a string, got {value!r}")
    return value
  raise ConfigError(source, field, "this field cannot be set from a config file")


def override(params: Any, values: Mapping[str, Any] | None, *, source: str, section: str,
             minimum: float | None = None) -> Any:
  """A copy of the dataclass ``params`` with the fields in ``values`` replaced (type-checked).

  Args:
    params: a (frozen) dataclass instance holding the defaults.
    values: field name -> new value, as read from YAML; None or empty leaves ``params`` unchanged.
    source: file name for error messages.
    section: dotted path of this section in the file, for error messages.
    minimum: smallest allowed value of every numeric field (None: no bound).

  Raises:
    ConfigError: ``values`` is not a mapping, names an unknown field, or holds a value of the wrong type.
  """
  if values is None:
    return params
  if not isinstance(values, Mapping):
    raise ConfigError(source, section, f"expected a mapping of field: value, got {values!r}")
  fields = {f.name: f for f in dataclasses.fields(params)}
  changes = {}
  for name, value in values.items():
    where = f"{section}.{name}" if section else str(name)
    if name not in fields:
      raise ConfigError(source, where, f"unknown field; expected one of {', '.join(fields)}")
    changes[name] = _coerce(getattr(params, name), value, source, where, minimum)
  return dataclasses.replace(params, **changes)


def string_list(value: Any, *, source: str, field: str, what: str) -> tuple[str, ...]:
  """A non-empty list of non-empty strings (a single string counts as a list of one) as a tuple; otherwise
  `ConfigError` naming ``field`` and ``what`` the strings are (e.g. "object sources")."""
  if isinstance(value, str):
    value = [value]
  if not isinstance(value, (list, tuple)) or not value or not all(isinstance(v, str) and v for v in value):
    raise ConfigError(source, field, f"expected a non-empty list of {what}, got {value!r}")
  return tuple(value)


def check_sections(data: Mapping[str, Any], allowed: tuple[str, ...], *, source: str, section: str = "") -> None:
  """Raises `ConfigError` if ``data`` has a key outside ``allowed``."""
  for name in data:
    if name not in allowed:
      where = f"{section}.{name}" if section else str(name)
      raise ConfigError(source, where, f"unknown section; expected one of {', '.join(allowed)}")


def as_dict(obj: Any) -> Any:
  """Nested plain-Python view of a dataclass (arrays become lists), for writing reports and configs."""
  import numpy as np  # local: keeps this module importable without the array stack

  if dataclasses.is_dataclass(obj):
    return {f.name: as_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
  if isinstance(obj, (list, tuple)):
    return [as_dict(x) for x in obj]
  if hasattr(obj, "__array__"):
    return np.asarray(obj).tolist()
  return obj
