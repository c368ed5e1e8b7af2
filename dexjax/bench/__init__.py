"""The Universal Picking benchmark in simulation (seed, "Characterization of Grasping Benchmark"), judged by the
analytic reward and by MuJoCo physics. Work in progress (issue 16): the metrics, the attempt log and the analytic
judge are here."""

from dexjax.bench.analytic_judge import analytic_verdict, world_grasp
from dexjax.bench.attempt_log import AttemptLogError, append_attempt, read_attempts
from dexjax.bench.picking_metrics import (Z_95, MotionModel, move_seconds, object_difficulty, reliability, sem_interval,
                                  summarize, wilson_interval)

__all__ = [
    'AttemptLogError', 'MotionModel', 'Z_95', 'analytic_verdict', 'append_attempt', 'move_seconds', 'object_difficulty',
    'read_attempts', 'reliability', 'sem_interval', 'summarize', 'wilson_interval', 'world_grasp',
]
