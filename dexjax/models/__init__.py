"""GQ-CNN models in Flax: the Dex-Net 4.0 grasp-quality network (`GQCNN`, spec section 2.2), a small variant for
CPU runs, its application to every stride-aligned, axis-aligned crop of a whole image at one pose (`score_map`; a
sliding window, not the FC-GQ-CNN of spec section 2.3), and input
normalisation fitted on the training split (`fit_normalization`)."""

from dexjax.models.fully_convolutional import output_stride, score_map, score_map_shape
from dexjax.models.normalization import Normalization, fit_normalization
from dexjax.models.saved import GraspQualityModel, load, model_info, predict, save_model
from dexjax.models.shipped import (PRETRAINED, load_model_file, load_models, pretrained, pretrained_info,
                                      save_model_file)
from dexjax.models.gqcnn import (GQCNN, PARALLEL_JAW_POSE_DIM, SUCTION_POSE_DIM, GQCNNConfig, ImageStream, init_gqcnn,
                                 num_parameters, success_probability)

__all__ = [
  'GQCNN', 'GQCNNConfig', 'GraspQualityModel', 'ImageStream', 'Normalization', 'PARALLEL_JAW_POSE_DIM',
  'SUCTION_POSE_DIM',
  'PRETRAINED', 'fit_normalization', 'init_gqcnn', 'load', 'load_model_file', 'load_models', 'model_info',
  'num_parameters', 'output_stride', 'predict', 'pretrained', 'pretrained_info', 'save_model', 'save_model_file',
  'score_map', 'score_map_shape', 'success_probability',
]
