"""Batched grasp evaluation for whole sets of grasps: nominal result and robust probability per grasp.

Wraps the single-grasp functions in one jitted ``vmap`` per gripper. Batches are padded to a fixed bucket
size so repeated calls with different counts reuse one compilation, and grasp ``i`` draws its samples from
``fold_in(key, i)``, so a grasp's result depends only on the key and its index, not on the batch it is in.

With several local devices the batch is split evenly over them (`split_over_devices`), each running its share
as its own program; results are the same bits as on one device. On a CPU, start Python with
``XLA_FLAGS=--xla_force_host_platform_device_count=<cores>``: one device per core uses the cores better than
one device's intra-operation threads (README, "Grasp quality": 1.1-1.7x on two cores).
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax.sharding import Mesh, PartitionSpec

from dexjax.geometry.object_model import ObjectModel
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality.grasp_quality import QualityConfig, parallel_jaw_quality, suction_quality
from dexjax.quality.robust import (Perturbations, nominal_conditions, robust_parallel_jaw_quality,
                                   robust_suction_quality)


@struct.dataclass
class GraspEvaluation:
  """Per-grasp results of `evaluate_grasps` (leading axis: grasps).

  Attributes:
    nominal: (N,) bool, resists under the nominal conditions (mean mass and friction, gravity along the
      approach, no pose noise, no disturbance).
    nominal_failure: (N,) int32 failure code of the nominal evaluation (`FAILURE_REASONS`).
    probability: (N,) robust probability of resisting.
  """

  nominal: jax.Array
  nominal_failure: jax.Array
  probability: jax.Array


def _evaluate_one(key, index, model, grasp, gripper, perturbations, config):
  if isinstance(gripper, ParallelJawGripper):
    nominal = parallel_jaw_quality(model, grasp, gripper, nominal_conditions(perturbations, grasp.approach), config)
    robust = robust_parallel_jaw_quality(jax.random.fold_in(key, index), model, grasp, gripper, perturbations, config)
  else:
    nominal = suction_quality(model, grasp, gripper, nominal_conditions(perturbations, grasp.approach), config)
    robust = robust_suction_quality(jax.random.fold_in(key, index), model, grasp, gripper, perturbations, config)
  return GraspEvaluation(nominal=nominal.resists, nominal_failure=nominal.failure, probability=robust.probability)


def split_over_devices(fn: Callable[..., Any]) -> Callable[..., Any]:
  """``fn``, batched along the leading axis of every argument and output, with its batch split evenly over the
  local devices (`jax.shard_map`; each device runs its share as its own program); ``fn`` itself on one device.
  Callers pad the batch to a multiple of ``len(jax.local_devices())``.

  (``check_vma=False``: the solver's loops start from constants that shard_map's check would ask to be marked as
  varying; every value here is per device anyway.)"""
  devices = jax.local_devices()
  if len(devices) == 1:
    return fn
  split = PartitionSpec('grasps')
  return jax.shard_map(fn, mesh=Mesh(np.asarray(devices), ('grasps',)), in_specs=split, out_specs=split,
                       check_vma=False)


@jax.jit
def _evaluate_batch(key, indices, model, grasps, gripper, perturbations, config):
  def evaluate(indices, grasps):
    return jax.vmap(_evaluate_one, in_axes=(None, 0, None, 0, None, None, None))(
        key, indices, model, grasps, gripper, perturbations, config)

  return split_over_devices(evaluate)(indices, grasps)


def _bucket(n: int, minimum: int = 64, multiple: int = 1) -> int:
  """Padded batch size: the next power of two (at least ``minimum``), rounded up to a multiple of ``multiple``."""
  size = max(minimum, 1 << max(n - 1, 0).bit_length())
  return -(-size // multiple) * multiple


def evaluate_grasps(key: jax.Array, model: ObjectModel, grasps: ParallelJawGrasp | SuctionGrasp,
                    gripper: ParallelJawGripper | SuctionGripper, perturbations: Perturbations,
                    config: QualityConfig = QualityConfig()) -> GraspEvaluation:
  """Nominal result and robust probability of every grasp in a batch (leading axis N) of one gripper type,
  split over the local devices when there are several (the same results as on one).

  Args:
    key: PRNG key; grasp i uses ``fold_in(key, i)``.
    model: the object.
    grasps: `ParallelJawGrasp` or `SuctionGrasp` with a leading axis N (matching ``gripper``).
    gripper: gripper parameters.
    perturbations: the Monte-Carlo model (``num_samples`` draws per grasp).
    config: wrench-resistance settings.

  Returns:
    `GraspEvaluation` with leading axis N, as NumPy arrays.
  """
  n = jax.tree.leaves(grasps)[0].shape[0]
  if n == 0:
    return GraspEvaluation(nominal=np.zeros(0, bool), nominal_failure=np.zeros(0, np.int32),
                           probability=np.zeros(0, np.float32))
  size = _bucket(n, multiple=len(jax.local_devices()))
  padded = jax.tree.map(lambda x: np.concatenate([np.asarray(x), np.repeat(np.asarray(x)[-1:], size - n, 0)]),
                        grasps)
  out = _evaluate_batch(key, jnp.arange(size), model, padded, gripper, perturbations, config)
  return jax.tree.map(lambda x: np.asarray(x)[:n], out)


__all__ = ['GraspEvaluation', 'evaluate_grasps', 'split_over_devices']
