"""What every notebook of ``notebooks/`` shares: the Colab-only install cell, a parameter cell, no stored outputs,
a line in notebooks/README.md and a test that runs it in a real kernel (tests/test_notebook_<name>.py)."""

from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
import types

import pytest

from notebook_kernel import NOTEBOOKS, PARAMETERS_TAG, code_cells, parameter_names

ROOT = NOTEBOOKS.parent
PATHS = sorted(NOTEBOOKS.glob("*.ipynb"))
_FIND_SPEC = importlib.util.find_spec  # the real one (the tests patch it)


def _ci_gl_packages() -> list[str]:
  """The Debian packages `.ci/run` installs for headless rendering (the README's set-up command has the same)."""
  match = re.search(r'^gl_packages="([^"]+)"', (ROOT / ".ci" / "run").read_text(), re.M)
  assert match, ".ci/run: gl_packages not found"
  return match.group(1).split()


def _run_install_cell(source: str, monkeypatch, on_colab: bool, installed: bool) -> list:
  """Executes an install cell with ``subprocess.check_call`` recorded (not run); returns the recorded commands."""
  calls = []
  monkeypatch.setattr(subprocess, "check_call", lambda cmd, **kw: calls.append((cmd, kw)) or 0)
  if on_colab:
    monkeypatch.setitem(sys.modules, "google.colab", types.ModuleType("google.colab"))
  else:
    monkeypatch.delitem(sys.modules, "google.colab", raising=False)
  monkeypatch.setattr(importlib.util, "find_spec", lambda n, *a: (None if n == "dexjax" and not installed
                                                                  else _FIND_SPEC(n, *a)))
  monkeypatch.delenv("DEXJAX_PIP_SPEC", raising=False)
  exec(compile(source, "install cell", "exec"), {})  # pylint: disable=exec-used
  return calls


def test_there_is_a_notebook_per_workflow():
  assert {p.stem for p in PATHS} >= {"grasp_quality", "objects_heaps", "depth_images", "generate_train", "policy",
                                     "analysis", "benchmark", "gradients"}


@pytest.mark.parametrize("path", PATHS, ids=lambda p: p.stem)
def test_first_code_cell_installs_on_colab_only(path, monkeypatch):
  """On Colab without dexjax: the GL packages of .ci/run with apt-get, then dexjax with pip; elsewhere, or when
  dexjax is already installed: nothing."""
  source = code_cells(path)[0].source
  assert source == code_cells(PATHS[0])[0].source, f"{path.name}: first code cell differs from {PATHS[0].name}'s"
  assert _run_install_cell(source, monkeypatch, on_colab=False, installed=False) == []
  assert _run_install_cell(source, monkeypatch, on_colab=True, installed=True) == []
  calls = _run_install_cell(source, monkeypatch, on_colab=True, installed=False)
  assert len(calls) == 2, calls
  (apt, apt_kw), (pip, pip_kw) = calls
  assert apt_kw.get("shell") and apt.startswith("apt-get install") and "--no-install-recommends" in apt
  assert all(package in apt.split() for package in _ci_gl_packages()), apt
  assert pip_kw.get("shell") and pip == f"{sys.executable} -m pip install -q 'dexjax'", pip


@pytest.mark.parametrize("path", PATHS, ids=lambda p: p.stem)
def test_second_code_cell_is_the_parameter_cell(path):
  cell = code_cells(path)[1]
  assert PARAMETERS_TAG in cell.metadata.get("tags", []), f"{path.name}: second code cell is not tagged"
  names = parameter_names(cell.source)
  assert names and all(n.isupper() for n in names), names
  lines = [l for l in cell.source.splitlines() if l.strip() and not l.lstrip().startswith("#")]
  assert all(re.match(r"^[A-Z_0-9]+\s*=|^\s", l) or l.strip() in "])}" for l in lines), cell.source


@pytest.mark.parametrize("path", PATHS, ids=lambda p: p.stem)
def test_notebook_is_stored_without_outputs_and_is_tested_and_listed(path):
  for cell in code_cells(path):
    assert not cell.get("outputs") and cell.get("execution_count") is None, f"{path.name}: stored outputs"
  test = ROOT / "tests" / f"test_notebook_{path.stem}.py"
  assert test.exists() and f'"{path.name}"' in test.read_text(), f"{path.name}: no {test.name} runs it"
  readme = (NOTEBOOKS / "README.md").read_text()
  assert f"({path.name})" in readme and f"notebooks/{path.name})" in readme, f"{path.name}: not in notebooks/README.md"
