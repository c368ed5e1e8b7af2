"""The Universal Picking benchmark in simulation (seed, "Characterization of Grasping Benchmark"), judged by the
analytic reward and by MuJoCo physics: the simulated bin (`PickingWorld`), the judges (`analytic_judge`,
`physics_judge`), one trial with the seed's stopping rules (`run_trial`), the metrics, the attempt log, and the
runner of whole benchmarks (`run_benchmark`, the engine of ``python -m dexjax.benchmark``), recorded attempts
judged again (`replay_attempt`, ``python -m dexjax.replay``), and each object's
pickability alone in the bin (`set_pickability`, ``python -m dexjax.objects pickable``); docs/benchmark.md."""

from dexjax.bench.analytic_judge import analytic_verdict, world_grasp
from dexjax.bench.attempt_log import AttemptLogError, append_attempt, read_attempts
from dexjax.bench.choice_calibration import CALIBRATION_BINS, calibration, choice_summary, precision_at_choice
from dexjax.bench.collision_rule import collision_samples, gripper_collision, label_collision
from dexjax.bench.execution import PHYSICS_FAILURES, PhysicsOutcome, PhysicsSettings, execute_grasp, receptacle_centre
from dexjax.bench.suction_hold import SealHold, seal_hold, seal_tolerance
from dexjax.bench.judges import Judge, Verdict, analytic_judge, physics_judge
from dexjax.bench.failure_memory import FailureMemory, REPEAT_RADIUS, repeated_attempts
from dexjax.bench.pickability import ObjectPickability, object_pickability, pickability_summary, set_pickability
from dexjax.bench.picking_metrics import (Z_95, MotionModel, cleared_fraction, move_seconds, object_difficulty,
                                          rated_acceleration, reliability, sem_interval, summarize, wilson_interval)
from dexjax.bench.supervisor_policy import SUPERVISOR, SupervisorPolicy, supervisor_policy
from dexjax.bench.protocol import STOP_REASONS, Protocol, stop_reason
from dexjax.bench.runner import (BenchmarkSpec, benchmark_config, benchmark_judges, load_benchmark_config,
                                 run_benchmark, summarize_run)
from dexjax.bench.attempt_replay import (RecordedAttempt, recorded_action, recorded_attempt, replay_attempt,
                                         spec_from_settings)
from dexjax.bench.tool_path import PHASES, PathSettings, ToolPath, move_fraction, tool_path
from dexjax.bench.trial import NO_GRASP, Planner, attempt_keys, run_trial, trial_camera, trial_fill, trial_key
from dexjax.bench.world import BENCHMARK_HULLS, BinState, PickingWorld, object_level

__all__ = [
    'BENCHMARK_HULLS', 'BinState', 'NO_GRASP', 'PickingWorld', 'Planner', 'Protocol', 'STOP_REASONS', 'object_level',
    'run_trial', 'stop_reason', 'trial_key', 'attempt_keys', 'trial_camera', 'trial_fill',
    'Judge', 'Verdict', 'analytic_judge', 'analytic_verdict', 'physics_judge', 'world_grasp',
    'PHYSICS_FAILURES', 'PhysicsOutcome', 'PhysicsSettings', 'execute_grasp', 'receptacle_centre',
    'SealHold', 'seal_hold', 'seal_tolerance', 'collision_samples', 'gripper_collision', 'label_collision',
    'PHASES', 'PathSettings', 'ToolPath', 'move_fraction', 'tool_path',
    'FailureMemory', 'REPEAT_RADIUS', 'repeated_attempts', 'SUPERVISOR', 'SupervisorPolicy', 'supervisor_policy',
    'BenchmarkSpec', 'benchmark_config', 'benchmark_judges', 'load_benchmark_config', 'run_benchmark', 'summarize_run',
    'RecordedAttempt', 'recorded_action', 'recorded_attempt', 'replay_attempt', 'spec_from_settings',
    'ObjectPickability', 'object_pickability', 'pickability_summary', 'set_pickability',
    'AttemptLogError', 'MotionModel', 'Z_95', 'append_attempt', 'cleared_fraction', 'move_seconds',
    'object_difficulty', 'rated_acceleration', 'read_attempts', 'reliability', 'sem_interval', 'summarize',
    'wilson_interval', 'CALIBRATION_BINS', 'calibration', 'choice_summary', 'precision_at_choice',
]
