"""GQ-CNN training (``python -m dexjax.train``): examples and augmentation from dataset rows (`data`), reproducible
fixed-size batches and training-split statistics (`batches`), the jitted step with Dex-Net 4.0's optimiser
(`step`), the per-gripper loop with validation, checkpoints and the best model (`loop`, `checkpoint`), data
parallelism (`distributed`), metrics (`metrics`, `validation`, `report`), configs (`config`) and whole runs (`run`).
"""

from dexjax.train.batches import GripperStats, dataset_stats, eval_batches, train_batches
from dexjax.train.checkpoint import Checkpointer
from dexjax.train.config import (BEST_METRICS, CLASS_BALANCE, CheckpointConfig, LoopConfig, QuickstartData,
                                 SplitConfig, TrainConfig, config_to_dict, load_train_config, train_config_from_dict)
from dexjax.train.data import gripper_examples, label_probability, pose_vectors, soft_labels, symmetrize
from dexjax.train.distributed import data_mesh, replicate, shard_batch
from dexjax.train.validation import evaluate_model, predict_rows, sample_examples
from dexjax.train.loop import Interrupted, check_trainable, final_state_params, sgd_step, train_gripper
from dexjax.train.metrics import average_precision, bootstrap_intervals, classification_metrics
from dexjax.train.report import plot_curves, read_records
from dexjax.train.run import check_run_dir, quickstart_dataset, train_run
from dexjax.train.on_policy_rounds import ROUNDS_FILE, round_configs, round_dirs, run_rounds
from dexjax.train.step import (OptimizerConfig, TrainState, create_state, cross_entropy, eval_logits,
                               learning_rate_schedule, make_optimizer, train_step)

__all__ = [
  'average_precision', 'BEST_METRICS', 'bootstrap_intervals', 'check_run_dir', 'check_trainable',
  'CheckpointConfig', 'Checkpointer', 'CLASS_BALANCE', 'classification_metrics', 'config_to_dict', 'create_state',
  'cross_entropy', 'data_mesh', 'dataset_stats', 'eval_batches', 'eval_logits', 'evaluate_model',
  'final_state_params', 'gripper_examples', 'GripperStats', 'Interrupted', 'label_probability',
  'learning_rate_schedule', 'load_train_config', 'LoopConfig', 'make_optimizer', 'OptimizerConfig', 'plot_curves',
  'pose_vectors', 'predict_rows', 'quickstart_dataset', 'QuickstartData', 'read_records', 'replicate',
  'round_configs', 'round_dirs', 'ROUNDS_FILE', 'run_rounds', 'sample_examples', 'sgd_step', 'shard_batch',
  'soft_labels', 'SplitConfig', 'symmetrize', 'train_batches', 'train_config_from_dict', 'train_gripper',
  'train_run', 'train_step', 'TrainConfig', 'TrainState',
]
