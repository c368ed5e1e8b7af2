"""``notebooks/policy.ipynb`` in a real Jupyter kernel, with small CEM and candidate counts."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

_ACTION = "dict(center=np.asarray({a}.center), valid=bool({a}.valid), probability=float({a}.probability), " \
          "pose=np.asarray({a}.pose), gripper={a}.gripper_name)"


def test_policy_notebook(run_notebook):
  """Every policy plans a grasp on an object of the rendered heap; the CEM keeps m + 1 rounds of samples; a noisy
  image with holes is prepared (inpainted, background-segmented) and planned on."""
  small = {"NUM_SEED": 40, "NUM_RESAMPLE": 16, "NUM_ITERATIONS": 1, "NUM_CANDIDATES": 48}
  values = {
      "objects": "objects",
      "policy_names": "list(IMAGE_POLICIES)",
      "actions": "{k: " + _ACTION.format(a="a") + " for k, a in actions.items()}",
      "per_gripper_valid": "np.asarray(actions['ambidextrous'].per_gripper.valid)",
      "per_gripper_probability": "np.asarray(actions['ambidextrous'].per_gripper.probability)",
      "m": "CEM.num_iterations",
      "samples_valid": "samples['valid']",
      "picture_shape": "picture.shape",
      "info": "info",
      "noisy": "noisy",
      "real_depth": "np.asarray(real_obs.depth)",
      "real_mask": "np.asarray(real_obs.mask)",
      "real_action": _ACTION.format(a="real_action"),
      "same_structure": "jax.tree.structure(real_obs) == jax.tree.structure(obs)",
  }
  v = run_notebook("policy.ipynb", small, values).values
  objects = v["objects"]
  assert objects.shape == (500, 500) and 0.01 < objects.mean() < 0.5

  def pixel(action):
    u, w = np.floor(np.asarray(action["center"]) + 0.5).astype(int)
    return w, u

  actions = v["actions"]
  assert set(actions) == set(v["policy_names"])
  for name, action in actions.items():
    assert action["valid"], name
    # Grasps are centred on the mask (here the rendered objects); see the notebook's note on parallel-jaw centres.
    assert objects[pixel(action)], f"{name}: grasp centre {action['center']} is not on an object"
    assert np.isfinite(action["probability"]) and 0.0 <= action["probability"] <= 1.0, name
    assert np.all(np.isfinite(action["pose"])), name
  assert np.all(v["per_gripper_valid"])  # one CEM plan per gripper
  assert actions["ambidextrous"]["probability"] == float(np.max(v["per_gripper_probability"]))  # argmax over grippers
  assert actions["parallel_jaw"]["gripper"] == "parallel_jaw" and actions["suction"]["gripper"] == "suction"

  m, valid = v["m"], v["samples_valid"]
  assert m == 1 and valid.shape == (2, m + 1, 40)  # (grippers, rounds, max(n, c))
  counts = valid.sum(axis=-1)
  assert np.all(counts[:, 0] > 0) and np.all((counts[:, 1:] > 0) & (counts[:, 1:] <= 16)), counts
  rows, cols = v["picture_shape"][:2]  # save_plan_png: one panel per round (m + 1) and the plan
  assert len(v["picture_shape"]) == 3 and cols > 2 * rows

  info, depth, mask, noisy = v["info"], v["real_depth"], v["real_mask"], v["noisy"]
  assert info["segmentation"] == "background" and info["invalid_fraction"] > 0.04
  assert np.all(np.isfinite(depth) & (depth > 0))  # holes inpainted
  assert not np.any(mask & (noisy <= 0))  # no grasp centred on a hole
  assert (mask & objects).sum() > 0.9 * mask.sum() and (mask & objects).sum() > 0.5 * objects.sum()
  real_action = v["real_action"]
  assert real_action["valid"] and mask[pixel(real_action)]
  assert ndimage.binary_dilation(objects, iterations=2)[pixel(real_action)]
  assert v["same_structure"]
