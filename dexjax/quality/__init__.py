"""Analytic grasp quality: wrench resistance, deterministic and robust (Monte-Carlo) quality, heap rewards."""

from dexjax.quality.batched import GraspEvaluation, evaluate_grasps, split_over_devices
from dexjax.quality.grasp_quality import (FAILURE_REASONS, Conditions, GraspOutcome, QualityConfig,
                                          external_wrench, parallel_jaw_quality, suction_quality)
from dexjax.quality.robust import (REWARD_SAMPLES, REWARD_THRESHOLD, SUPERVISOR_SAMPLES, SUPERVISOR_THRESHOLD,
                                   Perturbations, RobustQuality, nominal_conditions, parallel_jaw_perturbations,
                                   map_draws, perturb_parallel_jaw_grasp, perturb_suction_grasp,
                                   robust_jaw_samples, robust_parallel_jaw_quality, robust_suction_quality,
                                   sample_attempt, sample_conditions, suction_perturbations,
                                   with_known_friction, with_known_mass, with_object_mass)
from dexjax.quality.gripper_geometry import GripperGeometry, jaw_collides, jaw_collision_points
from dexjax.quality.heap_reward import (REWARD_FAILURES, HeapScene, RewardParams, RewardRecord, heap_grasp_reward,
                                        heap_scene,
                                        parallel_jaw_collisions, parallel_jaw_heap_reward, stack_models,
                                        suction_collisions, suction_heap_reward)
from dexjax.quality.wrench import NNLSResult, lift_bounded_groups, nnls, resists, wrench_residual
from dexjax.quality.smooth import (ParallelJawMargins, Smoothing, SuctionMargins, parallel_jaw_margins,
                                   smooth_robust_parallel_jaw_quality, smooth_robust_suction_quality, suction_margins)
from dexjax.quality.grasp_optimization import AscentResult, AscentSettings, move_grasp, optimize_grasp

__all__ = [
    "GraspEvaluation", "evaluate_grasps", "split_over_devices", "FAILURE_REASONS", "Conditions", "GraspOutcome",
    "QualityConfig", "external_wrench", "parallel_jaw_quality", "suction_quality", "REWARD_SAMPLES", "REWARD_THRESHOLD",
    "SUPERVISOR_SAMPLES", "SUPERVISOR_THRESHOLD", "Perturbations", "RobustQuality", "nominal_conditions",
    "parallel_jaw_perturbations", "perturb_parallel_jaw_grasp", "perturb_suction_grasp",
    "robust_parallel_jaw_quality", "robust_suction_quality", "sample_conditions", "suction_perturbations", "with_known_friction", "with_known_mass",
    "with_object_mass",
    "NNLSResult", "lift_bounded_groups", "nnls", "resists", "wrench_residual", "GripperGeometry", "jaw_collides",
    "jaw_collision_points", "REWARD_FAILURES",
    "HeapScene", "RewardParams", "RewardRecord", "heap_grasp_reward", "heap_scene", "parallel_jaw_collisions",
    "parallel_jaw_heap_reward", "stack_models", "suction_collisions", "suction_heap_reward",
    "ParallelJawMargins", "Smoothing", "SuctionMargins", "parallel_jaw_margins", "smooth_robust_parallel_jaw_quality",
    "smooth_robust_suction_quality", "suction_margins", "AscentResult", "AscentSettings", "move_grasp",
    "optimize_grasp", "sample_attempt", "map_draws", "robust_jaw_samples",
]
