"""Baselines that may be missing: a benchmark still measures dexjax without them and marks only the baseline (and
every ratio against it) as missing, with the reason.

The baselines need packages dexjax does not (``pip install -e ".[bench]"``; pyrender without its dependencies):
cvxopt, pybullet, pyrender, scikit-learn and threadpoolctl.
"""

from __future__ import annotations

import importlib
from types import ModuleType


def import_optional(name: str) -> tuple[ModuleType | None, str | None]:
  """(module, None), or (None, the reason: ``'ModuleNotFoundError: No module named ...'``) when ``name`` or a module
  it imports is missing."""
  try:
    return importlib.import_module(name), None
  except ImportError as e:
    return None, f'{type(e).__name__}: {e}'


def missing(reason: str) -> dict:
  """The report entry of a baseline that was not measured."""
  return {'status': 'missing', 'error': reason}


def version(name: str) -> str | None:
  """The installed version of distribution ``name``, or None."""
  try:
    return importlib.import_module('importlib.metadata').version(name)
  except Exception:  # pylint: disable=broad-except
    return None
