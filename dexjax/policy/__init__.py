"""Grasping policies (Dex-Net 4.0's "Policy"): plan a grasp of either gripper on one depth observation.

Every policy is a pytree called as ``policy(key, observation, samples=False) -> GraspAction`` (or
`plan_grasp(key, observation, policy)`): pure, jittable, one observation (`vmap` over keys and observations).

* `CEMPolicy` (`cem_policy`): the Cross-Entropy Method with Gaussian-mixture refitting for one gripper (seed:
  m = 3, n = 250, c = 50, k = 5, gamma = 0.25; `CEMParams`), the mixture fitted by EM in JAX (`dexjax.policy.gmm`);
  optionally its best grasps polished by gradient ascent on the GQ-CNN (`PolishParams`, `polish_grasps`).
* `GreedyComposite`: the ambidextrous choice, the grasp of highest predicted probability across grippers.
* `RankingPolicy`, `RandomPolicy`, `RandomComposite`: sample-and-rank, and uniformly random baselines.
* Heuristic scorers (`SuctionPlanarityCentroid`, `ParallelJawForceClosureCentroid`) and `HeuristicComposite`;
  `depth_instances` segments a depth image into objects by depth jumps (their per-object centroids).
* `GQCNNScorer`: a trained GQ-CNN as the quality function; `make_policy` builds the named policies of
  ``python -m dexjax.plan``.
* `prepare_observation`: real sensor images to an `Observation` (holes inpainted, a segmask from the user, an
  empty-bin image or a floor-plane fit); `load_depth` / `load_segmask` read ``.npy`` and 16-bit PNG files,
  `save_depth` writes the PNG.
"""

from dexjax.policy.actions import GraspAction, PolicySamples, action_from_grasp
from dexjax.policy.cem import CEMParams, CEMPolicy, cem_policy
from dexjax.policy.composite import (GreedyComposite, HeuristicComposite, RandomComposite, greedy_composite_policy,
                                     heuristic_composite_policy, plan_grasp, random_composite_policy)
from dexjax.policy.depth_io import load_depth, load_segmask, save_depth
from dexjax.policy.gmm import (GaussianMixture, fit_gaussian_mixture, gaussian_mixture_log_likelihood,
                               sample_gaussian_mixture)
from dexjax.policy.heuristics import (ParallelJawForceClosureCentroid, SuctionPlanarityCentroid,
                                      composite_heuristic_choice)
from dexjax.policy.instances import DEFAULT_MAX_JUMP, depth_instances
from dexjax.policy.observation import Observation, observation
from dexjax.policy.preprocess import (background_mask, fit_plane, inpaint_depth, plane_mask, prepare_observation)
from dexjax.policy.polish import PolishParams, polish_grasps
from dexjax.policy.presets import (IMAGE_POLICIES, POLICY_NAMES, PRIVILEGED_POLICIES, cem_params, default_sampler,
                                   make_policy)
from dexjax.policy.ranking import RandomPolicy, RankingPolicy, random_policy, ranking_policy
from dexjax.policy.scorers import GRIPPERS, GQCNNScorer

__all__ = [
    'CEMParams', 'CEMPolicy', 'DEFAULT_MAX_JUMP', 'GRIPPERS', 'GQCNNScorer', 'GaussianMixture', 'GraspAction', 'GreedyComposite',
    'HeuristicComposite', 'IMAGE_POLICIES', 'Observation', 'POLICY_NAMES', 'PRIVILEGED_POLICIES',
    'ParallelJawForceClosureCentroid', 'PolicySamples', 'PolishParams', 'polish_grasps',
    'RandomComposite', 'RandomPolicy', 'RankingPolicy', 'SuctionPlanarityCentroid', 'action_from_grasp',
    'background_mask', 'cem_params', 'cem_policy', 'composite_heuristic_choice', 'default_sampler', 'depth_instances',
    'fit_gaussian_mixture',
    'fit_plane', 'gaussian_mixture_log_likelihood', 'greedy_composite_policy', 'heuristic_composite_policy',
    'inpaint_depth', 'load_depth', 'load_segmask', 'make_policy', 'observation', 'plan_grasp', 'plane_mask',
    'prepare_observation', 'random_composite_policy', 'random_policy', 'ranking_policy', 'sample_gaussian_mixture',
    'save_depth',
]
