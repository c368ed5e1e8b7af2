"""Dataset generation: the Dex-Net 4.0 collection policy over rendered, settled heaps, written as shards.

Stages (each a module): `config` (every parameter, YAML), `cameras` (seed distribution or the user's camera),
`supervisor` (Omega: robust grasp sets per object, mapped into a heap), `policy` (tau: Omega with probability
epsilon, else uniform over the image's candidates), `labels` (one image: candidates, tau, reward S(x, u)),
`on_policy` (a learned policy's scored grasps as the candidates to label), `pipeline` (one shard: settle, render,
label), `parallel` (shards on processes or Ray), `run` (a whole run with resume), `report` (summary and preview
picture), `relabel` (a dataset's rows labelled again with new draws). The CLI is ``python -m dexjax.generate``.
"""

from dexjax.generate.cameras import apply_camera_file, image_size, run_camera
from dexjax.generate.config import (COLLECTION_POLICIES, CollectionConfig, DatasetConfig, GenerateConfig, ObjectsConfig,
                                    config_from_dict, fingerprint, load_generate_config, with_collection,
                                    with_grippers)
from dexjax.generate.labels import (PARALLEL_JAW, SUCTION, ImageRows, LabelParams, label_image, pickable_mask,
                                    reward_keys)
from dexjax.generate.parallel import RunResult, run_tasks
from dexjax.generate.pipeline import (ShardGenerator, close_process_generators, generate_shard, image_label_key,
                                      label_params, supervisor_sets)
from dexjax.generate.relabel import Relabelled, generation_reward_keys, relabel_shard, row_grasp
from dexjax.generate.on_policy import (collection_models, collection_policy, model_digest, plan_candidates,
                                       policy_candidates)
from dexjax.generate.policy import CANDIDATE, POLICY, SUPERVISOR, PolicyParams, collection_actions, supervisor_draws
from dexjax.generate.report import RowStats, format_summary, save_generation_png, summarize_rows
from dexjax.generate.run import check_run_dir, generate_dataset, load_run_config, num_shards, warm_caches
from dexjax.generate.supervisor import (GraspSet, SupervisorParams, cached_grasp_sets, heap_grasp_sets,
                                        parallel_jaw_grasp_set, parallel_jaw_supervisor_candidates,
                                        suction_grasp_set, suction_supervisor_candidates)
from dexjax.objects.sets import NoObjectsError, usable_objects

__all__ = [
  'apply_camera_file', 'cached_grasp_sets', 'CANDIDATE', 'check_run_dir', 'close_process_generators',
  'collection_actions', 'collection_models', 'COLLECTION_POLICIES', 'collection_policy', 'CollectionConfig',
  'config_from_dict', 'DatasetConfig', 'fingerprint', 'format_summary', 'generate_dataset', 'generate_shard',
  'GenerateConfig', 'generation_reward_keys', 'GraspSet', 'heap_grasp_sets', 'image_label_key', 'image_size',
  'ImageRows', 'label_image', 'label_params', 'LabelParams', 'load_generate_config', 'load_run_config',
  'model_digest', 'NoObjectsError', 'num_shards', 'ObjectsConfig', 'PARALLEL_JAW', 'parallel_jaw_grasp_set',
  'parallel_jaw_supervisor_candidates', 'pickable_mask', 'plan_candidates', 'POLICY', 'policy_candidates',
  'PolicyParams', 'relabel_shard', 'Relabelled', 'reward_keys', 'row_grasp', 'RowStats', 'run_camera',
  'run_tasks', 'RunResult', 'save_generation_png', 'ShardGenerator', 'SUCTION', 'suction_grasp_set',
  'suction_supervisor_candidates', 'summarize_rows', 'SUPERVISOR', 'supervisor_draws', 'supervisor_sets',
  'SupervisorParams', 'usable_objects', 'warm_caches', 'with_collection', 'with_grippers',
]
