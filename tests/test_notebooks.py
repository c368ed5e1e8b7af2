"""The notebooks run top to bottom (code cells executed in order, at a smaller batch size)."""

from __future__ import annotations

import json
import pathlib

import matplotlib
import numpy as np

NOTEBOOKS = pathlib.Path(__file__).parent.parent / "notebooks"


def _code(path: pathlib.Path) -> str:
  cells = json.loads(path.read_text())["cells"]
  lines = []
  for cell in cells:
    if cell["cell_type"] == "code":
      lines += [l for l in "".join(cell["source"]).splitlines() if not l.lstrip().startswith(("%", "!"))]
  return "\n".join(lines)


def test_grasp_quality_notebook_runs(cache_dir, monkeypatch):
  monkeypatch.setenv("DEXJAX_CACHE", str(cache_dir))
  matplotlib.use("Agg")
  src = _code(NOTEBOOKS / "grasp_quality.ipynb")
  assert "N = 2000" in src
  scope: dict = {}
  exec(compile(src.replace("N = 2000", "N = 64"), "grasp_quality.ipynb", "exec"), scope)
  p = scope["p_suction"]
  finite = p[~np.isnan(p)]
  assert p.shape == (64,) and finite.size > 32 and np.all((finite >= 0) & (finite <= 1))
  probs = scope["probs"]
  assert float(probs[0]) >= 0.5 and float(probs[-1]) <= 0.2  # light objects hold, past the payload they drop
