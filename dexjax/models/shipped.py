"""GQ-CNNs shipped with the package (`pretrained`), single-file models, and where a command's ``--model`` comes from.

`pretrained` loads the weights shipped in ``dexjax/models/weights/`` (one ``<gripper>.msgpack`` each, a few
hundred kB; their model card is ``docs/models.md``): no network, no training run. A *model file* is one msgpack
file holding a `GraspQualityModel` (parameters, input normalisation, architecture, crop window, free-form
``info``): `save_model_file` writes one (atomically), `load_model_file` reads it; it is how a trained model is
shipped or copied, where an orbax directory (`dexjax.models.save_model`) is how training keeps them.

`load_models` resolves what a user passes as ``--model`` / ``--checkpoint`` / ``--init``: ``'pretrained'`` (the
shipped models), a training run (``OUT``: every ``OUT/<gripper>/best``), a gripper directory or a saved model
directory (`dexjax.models.load`), or a model file.
"""

from __future__ import annotations

import functools
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax
import numpy as np
from flax import serialization

from dexjax.models.saved import FORMAT, GraspQualityModel, config_from_json, load, model_meta, params_template

PRETRAINED = 'pretrained'
"""The name that selects the shipped models wherever a model path is expected."""
PRETRAINED_GRIPPERS = ('parallel_jaw', 'suction')
MODEL_FILE_SUFFIX = '.msgpack'
WEIGHTS_DIR = Path(__file__).parent / 'weights'


def save_model_file(path: str | os.PathLike, model: GraspQualityModel, info: dict[str, Any] | None = None) -> Path:
  """Writes ``model`` (and JSON-able ``info``: data, metrics, ...) as one msgpack file; returns its path.

  Written to a temporary file and renamed into place: a reader never sees half a model."""
  path = Path(path)
  meta = model_meta(model, info)
  state = {'meta': json.dumps(meta),
           'params': serialization.to_state_dict(jax.tree.map(np.asarray, model.params)),
           'normalization': serialization.to_state_dict(jax.tree.map(np.asarray, model.normalization))}
  path.parent.mkdir(parents=True, exist_ok=True)
  tmp = path.with_name(path.name + '.tmp')
  tmp.write_bytes(serialization.msgpack_serialize(state))
  os.replace(tmp, path)
  return path


def _read_model_file(path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
  """(meta, raw state) of a model file; ValueError naming the file when it is not one."""
  try:
    state = serialization.msgpack_restore(path.read_bytes())
    meta = json.loads(state['meta'])
  except (ValueError, KeyError, TypeError, UnicodeDecodeError) as e:
    raise ValueError(f'{path}: not a dexjax model file ({type(e).__name__}); expected a file written by '
                     f'dexjax.models.save_model_file') from None
  if not isinstance(meta, dict) or meta.get('format') != FORMAT:
    raise ValueError(f"{path}: field 'format': expected {FORMAT!r}, got "
                     f"{meta.get('format') if isinstance(meta, dict) else meta!r}")
  return meta, state


def load_model_file(path: str | os.PathLike, gripper: str | None = None) -> GraspQualityModel:
  """Reads a model file (`save_model_file`) as a callable `GraspQualityModel`.

  Raises:
    FileNotFoundError: no such file.
    ValueError: not a dexjax model file, parameters that do not fit its architecture, or another gripper's model
      than ``gripper``.
  """
  path = Path(path)
  if not path.is_file():
    raise FileNotFoundError(f'{path}: no such model file')
  meta, state = _read_model_file(path)
  if gripper is not None and meta['gripper'] != gripper:
    raise ValueError(f"{path}: field 'gripper': expected {gripper!r}, got {meta['gripper']!r}")
  template = params_template(config_from_json(meta['config']))
  try:
    params = serialization.from_state_dict(template['params'], state['params'])
    norm = serialization.from_state_dict(template['normalization'], state['normalization'])
  except (ValueError, KeyError, TypeError) as e:
    raise ValueError(f"{path}: field 'params': does not fit the stored architecture ({e})") from None
  for got, want in zip(jax.tree.leaves((params, norm)), jax.tree.leaves((template['params'],
                                                                         template['normalization']))):
    if np.shape(got) != want.shape:
      raise ValueError(f"{path}: field 'params': an array of shape {np.shape(got)} where the architecture expects "
                       f'{want.shape}')
  params = jax.tree.map(lambda x, t: np.asarray(x, t.dtype), params, template['params'])
  norm = jax.tree.map(lambda x, t: np.asarray(x, t.dtype), norm, template['normalization'])
  return GraspQualityModel(params=params, normalization=norm, config=config_from_json(meta['config']),
                           gripper=meta['gripper'], crop_window=int(meta['crop_window']),
                           symmetric_views=bool(meta.get('symmetric_views', False)))


def model_file_info(path: str | os.PathLike) -> dict[str, Any]:
  """The ``info`` mapping of a model file (data, training, metrics)."""
  return _read_model_file(Path(path))[0]['info']


def _check_gripper(gripper: str) -> None:
  if gripper not in PRETRAINED_GRIPPERS:
    raise ValueError(f'gripper: expected one of {PRETRAINED_GRIPPERS}, got {gripper!r}')


def pretrained_path(gripper: str) -> Path:
  """The shipped model file of ``gripper``."""
  _check_gripper(gripper)
  return WEIGHTS_DIR / f'{gripper}{MODEL_FILE_SUFFIX}'


@functools.cache
def pretrained(gripper: str) -> GraspQualityModel:
  """The shipped GQ-CNN of ``gripper`` (``'parallel_jaw'`` or ``'suction'``): a callable `GraspQualityModel`
  (raw crops (B, S, S, 1) metres and poses -> p(success)), loaded from the package, cached. What it was trained
  on, how well it does on unseen objects and the camera and gripper it assumes: ``docs/models.md``.

  Raises:
    ValueError: unknown gripper.
    FileNotFoundError: the weights are missing from this installation (a broken install: reinstall dexjax).
  """
  path = pretrained_path(gripper)
  if not path.is_file():
    raise FileNotFoundError(f'{path}: the shipped {gripper} weights are missing from this installation; '
                            'reinstall dexjax (pip install --force-reinstall dexjax)')
  return load_model_file(path, gripper)


def pretrained_info(gripper: str) -> dict[str, Any]:
  """The ``info`` stored with a shipped model: its data, network, training and metrics."""
  return model_file_info(pretrained_path(gripper))


def held_grippers(spec: str | os.PathLike | None, loaded: Mapping[str, Any] | None = None) -> list[str]:
  """The grippers ``spec`` (as `load_models` takes it) holds a model of, sorted: the shipped set for
  ``'pretrained'``, a training run's ``<gripper>/best`` directories, and the grippers of the ``loaded`` models
  (a single model's gripper is only known once it is loaded). For messages that name what a run lacks."""
  if spec is None or os.fspath(spec) == PRETRAINED:
    return sorted(PRETRAINED_GRIPPERS)
  path = Path(spec)
  held = {g for g in PRETRAINED_GRIPPERS if (path / g).is_dir()} if path.is_dir() else set()
  return sorted(held | set(loaded or {}))


def load_models(spec: str | os.PathLike | None, grippers: tuple[str, ...] = PRETRAINED_GRIPPERS
                ) -> dict[str, GraspQualityModel]:
  """GQ-CNNs by gripper from what a command line names.

  Args:
    spec: ``None`` or ``'pretrained'`` (the shipped models of ``grippers``), a training run directory (its
      ``<gripper>/best`` of each of ``grippers`` it holds), a gripper or saved-model directory, or a model file.
    grippers: the grippers wanted (a run or the shipped set may hold more).

  Raises:
    FileNotFoundError: nothing loadable at ``spec`` (the message says what was expected).
    ValueError: not a dexjax model.
  """
  if spec is None or os.fspath(spec) == PRETRAINED:
    return {g: pretrained(g) for g in grippers}
  path = Path(spec)
  if path.is_file():
    model = load_model_file(path)
    return {model.gripper: model}
  held = [g for g in PRETRAINED_GRIPPERS if (path / g).is_dir()]
  if held:
    return {g: load(path, g) for g in held if g in grippers}
  model = load(path)
  return {model.gripper: model}


__all__ = ['MODEL_FILE_SUFFIX', 'PRETRAINED', 'PRETRAINED_GRIPPERS', 'WEIGHTS_DIR', 'held_grippers', 'load_model_file',
           'load_models',
           'model_file_info', 'pretrained', 'pretrained_info', 'pretrained_path', 'save_model_file']
