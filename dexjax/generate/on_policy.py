"""On-policy dataset synthesis: the grasps a learned policy considers on an image, as actions to label.

Satish, Mahler and Goldberg (2019, "On-Policy Dataset Synthesis for Learning Robot Grasping Policies Using Fully
Convolutional Deep Networks") found what dexjax's benchmark shows (issue 43): a GQ-CNN trained on the seed's
collection policy (uniform candidates, 1 % supervisor) is accurate on random candidates and wrong where its
planner looks, because the planner maximises the network and finds its false positives. Their remedy is to label
the actions the current policy itself would consider, mixed with the supervisor's guiding samples, and train
again.

A policy planned with ``samples=True`` (`dexjax.policy.cem_policy`, the ranking policy) returns every grasp it
scored in ``action.samples`` (`dexjax.policy.PolicySamples`: R rounds of N grasps, the CEM's initial set and each
resampled set, with the network's score). `policy_candidates` flattens them into the image grasps the labeller
takes as a gripper's candidate set U_g(y) with their scores as priorities: `dexjax.generate.label_image` with
``policy_candidates`` labels the policy's ``top_k`` highest-scored grasps first (its choices and near-choices:
where its false positives are), the other candidate actions uniformly among the rest of what it scored, and the
supervisor's with probability epsilon, as the seed's tau; those rows carry the code `POLICY`.

`collection_policy` is the learned policy a generation run collects with (``collection.policy: on_policy``,
``python -m dexjax.generate --collection-policy on_policy --model RUN``): the CEM of each gripper the models
cover, planned with ``samples=True``; `plan_candidates` turns one plan into ``label_image``'s
``policy_candidates``. The CEM's first round is the sampler's uniform candidates, so the scored set holds the
seed's uniform actions besides the policy's refined ones. `model_digest` names the models' content: the run's
fingerprint covers it, not their path, so a dataset is tied to the weights it was collected with.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from dexjax.policy.actions import PolicySamples
from dexjax.policy.observation import Observation
from dexjax.policy.scorers import GRIPPERS, PARALLEL_JAW, SUCTION
from dexjax.sampling.image_grasps import ImageParallelJawGrasp, ImageSuctionGrasp


def policy_candidates(samples: PolicySamples, gripper: str):
  """The grasps a policy scored, as one gripper's candidate set.

  Args:
    samples: `PolicySamples` of one gripper's plan, (R, N) leading axes.
    gripper: ``'parallel_jaw'`` or ``'suction'``: the image-grasp type to build.
  Returns:
    (grasps, valid, score): `ImageParallelJawGrasp` or `ImageSuctionGrasp` with leading axis C = R N, (C,) bool,
    (C,) float32 (-inf where invalid). A grasp the policy scored in several rounds appears once per round.
  """
  flat = lambda x: x.reshape((-1,) + x.shape[2:])
  center, angle, depth = flat(samples.center), flat(samples.angle), flat(samples.depth)
  valid = flat(samples.valid)
  score = jnp.where(valid, flat(samples.quality), -jnp.inf).astype(jnp.float32)
  if gripper == SUCTION:
    grasps = ImageSuctionGrasp(center=center, angle=angle, depth=depth, approach_angle=flat(samples.approach_angle))
  elif gripper == PARALLEL_JAW:
    grasps = ImageParallelJawGrasp(center=center, angle=angle, depth=depth, width=flat(samples.width))
  else:
    raise ValueError(f'policy_candidates: gripper: expected one of {GRIPPERS}, got {gripper!r}')
  return grasps, valid, score


def model_digest(models: Mapping[str, Any]) -> str:
  """A 16-hex-digit digest of GQ-CNNs by gripper (`dexjax.models.GraspQualityModel`): their description
  (`dexjax.models.saved.model_meta` without its free-form info) and every weight and normalisation array."""
  from dexjax.models.saved import model_meta  # pylint: disable=g-import-not-at-top (flax/orbax import)
  h = hashlib.sha256()
  for gripper in sorted(models):
    model = models[gripper]
    meta = {k: v for k, v in model_meta(model).items() if k != 'info'}
    h.update(json.dumps({'gripper': gripper, **meta}, sort_keys=True).encode())
    for leaf in jax.tree.leaves((model.params, model.normalization)):
      a = np.ascontiguousarray(np.asarray(leaf))
      h.update(f'{a.dtype.str}{a.shape}'.encode())
      h.update(a.tobytes())
  return h.hexdigest()[:16]


def collection_models(path: str, digest: str | None = None) -> tuple[dict[str, Any], str]:
  """(GQ-CNNs by gripper, their `model_digest`) of a training run, saved model or model file (`dexjax.models.
  load_models`: every gripper it holds).

  Raises:
    ValueError: ``digest`` given and the models' is another (the files changed since the run recorded them; the
      message names the path).
  """
  from dexjax.models.shipped import load_models  # pylint: disable=g-import-not-at-top (flax/orbax import)
  models = load_models(path)
  found = model_digest(models)
  if digest is not None and found != digest:
    raise ValueError(f'collection.model {path}: expected the GQ-CNNs of digest {digest} (the run\'s config), found '
                     f'{found}: the model changed since the run started; collect into a new --out')
  return models, found


def collection_policy(models: Mapping[str, Any], cem: str = 'seed'):
  """The learned policy that collects on-policy actions: a CEM per gripper of ``models`` (`dexjax.policy.
  make_policy`: the ambidextrous policy with both, the single-gripper one with one), preset ``cem``."""
  from dexjax.policy.presets import make_policy  # pylint: disable=g-import-not-at-top (loads the policies)
  held = [g for g in GRIPPERS if g in models]
  if not held:
    raise ValueError(f'collection_policy: models: expected a GQ-CNN of {" or ".join(GRIPPERS)}, got none')
  return make_policy('ambidextrous' if len(held) == 2 else held[0], {g: models[g] for g in held}, cem=cem)


def plan_candidates(key: jax.Array, observation: Observation, policy) -> dict[str, tuple]:
  """One plan of a `collection_policy` with its samples, as `dexjax.generate.label_image`'s ``policy_candidates``:
  ``{gripper: (grasps (C,), valid (C,), score (C,))}`` for each gripper the policy plans with (jittable)."""
  action = policy(key, observation, samples=True)
  held = sorted((p.gripper for p in policy.policies), key=GRIPPERS.index)  # the samples' stacking order
  return {g: policy_candidates(jax.tree.map(lambda x, i=i: x[i], action.samples), g) for i, g in enumerate(held)}


__all__ = ['collection_models', 'collection_policy', 'model_digest', 'plan_candidates', 'policy_candidates']
