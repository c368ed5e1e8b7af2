"""The Universal Picking benchmark in simulation (seed, "Characterization of Grasping Benchmark"), judged by the
analytic reward and by MuJoCo physics. Work in progress (issue 16): the metrics, the attempt log, the analytic
judge, the simulated bin and the trial loop with the seed's stopping rules are here; the physics judge, the
benchmark runner and its CLI are next."""

from dexjax.bench.analytic_judge import analytic_verdict, world_grasp
from dexjax.bench.attempt_log import AttemptLogError, append_attempt, read_attempts
from dexjax.bench.protocol import STOP_REASONS, Protocol, stop_reason
from dexjax.bench.trial import NO_GRASP, Verdict, analytic_judge, run_trial, trial_key
from dexjax.bench.world import BinState, PickingWorld, object_level
from dexjax.bench.picking_metrics import (Z_95, MotionModel, move_seconds, object_difficulty, reliability, sem_interval,
                                  summarize, wilson_interval)

__all__ = [
    'BinState', 'NO_GRASP', 'PickingWorld', 'Protocol', 'STOP_REASONS', 'Verdict', 'analytic_judge', 'object_level',
    'run_trial', 'stop_reason', 'trial_key',
    'AttemptLogError', 'MotionModel', 'Z_95', 'analytic_verdict', 'append_attempt', 'move_seconds', 'object_difficulty',
    'read_attempts', 'reliability', 'sem_interval', 'summarize', 'wilson_interval', 'world_grasp',
]
