"""``notebooks/gradients.ipynb`` in a real Jupyter kernel, a coarse landscape and 16 ascent starts; the ascent's
test on an unseen object is this notebook's."""

from __future__ import annotations

import numpy as np

from dexjax.quality import AscentSettings


def test_gradients_notebook(run_notebook, monkeypatch):
  """The landscape is a probability with finite gradients, higher on the top face's middle than at its edge, where
  the ascent direction points inwards; T = 0 is the hard quality; on a procedural object no other test uses, 20
  ascent steps from 16 sampled grasps raise the hard robust probability (100 independent draws) on average and for
  more grasps than they lower it, for both grippers, within the trust region; the cup-radius sweep has finite
  derivatives."""
  # The notebook is all compilation (184 s from an empty cache, 2026-12-07): its kernel compiles with most of XLA's
  # optimisations off (JAX_DISABLE_MOST_OPTIMIZATIONS, the same programs and results up to rounding), 132 s.
  monkeypatch.setenv("JAX_DISABLE_MOST_OPTIMIZATIONS", "1")
  values = {"landscapes": "landscapes", "smooth": "smooth", "hard_q": "hard_q", "results": "results",
            "shifts": "shifts", "steps": "STEPS", "draws": "DRAWS",
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
  assert (v["steps"], v["draws"]) == (20, 100)
  for name, (before, after) in v["results"].items():
    assert before.shape == after.shape == (16,) and np.all((after >= 0) & (after <= 1))
    assert after.mean() > before.mean(), name
    assert np.sum(after > before) > np.sum(after < before), name
    # the trust region (+ the suction cup's re-projection onto the surface)
    assert np.all(v["shifts"][name] <= AscentSettings().max_translation + 0.006), name
  assert np.all(np.isfinite(v["slopes"])) and np.ptp(v["values"]) > 0.05
