"""dexjax: Dex-Net 4.0 rebuilt as a JAX library.

The top level holds what a researcher composes: the grasp and gripper pytrees, the analytic quality functions
(nominal, robust Monte-Carlo, batched over grasp sets, and the heap reward S(x, u)), object models and object
sets, and the 3-D and image-space grasp samplers. Every function works on a single item; batch with `jax.vmap`.

Everything else lives in its subpackage, each with a deliberate ``__all__``:

* `dexjax.geometry` -- meshes, signed distance grids, the `ObjectModel` pytree, SO(3) helpers;
* `dexjax.objects` -- built-in and procedural objects, mesh folders, object sets, collision hulls;
* `dexjax.contacts` -- soft-finger jaw contacts and the compliant suction ring;
* `dexjax.quality` -- wrench resistance, nominal and robust quality, the heap reward;
* `dexjax.sampling` -- 3-D samplers on object models, image samplers, grasp-centred crops;
* `dexjax.sim` -- the heap state distribution and MuJoCo settling;
* `dexjax.render` -- cameras, intrinsics files, depth rendering, sensor noise;
* `dexjax.data` -- dataset shards, manifest and the streaming loader;
* `dexjax.generate` -- dataset generation (``python -m dexjax.generate``);
* `dexjax.models` -- Flax GQ-CNNs, normalisation, saved models;
* `dexjax.train` -- GQ-CNN training (``python -m dexjax.train``);
* `dexjax.policy` -- grasping policies on a depth image: CEM, ranking, heuristics, ambidextrous
  (``python -m dexjax.plan``);
* `dexjax.bench` -- the Universal Picking benchmark in simulation: the bin, the judges, trials and the runner
  (``python -m dexjax.benchmark``).

`dexjax.generate`, `dexjax.models` and `dexjax.train` (Flax, optax, orbax) are imported on first use.
"""

import importlib as _importlib

from dexjax import config, contacts, data, geometry, objects, quality, render, sampling, sim
from dexjax.config import ConfigError
from dexjax.geometry import ObjectModel, build_object_model
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp, parallel_jaw_pose, suction_pose
from dexjax.grippers import STANDARD_GRAVITY, SUCTION_PAYLOAD_KG, ParallelJawGripper, SuctionGripper
from dexjax.objects import load_object_model, load_object_set, prepare_object_set
from dexjax.quality import (FAILURE_REASONS, REWARD_FAILURES, Conditions, GraspEvaluation, GraspOutcome, HeapScene,
                            Perturbations, QualityConfig, RewardParams, RewardRecord, RobustQuality, evaluate_grasps,
                            heap_grasp_reward, parallel_jaw_heap_reward, parallel_jaw_perturbations,
                            parallel_jaw_quality, robust_parallel_jaw_quality, robust_suction_quality,
                            suction_heap_reward, suction_perturbations, suction_quality, wrench_residual)
from dexjax.sampling import (sample_antipodal_grasps, sample_antipodal_image_grasps, sample_suction_grasps,
                             sample_suction_image_grasps)

__version__ = "0.1.0"

#: Subpackages imported on first attribute access (heavier dependencies).
_LAZY_SUBPACKAGES = ("generate", "models", "train")

__all__ = [
    # subpackages
    "config", "contacts", "data", "generate", "geometry", "models", "objects", "quality", "render", "sampling",
    "sim", "train",
    # grasps and grippers
    "ParallelJawGrasp", "SuctionGrasp", "parallel_jaw_pose", "suction_pose", "ParallelJawGripper", "SuctionGripper",
    "STANDARD_GRAVITY", "SUCTION_PAYLOAD_KG",
    # quality
    "Conditions", "GraspOutcome", "QualityConfig", "FAILURE_REASONS", "parallel_jaw_quality", "suction_quality",
    "wrench_residual", "Perturbations", "RobustQuality", "parallel_jaw_perturbations", "suction_perturbations",
    "robust_parallel_jaw_quality", "robust_suction_quality", "GraspEvaluation", "evaluate_grasps",
    "HeapScene", "RewardParams", "RewardRecord", "REWARD_FAILURES", "heap_grasp_reward", "parallel_jaw_heap_reward",
    "suction_heap_reward",
    # objects
    "ObjectModel", "build_object_model", "load_object_model", "load_object_set", "prepare_object_set",
    # samplers
    "sample_antipodal_grasps", "sample_suction_grasps", "sample_antipodal_image_grasps",
    "sample_suction_image_grasps",
    # configuration
    "ConfigError", "__version__",
]


def __getattr__(name: str):
  """Imports `dexjax.generate`, `dexjax.models` and `dexjax.train` on first use."""
  if name in _LAZY_SUBPACKAGES:
    return _importlib.import_module(f"{__name__}.{name}")
  raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
  """The intended surface: ``__all__`` (dunder attributes aside)."""
  return sorted(__all__)
