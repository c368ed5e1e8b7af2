"""A whole training run (the library side of ``python -m dexjax.train``): the dataset (given, or the built-in
quick-start set generated once and cached), the training-split statistics, one GQ-CNN per gripper, and the
run's files (``config.yaml``, ``stats.json``, ``summary.json``, plus those of `dexjax.train.loop`).

Before anything is written, `check_run_dir` checks the run directory (a new run: a new or empty directory;
``resume``: an earlier run, recognised by its ``config.yaml``) and `dexjax.train.check_trainable` each gripper's
training split (both labels present, at least one batch per epoch), so a run that cannot learn anything fails
without leaving a "best" model behind."""

from __future__ import annotations

import dataclasses
import json
import os
import time
from pathlib import Path
from typing import Any

import yaml

from dexjax.cli import OutputError, check_output_dir
from dexjax.config import ConfigError, load_yaml
from dexjax.data.loader import DataDirs, list_shards, require_shards
from dexjax.geometry.cache import atomic_write_text, default_cache_dir
from dexjax.train.batches import GripperStats, dataset_stats
from dexjax.train.checkpoint import normalization_to_json
from dexjax.train.config import TrainConfig, config_to_dict, train_config_from_dict
from dexjax.train.distributed import is_main_process
from dexjax.train.loop import check_trainable, train_gripper
from dexjax.train.report import format_summary

CONFIG_FILE = 'config.yaml'
STATS_FILE = 'stats.json'
SUMMARY_FILE = 'summary.json'


def quickstart_dataset(config: TrainConfig, cache_dir: str | os.PathLike | None = None, progress: bool = True,
                       log=print) -> Path:
  """The built-in dataset of ``config.quickstart``: generated with Dex-Net 4.0's generation defaults on first
  use under ``<cache>/datasets/`` and reused (or completed, if a run was interrupted) afterwards."""
  # pylint: disable-next=g-import-not-at-top (the generator's imports are slow; only the quick start needs them)
  from dexjax.generate import GenerateConfig, fingerprint, generate_dataset, num_shards
  gen = GenerateConfig()
  gen = dataclasses.replace(gen, objects=dataclasses.replace(gen.objects, sources=config.quickstart.objects))
  cache = Path(cache_dir) if cache_dir is not None else Path(default_cache_dir())
  out = cache / 'datasets' / f'quickstart-{fingerprint(gen)[:12]}'
  images = config.quickstart.num_images
  if len(list_shards(out)) >= num_shards(gen, images):
    log(f'dataset: {out} (cached)')
    return out
  log(f'dataset: generating {images} heap images of {", ".join(config.quickstart.objects)} into {out} '
      f'(once; later runs reuse it)')
  summary = generate_dataset(gen, out, images, backend='process' if config.quickstart.workers > 1 else 'serial',
                             workers=config.quickstart.workers, cache_dir=os.fspath(cache_dir) if cache_dir else None,
                             progress=progress, preview=True, overwrite=True)  # dexjax's own cache directory
  failed = summary['shards']['failed']
  if failed:
    raise RuntimeError(f'{out}: {len(failed)} shards failed ({next(iter(failed.values())).splitlines()[0]}); '
                       f'rerun to retry them')
  log(f'dataset: {summary["rows"]} rows in {summary["seconds"]:.0f} s')
  return out


def check_run_dir(out_dir: str | os.PathLike, *, resume: bool = False) -> Path:
  """Checks, before anything is written, that a run may use ``out_dir``; returns it as a `Path`.

  A new run needs a new or empty directory under a writable one (an earlier run there: pass ``resume``; other
  files: choose another directory). ``resume`` needs an earlier run: a directory with a readable ``config.yaml``
  (a mistyped path fails instead of silently starting afresh).

  Raises:
    OutputError: naming ``--out``, the directory and what was expected.
  """
  out = check_output_dir(out_dir, option='--out')
  config = out / CONFIG_FILE
  if resume:
    if not config.is_file():
      raise OutputError('--out', out, f'is not a training run to resume (no {CONFIG_FILE}); expected the directory '
                                      'of an earlier run (check the path), or start a new run without --resume')
    return out
  if out.exists() and any(out.iterdir()):
    if config.is_file():
      raise OutputError('--out', out, 'holds an earlier run; pass --resume to continue it, or choose another --out')
    raise OutputError('--out', out, 'is not empty and holds no training run; expected a new or empty directory '
                                    '(choose another --out)')
  return out


def _check_resume_config(out: Path, config: TrainConfig) -> None:
  """A resumed run must keep its config (only ``loop.epochs`` may change)."""
  path = out / CONFIG_FILE
  if not path.exists():
    return
  try:
    data = load_yaml(path)
  except ConfigError as e:
    raise ConfigError(e.source, e.field, f'not a readable run config ({e.problem}); expected the config.yaml this '
                                         'run wrote') from None
  if not data:
    raise ConfigError(os.fspath(path), '', 'expected the mapping of the config.yaml this run wrote')
  saved = train_config_from_dict(data, os.fspath(path))
  if dataclasses.replace(saved, loop=dataclasses.replace(saved.loop, epochs=config.loop.epochs)) != config:
    raise ValueError(f'{path}: the run was started with another config; resume it with the same --config (only '
                     f'loop.epochs may change), or train into another --out')


def apply_init(config: TrainConfig) -> tuple[TrainConfig, dict[str, Any]]:
  """(config, models): without ``config.init``, the config unchanged and no models; with it, the GQ-CNNs to
  start from (by gripper) and the config with their architecture (``model``, ``crop_window``).

  Raises:
    FileNotFoundError, ValueError: ``config.init`` names nothing loadable, lacks a model of one of the run's
      grippers, or holds grippers of different architectures (naming the field ``init``).
  """
  if not config.init:
    return config, {}
  from dexjax.models.shipped import held_grippers, load_models  # pylint: disable=g-import-not-at-top (circular)
  models = load_models(config.init, config.grippers)
  missing = [g for g in config.grippers if g not in models]
  if missing:
    held = held_grippers(config.init, models)
    raise ValueError(f"init: {config.init}: no model of {' and '.join(missing)} there (has {held}); expected "
                     f"'pretrained', a training run of these grippers, or train only --grippers {' '.join(held)}")
  shapes = {(dataclasses.replace(m.config, pose_dim=config.model.pose_dim), m.crop_window) for m in models.values()}
  if len(shapes) > 1:
    raise ValueError(f'init: {config.init}: the grippers\' models differ in architecture; fine-tune one gripper at '
                     f'a time (--grippers)')
  (model, window), = shapes
  return dataclasses.replace(config, model=model, crop_window=window), models


def _stats_json(stats: dict[str, GripperStats]) -> dict[str, Any]:
  return {g: {'train_rows': s.train_rows, 'train_positives': s.train_positives,
              'positive_rate': s.positive_rate, 'normalization': normalization_to_json(s.normalization)}
          for g, s in stats.items()}


def train_run(config: TrainConfig, data_dir: DataDirs, out_dir: str | os.PathLike, *, resume: bool = False,
              progress: bool = True, log=print) -> dict[str, Any]:
  """Trains one GQ-CNN per gripper of ``config`` on ``data_dir`` (a dataset directory, or a sequence of them:
  their union, `dexjax.data.iterate_rows`) into ``out_dir``; returns the summary (``grippers``: the best
  validation record of each, ``seconds``, ``data``: the directory or the list of them, ``out``).

  Raises:
    FileNotFoundError: a directory of ``data_dir`` holds no shards.
    OutputError: ``out_dir`` is not a new or empty directory (a new run) or not an earlier run (``resume``).
    ValueError: a gripper's training split cannot teach anything (`dexjax.train.check_trainable`: one label
      only, or less than a batch); a resumed run's config differs.
  """
  out, start = Path(out_dir), time.perf_counter()
  dirs = require_shards(data_dir, 'make one with python -m dexjax.generate, or leave out --data for the built-in '
                                  'quick-start set')
  if is_main_process():
    check_run_dir(out, resume=resume)
  config, init = apply_init(config)
  if resume:
    _check_resume_config(out, config)
  stats = dataset_stats(data_dir, config)
  stats = {g: dataclasses.replace(s, normalization=init[g].normalization) if g in init else s
           for g, s in stats.items()}  # fine-tuning keeps the input scale the weights were trained with
  for gripper in config.grippers:
    check_trainable(gripper, stats[gripper], config, data_dir)
  if init:
    log(f'fine-tuning from {config.init}: {config.model}, {config.crop_window}-pixel windows')
  log(f'training into {out}')
  if is_main_process():
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / CONFIG_FILE, yaml.safe_dump(config_to_dict(config), sort_keys=False))
    atomic_write_text(out / STATS_FILE, json.dumps(_stats_json(stats), indent=1) + '\n')
  for gripper, s in stats.items():
    log(f'{gripper}: {s.train_rows} training rows, {100 * s.positive_rate:.1f} % positive')
  results = {}
  for gripper in config.grippers:
    results[gripper] = train_gripper(data_dir, out, config, gripper, stats[gripper], resume=resume,
                                     progress=progress, log=log,
                                     init_params=init[gripper].params if gripper in init else None)
  data = [os.fspath(d) for d in dirs]
  summary = {'grippers': results, 'seconds': time.perf_counter() - start,
             'data': data[0] if len(data) == 1 else data, 'out': os.fspath(out)}
  if is_main_process():
    atomic_write_text(out / SUMMARY_FILE, json.dumps(summary, indent=1) + '\n')
    log(format_summary(results, out))
  return summary


__all__ = ['CONFIG_FILE', 'STATS_FILE', 'SUMMARY_FILE', 'apply_init', 'check_run_dir', 'quickstart_dataset', 'train_run']
