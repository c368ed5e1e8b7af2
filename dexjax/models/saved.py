"""Trained GQ-CNNs on disk (orbax) and as callable quality functions.

A saved model is an orbax checkpoint directory (written atomically: orbax writes a temporary directory and
renames it) holding two items: ``params`` (the network parameters and the input `Normalization`) and ``model``
(JSON: format, gripper, architecture, crop window, and free-form ``info`` such as the epoch and validation
metrics). `dexjax.train` keeps the best model of each gripper in ``OUT/<gripper>/best``.

`load` returns a `GraspQualityModel`: call it on raw crops (metres) and raw poses to get p(success); it applies
the stored normalisation itself, so it is the whole quality function Q(y, u) of the policy.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import os
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp
from flax import struct

from dexjax.models.fully_convolutional import score_map
from dexjax.models.chunked import network_logits
from dexjax.models.gqcnn import GQCNNConfig, init_gqcnn, success_probability
from dexjax.models.normalization import Normalization
from dexjax.models.symmetry import NUM_VIEWS, symmetric_views

FORMAT = 'dexjax-gqcnn/1'
BEST_DIR = 'best'

#: The JSON files orbax reads from a saved model's step directory, checked (`check_saved_files`) before orbax
#: opens them: orbax would log an absl ``ERROR`` line for a damaged ``_CHECKPOINT_METADATA`` and raise a
#: ``UnicodeDecodeError`` naming no file for the others. ``_CHECKPOINT_METADATA`` may be missing (older orbax).
SAVED_JSON_FILES = ('_CHECKPOINT_METADATA', 'model/metadata', 'params/_METADATA')
_OPTIONAL_JSON_FILES = ('_CHECKPOINT_METADATA',)
_DAMAGED_HINT = 'expected a model saved by dexjax (python -m dexjax.train, dexjax.models.save_model); save it again'


@struct.dataclass
class GraspQualityModel:
  """A trained GQ-CNN with its input normalisation: p(success) of grasp crops.

  Attributes:
    params: network parameters.
    normalization: input statistics of the training split.
    config: architecture (static).
    gripper: ``'parallel_jaw'`` or ``'suction'`` (static).
    crop_window: side of the image window a crop is read from, pixels (static; ``config.crop_size`` pixels
      after resampling, see `dexjax.train.gripper_examples`).
    symmetric_views: average the prediction over the crop's four symmetric views (`dexjax.models.symmetry`:
      the grasp turned 180 degrees and flipped, the augmentations it was trained with; static). Four network
      evaluations per grasp; the shipped models turn it on (deviation 51). Saved with the model.
  """

  params: Any
  normalization: Normalization
  config: GQCNNConfig = struct.field(pytree_node=False)
  gripper: str = struct.field(pytree_node=False)
  crop_window: int = struct.field(pytree_node=False)
  symmetric_views: bool = struct.field(pytree_node=False, default=False)

  def _network_logits(self, crops: jax.Array, poses: jax.Array) -> jax.Array:
    crops, poses = self.normalization.apply(crops, poses, self.config.subtracts_grasp_depth)
    return network_logits(self.params, self.config, crops, poses)

  def logits(self, crops: jax.Array, poses: jax.Array) -> jax.Array:
    """Logits (B, 2) of raw crops (B, S, S, 1) metres and raw poses (B, pose_dim). With ``symmetric_views``, the
    log of the mean of the four views' class probabilities (a softmax of it is that mean)."""
    crops, poses = jnp.asarray(crops, jnp.float32), jnp.asarray(poses, jnp.float32)
    if not self.symmetric_views:
      return self._network_logits(crops, poses)
    views = functools.partial(symmetric_views, suction=self.gripper == 'suction')
    view_crops, view_poses = jax.vmap(views)(crops, poses)  # (B, 4, S, S, 1), (B, 4, pose_dim)
    b = crops.shape[0]
    logits = self._network_logits(view_crops.reshape((b * NUM_VIEWS,) + crops.shape[1:]),
                                  view_poses.reshape(b * NUM_VIEWS, -1)).reshape(b, NUM_VIEWS, -1)
    return jax.nn.logsumexp(jax.nn.log_softmax(logits, axis=-1), axis=1) - jnp.log(float(NUM_VIEWS))

  def __call__(self, crops: jax.Array, poses: jax.Array) -> jax.Array:
    """p(success) (B,) of raw crops (B, S, S, 1) metres and raw poses (B, pose_dim)."""
    return success_probability(self.logits(crops, poses))

  def score_image(self, depth: jax.Array, pose: jax.Array) -> jax.Array:
    """p(success) (H', W') of every stride-aligned, axis-aligned crop of a raw depth image (H, W) metres, with
    one raw pose (pose_dim,) or one per cell (H', W', pose_dim): `dexjax.models.score_map` with this model's
    normalisation. Cell (i, j) is the crop centred at (s i + S / 2, s j + S / 2), s = `output_stride`. A
    single-depth, axis-aligned sliding window (crops are not rotated; one view, whatever ``symmetric_views``
    says): not the FC-GQ-CNN of spec section 2.3.

    Raises:
      ValueError: the model reads resampled windows (``crop_window != config.crop_size``); resample the image
        by crop_size / crop_window first and build the model with equal sizes.
    """
    if self.crop_window != self.config.crop_size:
      raise ValueError(f'score_image: crop_window {self.crop_window} != crop_size {self.config.crop_size}: '
                       f'resample the depth image by {self.config.crop_size}/{self.crop_window} first')
    pose = jnp.asarray(pose, jnp.float32)
    if self.config.subtracts_grasp_depth and pose.ndim > 1:
      raise ValueError("score_image: a model of input_depth_mode 'im_depth_sub' takes crops relative to one grasp "
                       f'depth: expected one pose (pose_dim,), got shape {pose.shape}')
    image, pose = self.normalization.apply(jnp.asarray(depth, jnp.float32)[..., None], pose,
                                           self.config.subtracts_grasp_depth)
    return score_map(self.params, self.config, image, pose)


@jax.jit
def predict(model: GraspQualityModel, crops: jax.Array, poses: jax.Array) -> jax.Array:
  """Jitted ``model(crops, poses)``: p(success) (B,); compiles once per model architecture and batch shape."""
  return model(crops, poses)


def _options(keep: int) -> ocp.CheckpointManagerOptions:
  return ocp.CheckpointManagerOptions(max_to_keep=keep, create=True, enable_async_checkpointing=False)


def save_model(directory: str | os.PathLike, step: int, model: GraspQualityModel,
               info: dict[str, Any] | None = None) -> Path:
  """Saves ``model`` as checkpoint ``step`` of ``directory`` (older steps there are removed after the new one is
  complete, so a reader always finds a whole model). Returns the step's directory."""
  directory = Path(directory).absolute()
  meta = model_meta(model, info)
  with ocp.CheckpointManager(directory, options=_options(1), item_names=('params', 'model')) as manager:
    try:
      with interrupt_deferred():
        manager.save(step, args=ocp.args.Composite(
            params=ocp.args.StandardSave({'params': model.params, 'normalization': model.normalization}),
            model=ocp.args.JsonSave(meta)), force=True)
        manager.wait_until_finished()
    except BaseException:
      remove_orbax_temporaries(directory)
      raise
  return directory / str(step)


@contextlib.contextmanager
def interrupt_deferred() -> Iterator[None]:
  """Lets the block (an orbax save) finish before a Ctrl-C takes effect: the first SIGINT is held and raised as
  `KeyboardInterrupt` when the block ends, so the checkpoint is whole, orbax's writer threads are done (an
  interrupted save leaves them running: their tracebacks print after the command's ``error: interrupted``) and no
  ``*.orbax-checkpoint-tmp`` directory is left. A second Ctrl-C interrupts at once. Outside the main thread (where
  Python delivers signals) the block just runs."""
  if threading.current_thread() is not threading.main_thread():
    yield
    return
  held: list[int] = []
  previous = signal.getsignal(signal.SIGINT)

  def hold(signum, frame):  # pylint: disable=unused-argument
    if held:
      signal.signal(signal.SIGINT, previous)
      raise KeyboardInterrupt
    held.append(signum)

  signal.signal(signal.SIGINT, hold)
  try:
    yield
  finally:
    signal.signal(signal.SIGINT, previous)
  if held:
    raise KeyboardInterrupt


def remove_orbax_temporaries(directory: str | os.PathLike) -> None:
  """Removes the ``*.orbax-checkpoint-tmp*`` directories an interrupted orbax save left in ``directory``."""
  import shutil  # pylint: disable=g-import-not-at-top
  directory = Path(directory)
  if directory.is_dir():
    for tmp in directory.glob('*.orbax-checkpoint-tmp*'):
      shutil.rmtree(tmp, ignore_errors=True)


def model_meta(model: GraspQualityModel, info: dict[str, Any] | None = None) -> dict[str, Any]:
  """The JSON description saved with a model's arrays (format, gripper, crop window, views, architecture, info)."""
  return {'format': FORMAT, 'gripper': model.gripper, 'crop_window': model.crop_window,
          'symmetric_views': model.symmetric_views, 'config': dataclasses.asdict(model.config), 'info': info or {}}


def config_from_json(data: dict[str, Any]) -> GQCNNConfig:
  fields = {f.name for f in dataclasses.fields(GQCNNConfig)}
  return GQCNNConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items() if k in fields})


def params_template(config: GQCNNConfig) -> dict[str, Any]:
  """Zeros shaped like a saved model's ``{'params', 'normalization'}`` for ``config``: what a reader restores
  into (orbax here, a model file in `dexjax.models.shipped`)."""
  template = {'params': init_gqcnn(jax.random.key(0), config), 'normalization': Normalization.identity(config.pose_dim)}
  return jax.tree.map(lambda x: np.zeros(x.shape, x.dtype), template)


def _model_directory(path: Path, gripper: str | None) -> Path:
  """The orbax directory of a saved model, from a model directory, a gripper directory or a run directory."""
  candidates = [path, path / BEST_DIR] + ([path / gripper / BEST_DIR] if gripper else [])
  for candidate in candidates:
    if candidate.is_dir() and any(p.name.isdigit() and (p / 'model').exists() for p in candidate.iterdir()):
      return candidate
  names = sorted(p.name for p in path.iterdir() if (p / BEST_DIR).is_dir()) if path.is_dir() else []
  hint = (f"; it holds the grippers {names}: pass gripper=" if names and not gripper else '')
  raise FileNotFoundError(f"{path}: no saved GQ-CNN found (expected a model directory with numbered steps, "
                          f"'<gripper>/{BEST_DIR}' of a training run, or a run directory and a gripper){hint}")


def _latest_step_dir(directory: Path) -> Path:
  """The newest numbered step directory of a saved model's directory (orbax's ``latest_step``)."""
  return directory / str(max(int(p.name) for p in directory.iterdir() if p.name.isdigit() and p.is_dir()))


def check_saved_files(step_dir: str | os.PathLike) -> None:
  """Checks that the JSON files orbax reads from a saved model's step (`SAVED_JSON_FILES`) are whole JSON
  objects, before orbax opens them.

  Raises:
    ValueError: naming the damaged or missing file and what was expected.
  """
  for name in SAVED_JSON_FILES:
    path = Path(step_dir) / name
    if name in _OPTIONAL_JSON_FILES and not path.exists():
      continue
    try:
      data = json.loads(path.read_bytes().decode('utf-8'))
    except FileNotFoundError:
      raise ValueError(f'{path}: missing from the saved model; {_DAMAGED_HINT}') from None
    except (UnicodeDecodeError, ValueError) as e:
      raise ValueError(f'{path}: damaged, not the JSON file orbax writes ({type(e).__name__}: {e}); '
                       f'{_DAMAGED_HINT}') from None
    if not isinstance(data, dict):
      raise ValueError(f'{path}: damaged, expected a JSON object, got {type(data).__name__}; {_DAMAGED_HINT}')


def _short_error(error: BaseException) -> str:
  """``Type: message`` of an orbax / TensorStore error, cut to its first line and without the long spec."""
  text = str(error).split('\n')[0].split(' [tensorstore_spec=')[0]
  return f'{type(error).__name__}: {text[:300]}'


@contextlib.contextmanager
def _reading(step_dir: Path) -> Iterator[None]:
  """Turns an error of orbax reading a saved model into a `ValueError` naming its step directory."""
  try:
    yield
  except (ValueError, KeyError, TypeError, OSError, RuntimeError) as e:
    raise ValueError(f'{step_dir}: damaged saved model ({_short_error(e)}); {_DAMAGED_HINT}') from None


def _check_meta(meta: Any, where: Path) -> dict[str, Any]:
  """``meta`` if it is the ``model`` JSON of a dexjax GQ-CNN; ValueError naming the file and field otherwise."""
  if not isinstance(meta, dict) or meta.get('format') != FORMAT:
    got = meta.get('format') if isinstance(meta, dict) else meta
    raise ValueError(f"{where}: field 'format': expected {FORMAT!r}, got {got!r}")
  for field, kind in (('gripper', str), ('crop_window', int), ('config', dict)):
    if not isinstance(meta.get(field), kind):
      raise ValueError(f"{where}: field {field!r}: expected a {kind.__name__}, got {meta.get(field)!r}")
  return meta


def _read_meta(manager: ocp.CheckpointManager, directory: Path) -> tuple[int, dict[str, Any]]:
  """(newest step, its ``model`` JSON) of a saved model; ValueError naming the file if it is damaged or not a
  dexjax GQ-CNN."""
  step_dir = _latest_step_dir(directory)
  with _reading(step_dir):
    step = manager.latest_step()
    meta = manager.restore(step, args=ocp.args.Composite(model=ocp.args.JsonRestore()))['model']
  return step, _check_meta(meta, directory / str(step) / 'model' / 'metadata')


@contextlib.contextmanager
def _open_saved(path: str | os.PathLike, gripper: str | None) -> Iterator[tuple[Path, ocp.CheckpointManager]]:
  """(directory, orbax manager) of a saved model whose JSON files were checked first (`check_saved_files`)."""
  directory = _model_directory(Path(path).absolute(), gripper)
  check_saved_files(_latest_step_dir(directory))
  with ocp.CheckpointManager(directory, options=_options(1), item_names=('params', 'model')) as manager:
    yield directory, manager


def load(path: str | os.PathLike, gripper: str | None = None) -> GraspQualityModel:
  """Loads a saved GQ-CNN as a callable `GraspQualityModel`.

  Args:
    path: a model directory (``OUT/<gripper>/best``), a gripper directory (``OUT/<gripper>``), or a run directory
      ``OUT`` together with ``gripper``.
    gripper: which gripper's model, when ``path`` is a run directory.

  Raises:
    FileNotFoundError: nothing saved there (the message says what was expected).
    ValueError: the checkpoint is damaged (naming the file or step directory), not a dexjax GQ-CNN, or of another
      gripper than ``gripper``.
  """
  with _open_saved(path, gripper) as (directory, manager):
    step, meta = _read_meta(manager, directory)
    if gripper is not None and meta['gripper'] != gripper:
      raise ValueError(f"{directory}: field 'gripper': expected {gripper!r}, got {meta['gripper']!r}")
    with _reading(directory / str(step)):
      config = config_from_json(meta['config'])
      template = params_template(config)
      restored = manager.restore(step, args=ocp.args.Composite(params=ocp.args.StandardRestore(template)))['params']
  return GraspQualityModel(params=restored['params'], normalization=restored['normalization'], config=config,
                           gripper=meta['gripper'], crop_window=int(meta['crop_window']),
                           symmetric_views=bool(meta.get('symmetric_views', False)))


def model_info(path: str | os.PathLike, gripper: str | None = None) -> dict[str, Any]:
  """The ``info`` mapping saved with a model (epoch, validation metrics, ...)."""
  with _open_saved(path, gripper) as (directory, manager):
    return _read_meta(manager, directory)[1].get('info', {})


__all__ = ['BEST_DIR', 'FORMAT', 'GraspQualityModel', 'SAVED_JSON_FILES', 'check_saved_files', 'config_from_json',
           'interrupt_deferred', 'load', 'params_template', 'model_info', 'model_meta', 'predict',
           'remove_orbax_temporaries', 'save_model']
