"""``python -m dexjax.quality``: sampling and evaluating on built-in objects, and clear errors."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from dexjax.quality.__main__ import main


@pytest.fixture(autouse=True)
def _cache(cache_dir, monkeypatch):
  monkeypatch.setenv("DEXJAX_CACHE", str(cache_dir))


def test_sample_and_evaluate_builtin_box(tmp_path):
  out = tmp_path / "q.json"
  assert main(["builtin:box", "--grid-size", "64", "--gripper", "suction", "--num-grasps", "12", "--seed", "3", "--samples", "4",
               "--out", str(out)]) == 0
  doc = json.loads(out.read_text())
  assert len(doc["grasps"]) == 12
  for g in doc["grasps"]:
    assert g["gripper"] == "suction" and len(g["center"]) == 3 and len(g["pose"]) == 4
    assert g["nominal"] in (0, 1) and 0.0 <= g["robust_probability"] <= 1.0
  assert doc["parameters"]["seed"] == 3 and doc["parameters"]["num_samples"] == 4
  assert "suction" in doc["parameters"]["grippers"]
  # Same seed, same file.
  out2 = tmp_path / "q2.json"
  main(["builtin:box", "--grid-size", "64", "--gripper", "suction", "--num-grasps", "12", "--seed", "3", "--samples", "4",
        "--out", str(out2)])
  assert json.loads(out2.read_text())["grasps"] == doc["grasps"]


def test_evaluate_given_grasps_in_file_order(tmp_path):
  grasps = {"grasps": [
      {"gripper": "parallel_jaw", "center": [0, 0, 0], "axis": [1, 0, 0], "approach": [0, 0, -1]},
      {"gripper": "suction", "center": [0, 0, 0.02], "approach": [0, 0, -1]},
      {"gripper": "suction", "center": [0.019, 0.0, 0.02], "approach": [0, 0, -1]},
      {"gripper": "parallel_jaw", "center": [0.017, 0.017, 0], "axis": [1, -1, 0], "approach": [0, 0, -1],
       "width": 0.05},
  ]}
  src, out = tmp_path / "in.json", tmp_path / "out.json"
  src.write_text(json.dumps(grasps))
  assert main(["builtin:cube", "--grid-size", "64", "--grasps", str(src), "--seed", "0", "--samples", "4",
               "--out", str(out)]) == 0
  got = json.loads(out.read_text())["grasps"]
  assert [g["gripper"] for g in got] == ["parallel_jaw", "suction", "suction", "parallel_jaw"]
  assert got[0]["nominal"] == 1 and got[0]["robust_probability"] > 0.5 and got[0]["width"] == 0.05
  assert got[1]["nominal"] == 1 and got[1]["robust_probability"] > 0.5
  assert got[2]["nominal"] == 0 and got[2]["nominal_failure"] == "no_seal"
  assert got[3]["nominal"] == 0 and got[3]["robust_probability"] < 0.5


def test_bad_grasp_file_names_file_index_and_field(tmp_path, capsys):
  src = tmp_path / "bad.json"
  src.write_text(json.dumps({"grasps": [{"gripper": "suction", "center": [0, 0, 0.02], "approach": [0, 0, -1]},
                                        {"gripper": "suction", "center": [0, "x", 0], "approach": [0, 0, -1]}]}))
  assert main(["builtin:cube", "--grid-size", "64", "--grasps", str(src), "--out", str(tmp_path / "o.json")]) == 2
  err = capsys.readouterr().err
  assert "bad.json" in err and "grasps[1]" in err and "'center'" in err
  src.write_text(json.dumps({"grasps": [{"gripper": "claw", "center": [0, 0, 0], "approach": [0, 0, 1]}]}))
  assert main(["builtin:cube", "--grid-size", "64", "--grasps", str(src), "--out", str(tmp_path / "o.json")]) == 2
  assert "'gripper'" in capsys.readouterr().err


def test_broken_mesh_gives_a_clear_error(tmp_path, capsys):
  bad = tmp_path / "empty.obj"
  bad.write_text("")
  assert main([str(bad), "--gripper", "suction", "--out", str(tmp_path / "o.json")]) == 2
  assert "empty.obj" in capsys.readouterr().err


def test_module_entry_point_runs(tmp_path, cache_dir):
  """``python -m dexjax.quality`` reaches `main` and returns its exit code (an error path: nothing to compile)."""
  bad = tmp_path / "empty.obj"
  bad.write_text("")
  r = subprocess.run([sys.executable, "-m", "dexjax.quality", str(bad), "--gripper", "suction", "--out",
                      str(tmp_path / "o.json")],
                     capture_output=True, text=True, env={**__import__("os").environ, "DEXJAX_CACHE": str(cache_dir)},
                     timeout=300)
  assert r.returncode == 2 and "empty.obj" in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_config_file_sets_gripper_and_perturbations(tmp_path):
  """Values from the file reach the report and the physics (the default 2 cm cup seals at the face centre)."""
  grasps = {"grasps": [{"gripper": "suction", "center": [0, 0, 0.02], "approach": [0, 0, -1]}]}
  src = tmp_path / "in.json"
  src.write_text(json.dumps(grasps))
  cfg = tmp_path / "cup.yaml"
  cfg.write_text("num_samples: 6\nthreshold: 0.75\ngrippers:\n  suction:\n    cup_radius: 0.03\n"
                 "perturbations:\n  suction:\n    mass_mean: 0.05\n")
  from dexjax.quality.report import load_settings
  assert load_settings(cfg).num_samples == 6  # read from the file ...
  out = tmp_path / "o.json"
  assert main(["builtin:cube", "--grid-size", "64", "--grasps", str(src), "--config", str(cfg), "--samples", "4",
               "--out", str(out)]) == 0
  doc = json.loads(out.read_text())
  p = doc["parameters"]
  assert p["num_samples"] == 4 and p["threshold"] == 0.75  # ... and --samples on the command line overrides it
  assert p["grippers"]["suction"]["cup_radius"] == 0.03 and p["grippers"]["suction"]["cone_height"] == 0.01
  assert p["perturbations"]["suction"]["mass_mean"] == 0.05
  # A 6 cm cup does not fit on the 4 cm cube's face: the lip hangs over the edges.
  assert doc["grasps"][0]["nominal_failure"] == "no_seal"


def test_bad_config_names_file_and_field(tmp_path, capsys):
  cfg = tmp_path / "bad.yaml"
  cfg.write_text("grippers:\n  suction:\n    cup_radius: -0.01\n")
  assert main(["builtin:cube", "--gripper", "suction", "--config", str(cfg), "--out", str(tmp_path / "o")]) == 2
  err = capsys.readouterr().err
  assert "bad.yaml" in err and "grippers.suction.cup_radius" in err and ">= 0" in err
  assert not (tmp_path / "o").exists()
