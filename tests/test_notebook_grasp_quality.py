"""``notebooks/grasp_quality.ipynb`` in a real Jupyter kernel, with fewer grasps."""

from __future__ import annotations

import numpy as np


def test_grasp_quality_notebook(run_notebook):
  """Batched robust probabilities of sampled suction grasps lie in [0, 1]; light objects hold on the cup, objects
  past its payload drop; the figures are drawn."""
  run = run_notebook("grasp_quality.ipynb", {"N": 64},
                     {"p_suction": "p_suction", "p_pj": "p_pj", "probs": "probs", "masses": "masses"})
  p = run.values["p_suction"]
  finite = p[~np.isnan(p)]
  assert p.shape == (64,) and finite.size > 32 and np.all((finite >= 0) & (finite <= 1))
  assert run.values["p_pj"].shape == (64,)
  probs = run.values["probs"]
  assert float(probs[0]) >= 0.5 and float(probs[-1]) <= 0.2  # light objects hold, past the payload they drop
  assert run.images() == 2  # the grasps coloured by probability, the payload curve
  assert "robust grasps/s" in run.stdout()
  assert "cpu_aot" not in run.stderr(), run.stderr()[:2000]  # cache hits print no XLA:CPU AOT warning (issue 44)
