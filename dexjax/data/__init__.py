"""Dataset storage: deterministic, atomically written shards with a resumable manifest (`dexjax.data.shards`),
and a streaming, shuffled train/validation loader split by heap or by object (`dexjax.data.loader`)."""

from dexjax.data.loader import (TRAIN, VAL, DataDirs, dataset_dirs, dataset_label, dataset_shards, iterate_rows,
                                list_shards, require_shards, row_groups, split_images)
from dexjax.data.manifest import (Manifest, ShardRecord, file_sha256, finish_shard, load_manifest, manifest_problem,
                                  open_manifest, parse_shard_assignment, pending_shards, record_shard)
from dexjax.data.shards import (FORMAT_VERSION, GRIPPER_NAMES, IMAGE_SCHEMA, MANIFEST_NAME, POLICY_NAMES,
                                ROW_SCHEMA, ConfigMismatchError, Shard, ShardError, config_fingerprint, read_shard,
                                shard_path, shard_seed, shard_seed_sequence, write_shard)

__all__ = [
  "FORMAT_VERSION", "GRIPPER_NAMES", "IMAGE_SCHEMA", "MANIFEST_NAME", "POLICY_NAMES", "ROW_SCHEMA", "TRAIN", "VAL",
  "ConfigMismatchError", "DataDirs", "Manifest", "Shard", "ShardError", "ShardRecord", "config_fingerprint",
  "dataset_dirs", "dataset_label", "dataset_shards", "file_sha256",
  "finish_shard", "iterate_rows", "list_shards", "load_manifest", "manifest_problem", "open_manifest",
  "parse_shard_assignment",
  "pending_shards", "read_shard", "record_shard", "require_shards", "row_groups", "shard_path", "shard_seed", "shard_seed_sequence", "split_images",
  "write_shard",
]
