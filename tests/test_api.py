"""The public surface: a short, deliberate top level, an ``__all__`` per package, no module shadowing a name."""

from __future__ import annotations

import importlib
import pkgutil
import types

import pytest

import dexjax

PACKAGES = ("config", "contacts", "data", "generate", "geometry", "models", "objects", "quality", "render",
            "sampling", "sim", "train")


def _package_modules():
  """(package, [submodule names]) of every dexjax package (CLI entry points aside)."""
  out = []
  for name in PACKAGES:
    module = importlib.import_module(f"dexjax.{name}")
    if hasattr(module, "__path__"):
      out.append((module, [m.name for m in pkgutil.iter_modules(module.__path__) if m.name != "__main__"]))
  return out


def test_top_level_is_the_intended_short_surface():
  names = dir(dexjax)
  assert names == sorted(dexjax.__all__)
  assert len(names) < 60, len(names)
  for name in dexjax.__all__:
    getattr(dexjax, name)  # every listed name resolves (lazy subpackages included)
  for hidden in ("atomic_write_npz", "sdf", "cache_key", "sdf_value", "evaluate"):
    assert hidden not in names
  subpackages = {n for n in dexjax.__all__ if isinstance(getattr(dexjax, n), types.ModuleType)}
  assert subpackages == set(PACKAGES)


def test_every_package_declares_all_and_its_names_resolve():
  for module, _ in _package_modules():
    assert isinstance(getattr(module, "__all__", None), list), module.__name__
    assert len(set(module.__all__)) == len(module.__all__), module.__name__
    for name in module.__all__:
      value = getattr(module, name)
      assert not isinstance(value, types.ModuleType), f"{module.__name__}.{name} is a module in __all__"


def test_no_module_shadows_a_name():
  """A submodule ``P.m`` must stay the module after the whole package is imported: a function or class called
  ``m`` exported by ``P`` (or by a star import) would make ``P.m`` mean two things."""
  for module, submodules in _package_modules():
    for sub in submodules:
      loaded = importlib.import_module(f"{module.__name__}.{sub}")
      assert getattr(module, sub) is loaded, f"{module.__name__}.{sub}"
      assert sub not in module.__all__, f"{module.__name__}.{sub}"


#: File names several packages use for the same role: the package's config dataclasses (and the shared YAML
#: machinery, `dexjax.config`), its report (summary / JSON / metrics), its whole run, its preview pictures.
_PACKAGE_ROLES = {"config", "report", "run", "preview"}


def test_each_module_name_has_one_meaning():
  """No two modules share a file name unless it names the same role in each package (three ``evaluate.py``
  once meant a CLI, a batched grasp evaluation and a model's metrics)."""
  seen: dict[str, str] = {}
  for info in pkgutil.walk_packages(dexjax.__path__, "dexjax."):
    leaf = info.name.rsplit(".", 1)[-1]
    if leaf == "__main__" or info.ispkg or leaf in _PACKAGE_ROLES:
      continue
    assert leaf not in seen, f"{info.name} and {seen[leaf]}"
    seen[leaf] = info.name


@pytest.mark.parametrize("name", ["score_map", "score_image"])
def test_sliding_window_scoring_is_not_called_fc_gqcnn(name):
  """`score_map` / `score_image` are single-depth, axis-aligned sliding windows, not the FC-GQ-CNN of spec 2.3."""
  from dexjax import models
  target = getattr(models, name, None) or getattr(models.GraspQualityModel, name)
  doc = target.__doc__ or ""
  assert "FC-GQ-CNN" not in doc.replace("not the FC-GQ-CNN", "")
