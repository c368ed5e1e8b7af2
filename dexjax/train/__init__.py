"""GQ-CNN training (issue 6, in progress): examples and augmentation from dataset rows (`data`), the jitted train
step with Dex-Net 4.0's optimiser (`step`) and validation metrics (`metrics`)."""

from dexjax.train.data import gripper_examples, pose_vectors, symmetrize
from dexjax.train.metrics import average_precision, classification_metrics
from dexjax.train.step import (OptimizerConfig, TrainState, create_state, cross_entropy, eval_logits, make_optimizer,
                               train_step)

__all__ = ['OptimizerConfig', 'TrainState', 'average_precision', 'classification_metrics', 'create_state',
           'cross_entropy', 'eval_logits', 'gripper_examples', 'make_optimizer', 'pose_vectors', 'symmetrize',
           'train_step']
