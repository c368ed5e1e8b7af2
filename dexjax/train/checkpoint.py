"""Resumable training checkpoints of one gripper's run (orbax).

``OUT/<gripper>/checkpoints/<step>`` holds the whole `TrainState` (parameters, optimiser state, step) and a JSON
``progress`` item: where in the data the run is (epoch, batches done in that epoch), the input normalisation
and the best validation value so far. A checkpoint is written every ``every_steps`` SGD steps and at the end of
every epoch (after its validation); the ``keep`` newest are kept. Orbax writes each step to a temporary
directory and renames it when complete, so a run killed at any moment leaves only whole checkpoints behind.
A Ctrl-C during a save lets it finish first (`dexjax.models.saved.interrupt_deferred`: no half-written step, no
orbax thread still writing when the command exits); a second Ctrl-C stops at once and the temporary directory is
removed.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from dexjax.models.normalization import Normalization
from dexjax.models.saved import interrupt_deferred, remove_orbax_temporaries
from dexjax.train.config import CheckpointConfig
from dexjax.train.step import TrainState

CHECKPOINT_DIR = 'checkpoints'


def normalization_to_json(norm: Normalization) -> dict[str, Any]:
  return {k: np.asarray(getattr(norm, k)).tolist() for k in ('image_mean', 'image_std', 'pose_mean', 'pose_std')}


def normalization_from_json(data: dict[str, Any]) -> Normalization:
  return Normalization(**{k: jnp.asarray(data[k], jnp.float32) for k in ('image_mean', 'image_std', 'pose_mean',
                                                                          'pose_std')})


class Checkpointer:
  """The training checkpoints of one gripper in ``gripper_dir`` (see the module doc); use as a context manager."""

  def __init__(self, gripper_dir: str | os.PathLike, config: CheckpointConfig):
    self.directory = Path(gripper_dir).absolute() / CHECKPOINT_DIR
    options = ocp.CheckpointManagerOptions(max_to_keep=config.keep, create=True, enable_async_checkpointing=False)
    self._manager = ocp.CheckpointManager(self.directory, options=options, item_names=('state', 'progress'))

  def __enter__(self) -> Checkpointer:
    return self

  def __exit__(self, *exc) -> None:
    try:
      self._manager.close()  # waits for orbax's writer threads
    finally:
      if exc[0] is not None:  # an interrupted or failed save: resuming would clean it too, but leave nothing
        remove_orbax_temporaries(self.directory)

  def latest_step(self) -> int | None:
    return self._manager.latest_step()

  def save(self, state: TrainState, progress: dict[str, Any], replace: bool = False) -> None:
    """Saves ``state`` (at its step) with the JSON-ready ``progress``. A step already saved is left alone, or
    with ``replace`` rewritten (the end of an epoch that is also a periodic step: its progress moves on)."""
    step = int(state.step)
    if step in self._manager.all_steps() and not replace:
      return
    with interrupt_deferred():  # a Ctrl-C lets the save finish (see `interrupt_deferred`)
      if step in self._manager.all_steps():
        self._manager.delete(step)
      self._manager.save(step, args=ocp.args.Composite(state=ocp.args.StandardSave(state),
                                                       progress=ocp.args.JsonSave(progress)))
      self._manager.wait_until_finished()

  def restore(self, template: TrainState) -> tuple[TrainState, dict[str, Any]] | None:
    """The newest (state, progress), with the arrays placed like ``template``'s; None without checkpoints."""
    step = self._manager.latest_step()
    if step is None:
      return None
    abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, template)
    restored = self._manager.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(abstract),
                                                                   progress=ocp.args.JsonRestore()))
    return restored['state'], restored['progress']


__all__ = ['CHECKPOINT_DIR', 'Checkpointer', 'normalization_from_json', 'normalization_to_json']
