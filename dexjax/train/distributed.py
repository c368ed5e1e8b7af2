"""Data parallelism over every device of every host with `jax.sharding` (a no-op on one CPU device).

The mesh has one axis, ``data``, over all devices (`jax.devices()`: every host's). Parameters and optimiser
state are replicated; each batch is split along its first axis. Every host reads the same deterministic batch
stream (`dexjax.train.batches`) and contributes its contiguous slice of each global batch
(`jax.make_array_from_process_local_data`), so one host or many run the same global SGD steps. On a cluster,
call `initialize` (`jax.distributed.initialize`) in every process before anything else touches JAX.
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec


def initialize(coordinator_address: str | None = None, num_processes: int | None = None,
               process_id: int | None = None) -> None:
  """`jax.distributed.initialize` (arguments None: detected from the cluster environment, e.g. SLURM)."""
  jax.distributed.initialize(coordinator_address=coordinator_address, num_processes=num_processes,
                             process_id=process_id)


def data_mesh() -> Mesh:
  """A one-axis (``data``) mesh over all devices of all processes."""
  return Mesh(np.asarray(jax.devices()), ('data',))


def check_batch_size(batch_size: int, mesh: Mesh, field: str = 'loop.batch_size') -> None:
  """Raises ValueError unless ``batch_size`` splits evenly over the mesh's devices."""
  devices = mesh.devices.size
  if batch_size % devices:
    raise ValueError(f'{field}: expected a multiple of the {devices} devices, got {batch_size}')


def replicate(tree: Any, mesh: Mesh) -> Any:
  """``tree`` placed on every device of ``mesh`` (parameters, optimiser state, normalisation)."""
  sharding = NamedSharding(mesh, PartitionSpec())
  return jax.tree.map(lambda x: jax.make_array_from_process_local_data(sharding, np.asarray(x)), tree)


def shard_batch(batch: dict[str, np.ndarray], mesh: Mesh) -> dict[str, jax.Array]:
  """A global batch (same arrays on every process, leading axis B) split along B over ``mesh``'s devices."""
  sharding = NamedSharding(mesh, PartitionSpec('data'))
  count, index = jax.process_count(), jax.process_index()

  def place(x: np.ndarray) -> jax.Array:
    local = np.array_split(x, count)[index]
    return jax.make_array_from_process_local_data(sharding, local, x.shape)

  return {k: place(np.asarray(v)) for k, v in batch.items()}


def is_main_process() -> bool:
  """True on the process that writes metrics, plots and the best model (process 0)."""
  return jax.process_index() == 0


__all__ = ['check_batch_size', 'data_mesh', 'initialize', 'is_main_process', 'replicate', 'shard_batch']
