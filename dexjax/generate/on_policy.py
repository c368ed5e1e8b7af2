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
"""

from __future__ import annotations

import jax.numpy as jnp

from dexjax.policy.actions import PolicySamples
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


__all__ = ['policy_candidates']
