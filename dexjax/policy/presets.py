"""The named policies of `python -m dexjax.plan` and of the benchmark, built from trained GQ-CNNs.

| name | what it does | models |
|---|---|---|
| ``ambidextrous`` | Dex-Net 4.0: CEM per gripper, then the grasp of highest predicted probability | both |
| ``parallel_jaw`` / ``suction`` | CEM with that gripper's GQ-CNN only | that gripper's |
| ``ranking`` | N candidates per gripper scored by the GQ-CNNs, the best overall (no refinement) | one or both |
| ``random`` | a uniformly random gripper and candidate (its predicted probability reported if a model is given) | none |
| ``suction_heuristic`` | suction planarity-centroid ranking (Dex-Net 3.0's baseline), approach on the disc's best-fit plane | none |
| ``composite_heuristic`` | the suction or the parallel-jaw force-closure heuristic, by a fixed rule | none |
| ``supervisor`` | the best robust grasp in the true bin (privileged state: the benchmark's ceiling) | none |

The samplers are the ones that drew the training candidates (`dexjax.generate` defaults: the Dex-Net 4.0 values),
with their border widened, if needed, so a model's rotated crop window stays inside the image:
ceil(sqrt(2) window / 2) pixels (gqcnn's rule; 68 for 96-pixel windows). The ranking policy scores
``num_candidates`` grasps per gripper (default 400, the network evaluations of one seed-default CEM plan).
The heuristics' centroid term uses each object's own centroid, the objects segmented from the image by depth jumps
of `DEFAULT_MAX_JUMP` (`dexjax.policy.depth_instances`; gqcnn's default centroid is the whole segmask's).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from dexjax.models.saved import GraspQualityModel
from dexjax.policy.cem import CEMParams, CEMPolicy
from dexjax.policy.composite import GreedyComposite, HeuristicComposite, RandomComposite
from dexjax.policy.heuristics import ParallelJawForceClosureCentroid, SuctionPlanarityCentroid
from dexjax.policy.instances import DEFAULT_MAX_JUMP
from dexjax.policy.polish import PolishParams
from dexjax.policy.ranking import RandomPolicy, RankingPolicy
from dexjax.policy.scorers import GRIPPERS, PARALLEL_JAW, SUCTION, GQCNNScorer
from dexjax.sampling.image_samplers import AntipodalImageSampler, SuctionImageSampler

POLICY_NAMES = ('ambidextrous', 'parallel_jaw', 'suction', 'ranking', 'random', 'suction_heuristic',
                'composite_heuristic', 'supervisor')
PRIVILEGED_POLICIES = ('supervisor',)
"""Policies that read the true state of a simulated bin, not only the image: benchmark-only references."""
IMAGE_POLICIES = tuple(name for name in POLICY_NAMES if name not in PRIVILEGED_POLICIES)
"""Policies that plan on a depth image alone (`plan_grasp`, ``python -m dexjax.plan``)."""
CEM_PRESETS = ('seed', 'gqcnn')
CEM_POLICIES = ('ambidextrous', 'parallel_jaw', 'suction')
RANKING_CANDIDATES = 400


def required_grippers(name: str) -> tuple[str, ...]:
  """The grippers whose GQ-CNN policy ``name`` needs (``ranking`` and ``random`` use whichever are given)."""
  _check_name(name)
  return {'ambidextrous': GRIPPERS, 'parallel_jaw': (PARALLEL_JAW,), 'suction': (SUCTION,)}.get(name, ())


def uses_models(name: str) -> bool:
  """Whether policy ``name`` scores grasps with GQ-CNNs (``random`` only reports their probability)."""
  _check_name(name)
  return name in ('ambidextrous', 'parallel_jaw', 'suction', 'ranking', 'random')


def _check_name(name: str) -> None:
  if name not in POLICY_NAMES:
    raise ValueError(f'policy: expected one of {", ".join(POLICY_NAMES)}, got {name!r}')


def default_sampler(gripper: str, crop_window: int = 96, num_grasps: int = 100):
  """The gripper's image sampler (generation defaults) for a model reading ``crop_window``-pixel windows."""
  boundary = max(68.0, float(math.ceil(math.sqrt(2.0) * crop_window / 2)))
  if gripper == PARALLEL_JAW:
    return AntipodalImageSampler(boundary=boundary, num_grasps=num_grasps)
  if gripper == SUCTION:
    return SuctionImageSampler(boundary=boundary, num_grasps=num_grasps)
  raise ValueError(f'gripper: expected one of {GRIPPERS}, got {gripper!r}')


def cem_params(preset: str, gripper: str) -> CEMParams:
  """``'seed'``: the seed's CEM (m 3, n 250, c 50, k 5, gamma 0.25); ``'gqcnn'``: gqcnn's Dex-Net 4.0 configs."""
  if preset == 'seed':
    return CEMParams()
  if preset == 'gqcnn':
    return CEMParams.gqcnn_dexnet4(gripper)
  raise ValueError(f'cem: expected one of {CEM_PRESETS}, got {preset!r}')


def _window(models: Mapping[str, GraspQualityModel], gripper: str) -> int:
  return models[gripper].crop_window if gripper in models else 96


def make_policy(name: str, models: Mapping[str, GraspQualityModel] | None = None, *, cem: str = 'seed',
                num_candidates: int = RANKING_CANDIDATES, polish: PolishParams | None = None, world: Any = None):
  """The policy ``name`` (see the module table) as a pytree to pass to `dexjax.policy.plan_grasp`.

  Args:
    name: one of `POLICY_NAMES`.
    models: GQ-CNNs by gripper (``'parallel_jaw'``, ``'suction'``); None: the shipped models
      (`dexjax.models.pretrained`) of the grippers the policy scores with.
    cem: CEM preset, ``'seed'`` or ``'gqcnn'``.
    num_candidates: candidates per gripper of the ranking, random and heuristic policies.
    polish: None, or `PolishParams`: the CEM policies polish their best grasps by gradient ascent on the GQ-CNN
      (`dexjax.policy.polish`).
    world: the `dexjax.bench.PickingWorld` a privileged policy (``supervisor``) reads the true bin of.

  Returns:
    A pytree for `dexjax.policy.plan_grasp`, or for ``supervisor`` a `dexjax.bench.SupervisorPolicy` (its planner
    needs the bin's true state: `dexjax.bench.run_trial` gives it).

  Raises:
    ValueError: unknown name or preset; a model the policy needs is missing (the message names it); a model of
      the wrong gripper; ``polish`` for a policy that is not a CEM policy, or with an invalid field; ``supervisor``
      without a ``world``.
  """
  _check_name(name)
  if name in PRIVILEGED_POLICIES:
    if world is None:
      raise ValueError(f"policy {name!r}: reads the true state of a simulated bin; it needs the benchmark's world "
                       "(python -m dexjax.benchmark --policy supervisor)")
    from dexjax.bench.supervisor_policy import supervisor_policy  # pylint: disable=g-import-not-at-top
    return supervisor_policy(world)
  if models is None:
    from dexjax.models.shipped import pretrained  # pylint: disable=g-import-not-at-top (flax/orbax import)
    models = {g: pretrained(g) for g in (GRIPPERS if uses_models(name) else ())}
  models = dict(models)
  for gripper, model in models.items():
    if model.gripper != gripper:
      raise ValueError(f"models[{gripper!r}]: expected a {gripper} GQ-CNN, got a {model.gripper} one")
  missing = [g for g in required_grippers(name) if g not in models]
  if missing:
    raise ValueError(f"policy {name!r}: needs a GQ-CNN of {' and '.join(missing)} (--model: a training run with "
                     f"'<gripper>/best', or that gripper's saved model); have {sorted(models) or 'none'}")
  if num_candidates < 1:
    raise ValueError(f'num_candidates: expected an integer >= 1, got {num_candidates}')
  if polish is not None:
    if name not in CEM_POLICIES:
      raise ValueError(f"polish: only the CEM policies ({', '.join(CEM_POLICIES)}) polish their grasps; "
                       f"policy {name!r} does not")
    polish = polish.validate()
  sampler = lambda g, n=num_candidates: default_sampler(g, _window(models, g), n)
  if name in CEM_POLICIES:
    subs = tuple(CEMPolicy(GQCNNScorer(models[g]), sampler(g), cem_params(cem, g).validate(), polish)
                 for g in required_grippers(name))
    return GreedyComposite(subs)
  if name == 'ranking':
    if not models:
      raise ValueError("policy 'ranking': needs at least one GQ-CNN (--model)")
    return GreedyComposite(tuple(RankingPolicy(GQCNNScorer(models[g]), sampler(g)) for g in GRIPPERS if g in models))
  if name == 'random':
    return RandomComposite(tuple(RandomPolicy(sampler(g), GQCNNScorer(models[g]) if g in models else None)
                                 for g in GRIPPERS))
  # Per-object centroids from the image's depth instances: the segmask's centroid is the bin's (heuristics doc).
  # The suction heuristic approaches along its disc's best-fit plane, not the noisy pixel normal (heuristics doc).
  suction = RankingPolicy(SuctionPlanarityCentroid(instance_jump=DEFAULT_MAX_JUMP, fit_approach=2), sampler(SUCTION))
  if name == 'suction_heuristic':
    return GreedyComposite((suction,))
  jaws = ParallelJawForceClosureCentroid(instance_jump=DEFAULT_MAX_JUMP)
  return HeuristicComposite(suction=suction, parallel_jaw=RankingPolicy(jaws, sampler(PARALLEL_JAW)))


__all__ = ['CEM_POLICIES', 'CEM_PRESETS', 'IMAGE_POLICIES', 'POLICY_NAMES', 'PRIVILEGED_POLICIES', 'RANKING_CANDIDATES', 'cem_params',
           'default_sampler', 'make_policy',
           'required_grippers', 'uses_models']
