"""Config files: the shipped defaults equal the built-in ones, and bad values name file, field and expectation."""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np
import pytest

from dexjax.config import ConfigError, as_dict, override
from dexjax.grippers import SuctionGripper
from dexjax.quality.report import ReportSettings, load_settings, settings_from_config

SHIPPED = pathlib.Path(__file__).parent.parent / "configs" / "quality.yaml"


def _flat(d, prefix=""):
  out = {}
  for k, v in d.items():
    if isinstance(v, dict):
      out.update(_flat(v, f"{prefix}{k}."))
    else:
      out[f"{prefix}{k}"] = v
  return out


def test_shipped_quality_config_equals_the_defaults():
  got, want = _flat(as_dict(load_settings(SHIPPED))), _flat(as_dict(ReportSettings()))
  assert got.keys() == want.keys()
  for k in want:
    if want[k] is None:
      assert got[k] is None, k
    else:
      np.testing.assert_allclose(got[k], want[k], rtol=1e-7, err_msg=k)


def test_override_keeps_unset_fields_and_types():
  cup = override(SuctionGripper(), {"cup_radius": 0.015, "num_ring_vertices": 12}, source="f.yaml",
                 section="suction")
  assert cup.cup_radius == 0.015 and cup.num_ring_vertices == 12 and cup.cone_height == 0.01
  assert isinstance(cup.cup_radius, float)


@pytest.mark.parametrize("text, field, expected", [
    ("grippers:\n  suction:\n    cup_radius: big\n", "grippers.suction.cup_radius", "finite number"),
    ("grippers:\n  suction:\n    cup_radus: 0.01\n", "grippers.suction.cup_radus", "cup_radius"),
    ("grippers:\n  suction:\n    num_ring_vertices: 8.5\n", "grippers.suction.num_ring_vertices", "integer"),
    ("grippers:\n  vacuum: {}\n", "grippers.vacuum", "parallel_jaw"),
    ("perturbations:\n  suction:\n    friction_range: [0.0]\n", "perturbations.suction.friction_range",
     "list of 2"),
    ("perturbations:\n  parallel_jaw:\n    mass_mean: .nan\n", "perturbations.parallel_jaw.mass_mean", "finite"),
    ("threshold: 1.5\n", "threshold", "[0, 1]"),
    ("num_samples: 0\n", "num_samples", "an integer in [1, 10,000]"),
    ("solver: {}\n", "solver", "quality"),
])
def test_bad_values_name_file_field_and_expectation(tmp_path, text, field, expected):
  path = tmp_path / "my.yaml"
  path.write_text(text)
  with pytest.raises(ConfigError) as e:
    load_settings(path)
  msg = str(e.value)
  assert "my.yaml" in msg and field in msg and expected in msg, msg


def test_unreadable_and_non_mapping_files(tmp_path):
  with pytest.raises(ConfigError, match="missing.yaml"):
    load_settings(tmp_path / "missing.yaml")
  bad = tmp_path / "list.yaml"
  bad.write_text("- 1\n- 2\n")
  with pytest.raises(ConfigError, match="list.yaml.*mapping"):
    load_settings(bad)
  bad.write_text("grippers: [1, 2\n")
  with pytest.raises(ConfigError, match="not valid YAML"):
    load_settings(bad)


def test_empty_config_is_the_default():
  assert settings_from_config({}, "empty.yaml") == dataclasses.replace(ReportSettings())
