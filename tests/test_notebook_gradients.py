"""``notebooks/gradients.ipynb`` in a real Jupyter kernel, a coarse landscape and 16 ascent starts."""

from __future__ import annotations

import numpy as np


def test_gradients_notebook(run_notebook):
  """The landscape is a probability with finite gradients, higher on the top face's middle than at its edge, where
  the ascent direction points inwards; T = 0 is the hard quality; the ascent runs on both grippers; the cup-radius
  sweep has finite derivatives."""
  # 16 starts and 100 judging draws on procedural:L1/4@23, as in test_smooth_quality.py's ascent test: the same
  # programs, so one of the two files loads them from the session's compilation cache (conftest).
  values = {"landscapes": "landscapes", "smooth": "smooth", "hard_q": "hard_q", "results": "results",
            "slopes": "np.asarray(slopes)", "values": "np.asarray(values)"}
  v = run_notebook("gradients.ipynb", {"GRID": 5, "NUM_STARTS": 16}, values).values

  value, grad = v["landscapes"]["suction"]
  assert value.shape == (5, 5) and grad.shape == (5, 5, 2)
  assert np.all((value >= 0) & (value <= 1)) and np.all(np.isfinite(grad))
  middle, edge = value[2, 2], value[2, 4]  # x = 0 and x = 3.9 cm (the cup overhangs the +x edge)
  assert middle > edge + 0.1, (middle, edge)
  assert grad[2, 4, 0] < 0  # at the +x edge, the ascent direction points to -x
  pj_value, pj_grad = v["landscapes"]["parallel jaw"]
  assert np.all((pj_value >= 0) & (pj_value <= 1)) and np.all(np.isfinite(pj_grad)) and pj_value.max() > 0.1

  assert v["smooth"][-1] == v["hard_q"]  # T = 0 is the hard metric exactly
  for before, after in v["results"].values():  # (whether ascent helps: test_smooth_quality.py, 16 starts)
    assert before.shape == after.shape == (16,) and np.all((after >= 0) & (after <= 1))
  assert np.all(np.isfinite(v["slopes"])) and np.ptp(v["values"]) > 0.05
