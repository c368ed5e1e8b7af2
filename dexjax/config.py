"""YAML configuration files mapped onto frozen parameter dataclasses, with errors that name file and field.

A config file is a mapping whose sections override fields of parameter dataclasses (`ParallelJawGripper`,
`Perturbations`, ...). Every value is checked against the type of the field's default: a float field takes a
finite number, an integer field an integer, a tuple field a list of the same length, a bool field a bool.
A nested parameter dataclass (e.g. ``QualityConfig.geometry``) takes a mapping of its own fields.
Anything else (an unknown section or field, a string where a number belongs, a NaN) raises `ConfigError`
naming the file, the dotted field path and what was expected. Range checks (e.g. "positive") are the
caller's, through ``minimum``; the limits of every field (e.g. sizes of a gripper at most 1 m) and the rules
that tie fields together (``min_width <= max_width``, a friction range with ``low <= high``) are checked by
`check_fields` tables: `validate_perturbations`, `validate_heap_distribution` and `validate_generate_config` of
`dexjax.config_rules` (also importable from here), ``validate`` of the grippers.

Every structured file dexjax reads (configs, grasp files, camera and intrinsics files, run records) is parsed by
`parse_yaml` or `parse_json`, which refuse hostile input with a one-line `ConfigError` naming the file, the line
and column and what was expected, before any code recurses through the data: lists or mappings nested deeper
than `MAX_NESTING` levels, YAML aliases that expand past `MAX_YAML_NODES` values or contain themselves, and
duplicate keys in a YAML mapping (which would otherwise silently keep the last value).
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import os
import re
from typing import Any, Mapping

import yaml

# The value rules and limits live in dexjax.config_rules; they are part of this module's interface too.
from dexjax.config_rules import (MAX_GRID_SIZE, ConfigError, Rule, check_fields, count_rule,  # noqa: F401
                                 number_or_nan, number_rule, perturbation_rules, validate_generate_config,
                                 validate_heap_distribution, validate_perturbations)


#: Deepest nesting of lists and mappings accepted in a structured input file (dexjax's own files nest at most
#: 5 levels); deeper input is refused before anything recurses through it (Python's recursion limit is ~1000).
MAX_NESTING = 32

#: Most values (scalars, lists and mappings) a YAML file may expand to through its aliases: a few lines of
#: nested aliases ("billion laughs") would otherwise expand to billions.
MAX_YAML_NODES = 1_000_000

_TOO_DEEP = f"lists or mappings nested deeper than {MAX_NESTING} levels; expected at most {MAX_NESTING} levels deep"


class _RefusedYAML(yaml.MarkedYAMLError):
  """Well-formed YAML that dexjax refuses (duplicate key, too deep, too large, recursive)."""


class StrictLoader(yaml.SafeLoader):  # pylint: disable=too-many-ancestors
  """`yaml.SafeLoader` that refuses duplicate mapping keys, nesting deeper than `MAX_NESTING`, aliases that
  refer to a node containing them, and documents expanding past `MAX_YAML_NODES` values."""

  def __init__(self, stream: Any):
    super().__init__(stream)
    self._open_anchors: list[str | None] = []  # anchors of the collections being composed, outermost first
    self._sizes: dict[int, int] = {}  # id(node) -> values it expands to (aliases counted in full)

  def compose_node(self, parent: Any, index: Any) -> Any:
    """Composes one node, checking depth, recursive aliases and the expanded size before recursing."""
    event = self.peek_event()
    if isinstance(event, yaml.AliasEvent) and event.anchor in self._open_anchors:
      raise _RefusedYAML(None, None, f"the alias *{event.anchor} refers to a list or mapping that contains it; "
                                     "expected no recursive structure", event.start_mark)
    if not isinstance(event, (yaml.SequenceStartEvent, yaml.MappingStartEvent)):
      node = super().compose_node(parent, index)
      self._sizes.setdefault(id(node), 1)
      return node
    if len(self._open_anchors) >= MAX_NESTING:
      raise _RefusedYAML(None, None, _TOO_DEEP, event.start_mark)
    self._open_anchors.append(event.anchor)
    try:
      node = super().compose_node(parent, index)
    finally:
      self._open_anchors.pop()
    self._count(node, event.start_mark)
    return node

  def _count(self, node: Any, mark: Any) -> None:
    """Records the number of values ``node`` expands to; raises `_RefusedYAML` past `MAX_YAML_NODES`."""
    children = itertools.chain.from_iterable(node.value) if isinstance(node, yaml.MappingNode) else node.value
    size = 1 + sum(self._sizes.get(id(child), 1) for child in children)
    if size > MAX_YAML_NODES:
      raise _RefusedYAML(None, None, f"expands to more than {MAX_YAML_NODES:,} values through aliases; expected "
                                     "a small file", mark)
    self._sizes[id(node)] = size

  def construct_mapping(self, node: Any, deep: bool = False) -> dict[Any, Any]:
    """The mapping of ``node``; raises `_RefusedYAML` naming a key given twice (merge keys ``<<`` may be
    overridden, as YAML intends)."""
    if isinstance(node, yaml.MappingNode):
      first: dict[Any, Any] = {}
      for key_node, _ in node.value:
        if key_node.tag == "tag:yaml.org,2002:merge":
          continue
        key = self.construct_object(key_node, deep=True)
        try:
          earlier = first.setdefault(key, key_node.start_mark)
        except TypeError:
          continue  # an unhashable key: SafeLoader reports it
        if earlier is not key_node.start_mark:
          raise _RefusedYAML(None, None, f"duplicate key {key!r} (first at line {earlier.line + 1}); expected each "
                                         "key once per mapping", key_node.start_mark)
    return super().construct_mapping(node, deep=deep)


def _at(mark: Any) -> str:
  """'line L, column C' of a PyYAML mark (1-based)."""
  return f"line {mark.line + 1}, column {mark.column + 1}"


def _expecting(expected: str | None) -> str:
  """'; expected <expected>', or '' for None."""
  return f"; expected {expected}" if expected else ""


def _yaml_error(error: yaml.YAMLError, source: str, expected: str | None) -> ConfigError:
  """A one-line `ConfigError` for a PyYAML error: the file, the line and column, the problem and its context."""
  if isinstance(error, yaml.reader.ReaderError):
    code = error.character if isinstance(error.character, int) else ord(error.character)
    problem = f"not valid YAML: unacceptable character #x{code:04x} ({error.reason}){_expecting(expected)}"
    return ConfigError(source, f"character {error.position + 1}", problem)
  if not isinstance(error, yaml.MarkedYAMLError):
    return ConfigError(source, "", f"not valid YAML: {' '.join(str(error).split())}{_expecting(expected)}")
  mark = error.problem_mark or error.context_mark
  problem = " ".join(str(error.problem or error.context).split())
  if error.context and error.problem and error.context_mark is not None:
    problem += f" ({error.context} at {_at(error.context_mark)})"
  if not isinstance(error, _RefusedYAML):
    problem = f"not valid YAML: {problem}{_expecting(expected)}"
  return ConfigError(source, _at(mark) if mark is not None else "", problem)


def _too_deep(source: str, where: str = "") -> ConfigError:
  """The `ConfigError` of input nested deeper than `MAX_NESTING`."""
  return ConfigError(source, where, _TOO_DEEP)


def parse_yaml_documents(text: str, source: str, *, expected: str | None = "a YAML mapping") -> list[Any]:
  """Every document of the YAML ``text`` (from the file ``source``), read with `StrictLoader`.

  Raises:
    ConfigError: one line naming ``source``, the line and column, the problem and ``expected`` (None: the
      caller says what it expected): malformed YAML, a duplicate key, nesting deeper than `MAX_NESTING`, an
      alias inside its own anchor, aliases expanding past `MAX_YAML_NODES` values.
  """
  try:
    return list(yaml.load_all(text, Loader=StrictLoader))  # nosec B506: StrictLoader is a SafeLoader
  except yaml.YAMLError as e:
    raise _yaml_error(e, source, expected) from None
  except RecursionError:
    raise _too_deep(source) from None


def parse_yaml(text: str, source: str, *, expected: str | None = "a YAML mapping") -> Any:
  """The single document of the YAML ``text`` (None if empty); errors as `parse_yaml_documents`."""
  documents = parse_yaml_documents(text, source, expected=expected)
  if len(documents) > 1:
    raise ConfigError(source, "", f"holds {len(documents)} YAML documents (separated by '---'); expected one"
                                  f"{', ' + expected if expected else ''}")
  return documents[0] if documents else None


_JSON_STRING = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"')
_JSON_TOKEN = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"|[\[\]{}]')
_NOT_BRACKET = re.compile(r"[^\[\]{}]+")
_BRACKET_STEP = {"[": 1, "{": 1, "]": -1, "}": -1}


def _json_too_deep(text: str) -> int | None:
  """Offset in the JSON ``text`` of the first bracket nested deeper than `MAX_NESTING` (brackets in strings
  do not count), or None. A quick count in C first; the position is only searched for in deep text."""
  brackets = _NOT_BRACKET.sub("", _JSON_STRING.sub("", text))
  if max(itertools.accumulate(map(_BRACKET_STEP.__getitem__, brackets)), default=0) <= MAX_NESTING:
    return None
  depth = 0
  for token in _JSON_TOKEN.finditer(text):
    depth += _BRACKET_STEP.get(token.group(), 0)
    if depth > MAX_NESTING:
      return token.start()
  return None


class _DuplicateKey(ValueError):
  """A JSON object names one key twice (`json` would silently keep the last value)."""

  def __init__(self, key: str):
    super().__init__(key)
    self.key = key


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
  """`json` ``object_pairs_hook``: the object's dict; raises `_DuplicateKey` for a key given twice."""
  data = dict(pairs)
  if len(data) != len(pairs):
    seen: set[str] = set()
    raise _DuplicateKey(next(k for k, _ in pairs if k in seen or seen.add(k)))
  return data


def parse_json(text: str, source: str, *, expected: str | None = "a JSON object") -> Any:
  """The decoded JSON ``text`` (from the file ``source``), its nesting checked before decoding.

  Raises:
    ConfigError: one line naming ``source``, the line and column, the problem and ``expected`` (None: the
      caller says what it expected): malformed JSON, nesting deeper than `MAX_NESTING`, or a key given twice in
      one object (as `parse_yaml`).
  """
  offset = _json_too_deep(text)
  if offset is not None:
    line, column = text.count("\n", 0, offset) + 1, offset - text.rfind("\n", 0, offset)
    raise _too_deep(source, f"line {line}, column {column}")
  try:
    return json.loads(text, object_pairs_hook=_unique_keys)
  except _DuplicateKey as e:
    raise ConfigError(source, "", f"duplicate key {e.key!r} in one JSON object; expected each key once") from None
  except json.JSONDecodeError as e:
    raise ConfigError(source, f"line {e.lineno}, column {e.colno}",
                      f"not valid JSON: {e.msg}{_expecting(expected)}") from None
  except ValueError as e:  # an integer of more digits than Python converts (sys.get_int_max_str_digits)
    raise ConfigError(source, "", f"not usable JSON: {e}{_expecting(expected)}") from None
  except RecursionError:
    raise _too_deep(source) from None


def load_yaml(path: str | os.PathLike[str]) -> dict[str, Any]:
  """Reads a YAML mapping from ``path`` (an empty file is an empty mapping) with `parse_yaml`.

  Raises:
    ConfigError: the file cannot be read, is not UTF-8 text, is not a YAML mapping or is refused by
      `parse_yaml` (naming the file, and the line and column where known).
  """
  path = os.fspath(path)
  try:
    with open(path, encoding="utf-8") as f:
      text = f.read()
  except OSError as e:
    raise ConfigError(path, "", f"cannot read the file ({e.strerror})") from None
  except UnicodeDecodeError as e:
    raise ConfigError(path, "", f"not a text file (byte {e.start} is not UTF-8); expected a YAML mapping") from None
  data = parse_yaml(text, path, expected="a YAML mapping of config sections")
  if data is None:
    return {}
  if not isinstance(data, dict):
    raise ConfigError(path, "", f"expected a mapping of sections at the top level, got {type(data).__name__}")
  return data


def number_hint(value: Any) -> str:
  """A hint for a number YAML 1.1 reads as a string (``1e9``: without a decimal point or an exponent sign): how
  to write it so that it is a number (`` (YAML 1.1 reads 1e9 as a string; write 1.0e+9)``); '' for any other
  value."""
  if not isinstance(value, str) or "e" not in value.lower():
    return ""
  try:
    if not math.isfinite(float(value)):
      return ""
  except ValueError:
    return ""
  mantissa, _, exponent = value.strip().lower().partition("e")
  mantissa = mantissa if "." in mantissa else f"{mantissa}.0"
  exponent = exponent if exponent[:1] in "+-" else f"+{exponent}"
  fixed = f"{mantissa}e{exponent}"
  if not isinstance(yaml.safe_load(fixed), float):
    return ""
  return f" (YAML 1.1 reads {value.strip()} as a string; write {fixed})"


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
      raise ConfigError(source, field, f"expected a finite number, got {value!r}{number_hint(value)}")
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
  if dataclasses.is_dataclass(default) and not isinstance(default, type):
    return override(default, value, source=source, section=field, minimum=minimum)
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


def plain_json(value: Any, *, nan_to_none: bool = False) -> Any:
  """JSON-ready copy of nested mappings and sequences: keys to strings, tuples to lists, NumPy scalars and
  arrays to Python numbers and lists; with ``nan_to_none``, NaN and infinities to None (JSON has no NaN)."""
  if isinstance(value, Mapping):
    return {str(k): plain_json(v, nan_to_none=nan_to_none) for k, v in value.items()}
  if isinstance(value, (list, tuple)):
    return [plain_json(v, nan_to_none=nan_to_none) for v in value]
  if hasattr(value, "tolist"):
    return plain_json(value.tolist(), nan_to_none=nan_to_none)
  if nan_to_none and isinstance(value, float) and not math.isfinite(value):
    return None
  return value


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
