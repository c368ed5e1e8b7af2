"""A whole generation run: plan the shards, skip the finished ones, run the rest in parallel, summarise.

`generate_dataset` is the library side of ``python -m dexjax.generate``. The run is ``ceil(num_images /
images_per_shard)`` shards; worker i of N (``--shard i/N``) takes the shards with ``index % N == i``. Shards
already finished in ``out_dir`` (valid file of the same config and seed) are skipped, so rerunning a killed
run resumes it with no lost or duplicated rows. The resolved config is written to ``out_dir/config.json``.

Before anything is computed or written, `check_run_dir` makes sure the run cannot clobber files it did not write:
a new run needs a new or empty directory, and a ``config.json`` or ``preview.png`` already there must be this
command's own (the run's config record; a PNG marked by dexjax), unless ``overwrite``.
"""

from __future__ import annotations

import dataclasses
import errno
import functools
import json
import math
import os
import re
import time
import warnings
from pathlib import Path
from typing import Any

from dexjax.cli import OutputError, check_output_dir, is_dexjax_png
from dexjax.config import ConfigError, as_dict, parse_json, validate_generate_config
from dexjax.data.manifest import manifest_problem, open_manifest, pending_shards
from dexjax.data.shards import MANIFEST_NAME, read_shard, shard_path
from dexjax.generate.config import CollectionConfig, GenerateConfig, content_fields, fingerprint, load_generate_config
from dexjax.geometry.cache import atomic_write_text
from dexjax.generate.parallel import run_tasks
from dexjax.generate.pipeline import (close_process_generators, generate_shard, process_generator, stage_names,
                                      supervisor_sets)
from dexjax.generate.report import RowStats
from dexjax.objects.sets import load_object_set, prepare_object_set, usable_objects

CONFIG_NAME = 'config.json'
PREVIEW_NAME = 'preview.png'


#: Errors of the file system (disk full, quota, read-only, permission denied) that stop a run with one ``error:``
#: line naming the file (exit 2, docs/errors.md) instead of failing every remaining task with a traceback.
FILE_SYSTEM_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM)


def file_system_error(error: BaseException) -> dict[str, Any] | None:
  """A picklable record of ``error`` if it is a file system error (`FILE_SYSTEM_ERRNOS`), for a task to return
  to the parent (`raise_file_system_error`); None otherwise."""
  if isinstance(error, OSError) and error.errno in FILE_SYSTEM_ERRNOS:
    return {'errno': error.errno, 'strerror': error.strerror, 'filename': error.filename}
  return None


def raise_file_system_error(result: dict[str, Any]) -> None:
  """Raises the `OSError` a task recorded in ``result['file_system_error']`` (`file_system_error`), if any."""
  error = result.get('file_system_error')
  if error is not None:
    raise OSError(error['errno'], error['strerror'], error['filename'])


def _shard_task(index: int, **kwargs: Any) -> dict[str, Any]:
  """`generate_shard`, but a file system error (disk full, ...) is returned for the parent to stop the run with one
  line naming the file, instead of every later shard failing with the same traceback."""
  try:
    return generate_shard(index, **kwargs)
  except OSError as e:
    recorded = file_system_error(e)
    if recorded is None:
      raise
    return {'file_system_error': recorded}


def num_shards(config: GenerateConfig, num_images: int) -> int:
  """Shards needed for at least ``num_images`` images (whole shards: the last one is not cut short)."""
  if num_images < 1:
    raise ValueError(f'--num-images: expected an integer >= 1, got {num_images}')
  return math.ceil(num_images / config.dataset.images_per_shard)


# Files a run starting in the same directory at the same moment (another --shard worker) may already have made.
_STARTING_RUN_FILE = re.compile(r'\..+\.tmp-.*|\.tmp-.*|shard-\d{6}\.npz\.tmp-\d+|manifest\.lock')


def _is_run_config(path: Path) -> bool:
  """True if ``path`` is a ``config.json`` this module wrote: a JSON object of exactly fingerprint and config."""
  try:
    data = parse_json(path.read_text(encoding='utf-8'), os.fspath(path), expected=None)
  except (OSError, ValueError):  # unreadable, not UTF-8, or refused by parse_json (ConfigError: deep nesting, ...)
    return False
  return isinstance(data, dict) and set(data) == {'fingerprint', 'config'}


def check_run_dir(out_dir: str | os.PathLike[str], *, overwrite: bool = False) -> Path:
  """Checks, before anything is computed or written, that a run may write into ``out_dir``; returns it.

  ``out_dir`` must be a directory or not exist yet, under a writable directory (missing levels are created).
  A new run (no ``manifest.json``) needs it absent or empty; a directory of a run may also hold other files
  (they are never written). A ``manifest.json``, ``config.json`` or ``preview.png`` must be the run's own: a run
  manifest (`dexjax.data.manifest_problem`), the config record this module writes, a PNG marked as dexjax's
  (`dexjax.cli.is_dexjax_png`). With ``overwrite`` the last two rules are lifted and a foreign ``manifest.json``
  is replaced. A manifest or shards of another run are refused later (`dexjax.data.ConfigMismatchError`).

  Raises:
    OutputError: naming ``--out``, the directory and what was expected.
  """
  out = check_output_dir(out_dir, option='--out')
  if overwrite or not out.exists():
    return out
  entries = sorted(p.name for p in out.iterdir())
  mine = {CONFIG_NAME: _is_run_config, PREVIEW_NAME: _is_dexjax_png}
  for name in entries:
    if name in mine and not mine[name](out / name):
      raise OutputError('--out', out, f"holds a '{name}' this command did not write; expected this run's own "
                                      f'{name} (move the file away, choose another --out, or pass --overwrite)')
  if MANIFEST_NAME in entries:
    problem = manifest_problem(out / MANIFEST_NAME)
    if problem is not None:
      raise OutputError('--out', out / MANIFEST_NAME, f'{problem}: move the file away, choose another --out, or pass '
                                                     '--overwrite to replace it')
  else:
    others = [n for n in entries if not _STARTING_RUN_FILE.fullmatch(n)]
    if others:
      shown = ', '.join(repr(n) for n in others[:3]) + (', ...' if len(others) > 3 else '')
      raise OutputError('--out', out, f'is not empty ({shown}) and holds no dataset run (no {MANIFEST_NAME}); '
                                      'expected a new or empty directory, or a run to resume (or pass --overwrite)')
  return out


def _is_dexjax_png(path: Path) -> bool:
  try:
    return is_dexjax_png(path)
  except (OSError, ValueError):
    return False


def _flat(data: Any, prefix: str = '') -> dict[str, Any]:
  if isinstance(data, dict):
    return {k: v for key, value in data.items() for k, v in _flat(value, f'{prefix}{key}.').items()}
  return {prefix[:-1]: data}


def load_run_config(data_dir: str | os.PathLike[str], path: str | os.PathLike[str] | None = None) -> GenerateConfig:
  """The `GenerateConfig` a finished run was made with: the config file ``path`` (default: the defaults) with the
  run's object sources, seed and on-policy collection (``--objects``, ``--seed`` and ``--model`` may have set
  them; the collecting model is not loaded again), checked field by field against
  the run's ``config.json``: every field of `content_fields` the record holds (older versions wrote fewer).

  Raises:
    FileNotFoundError: ``data_dir`` has no run config record.
    ConfigError: a field differs (named, with the run's value).
  """
  record_path = Path(data_dir) / CONFIG_NAME
  if not _is_run_config(record_path):
    raise FileNotFoundError(f'{record_path}: no run config record (python -m dexjax.generate writes one)')
  record = json.loads(record_path.read_text(encoding='utf-8'))['config']
  config = load_generate_config(path, objects=list(record['objects']['sources']), seed=int(record['seed']))
  if record.get('collection', {}).get('policy', 'tau') != 'tau':  # as recorded: its model is not needed again
    config = dataclasses.replace(config, collection=CollectionConfig(**record['collection']))
  ours = _flat(content_fields(as_dict(config)))
  for field, value in _flat(content_fields(record)).items():
    if field in ours and ours[field] != value:
      raise ConfigError(os.fspath(record_path), field,
                        f'the run was made with {value!r}, the config ({path or "defaults"}) gives {ours[field]!r}')
  return config


def write_run_config(out_dir: Path, config: GenerateConfig) -> None:
  """Writes the run's config record ``out_dir/config.json`` (fingerprint and resolved config), atomically."""
  data = {'fingerprint': fingerprint(config), 'config': as_dict(config)}
  atomic_write_text(out_dir / CONFIG_NAME, json.dumps(data, indent=1, sort_keys=True, default=str))


def warm_caches(config: GenerateConfig, cache_dir: str | None = None, progress: bool = False, *,
                backend: str = 'serial', workers: int = 1, ray_address: str | None = None) -> int:
  """Builds the object models, collision hulls and supervisor grasp sets into the cache once, before worker
  processes start (so they load instead of each computing them). Returns the number of usable objects.

  Every cache entry belongs to one object, so with ``workers > 1`` the objects are split into interleaved parts
  built on the ``backend``'s workers (`dexjax.generate.run_tasks`); this process then loads them all (and builds
  what a failed part left, with a warning).

  Raises:
    NoObjectsError: no object of the run's sources could be used.
  """
  if backend != 'serial' and workers > 1:
    parts = _WARM_PARTS_PER_WORKER * workers
    task = functools.partial(_warm_part, config=config, cache_dir=cache_dir, parts=parts)
    result = run_tasks(task, range(parts), backend=backend, workers=workers, progress=progress,
                       ray_address=ray_address, description='object caches')
    if result.failures:
      index, reason = next(iter(result.failures.items()))
      warnings.warn(f'object caches: {len(result.failures)} of {parts} parts failed on the workers (part {index}: '
                    f'{reason}); this process builds what they left', stacklevel=2)
  prepared, _ = usable_objects(config, cache_dir, progress)
  supervisor_sets(config, [p.model for p in prepared], cache_dir)
  return len(prepared)


_WARM_PARTS_PER_WORKER = 4  # interleaved parts per worker: objects differ in cost, small parts balance the load


def _warm_part(index: int, *, config: GenerateConfig, cache_dir: str | None, parts: int) -> dict[str, Any]:
  """Builds the caches of objects ``index``, ``index + parts``, ... of the run's sources (a `warm_caches` task)."""
  report = load_object_set(config.objects.sources, scale=config.objects.scale)
  prepared, _ = prepare_object_set(report.loaded[index::parts], cache_dir=cache_dir,
                                   grid_size=config.objects.grid_size)
  if prepared:
    supervisor_sets(config, [p.model for p in prepared], cache_dir)
  return {'objects': len(prepared)}


def generate_dataset(config: GenerateConfig, out_dir: str | os.PathLike[str], num_images: int, *,
                     assignment: tuple[int, int] = (0, 1), backend: str = 'serial', workers: int = 1,
                     ray_address: str | None = None, cache_dir: str | None = None, progress: bool = True,
                     preview: bool = True, verify: bool = False, overwrite: bool = False) -> dict[str, Any]:
  """Generates (or resumes) a dataset in ``out_dir`` and returns the run's summary (plain JSON).

  Args:
    config: the run's `GenerateConfig`.
    out_dir: output directory (shards, ``manifest.json``, ``config.json``, ``preview.png``).
    num_images: images wanted (rounded up to whole shards).
    assignment: (i, N): this worker writes the shards with ``index % N == i``.
    backend: ``'serial'``, ``'process'`` or ``'ray'`` (`dexjax.generate.run_tasks`).
    workers: parallel workers of the backend.
    ray_address: an existing Ray cluster to join (``'auto'`` or ``'host:port'``); None starts a local one.
    cache_dir: object and supervisor cache (default ``$DEXJAX_CACHE`` or ``~/.cache/dexjax/objects``).
    progress: progress bars on stderr.
    preview: write ``preview.png`` (first image of the first finished shard: grasps coloured by reward, crops).
    verify: re-read every finished shard before resuming (default: trust manifest entries whose file size
      matches, see `dexjax.data.pending_shards`).
    overwrite: allow a non-empty ``out_dir`` without a run and replacing a ``config.json`` / ``preview.png``
      this module did not write (`check_run_dir`).

  Returns:
    ``rows``, ``positive_rate`` and per-gripper counts (rows, positives, positive rate, supervisor rows,
    failure reasons; `dexjax.generate.RowStats`), ``rows_per_s`` of this invocation, ``warm_rows_per_s`` (the
    workers' rates after their first shard, summed; None when no worker made two), ``seconds`` per stage
    (summed over workers), shard counts (``shards``, ``skipped``, ``written``, ``failed`` with reasons),
    heap counts, and the paths written.

  Raises:
    NoObjectsError: no object of ``config.objects.sources`` could be used (checked before a new run writes
      anything; a task's own errors are reported per shard in ``shards.failed`` instead).
    ValueError: ``num_images < 1``.
    OutputError: ``out_dir`` cannot be written, or holds files this run did not write (`check_run_dir`).
    OSError: the disk is full (or read-only, ...) while writing a shard: the run stops, naming the file; shards
      already written are complete and kept (`FILE_SYSTEM_ERRNOS`).
    dexjax.data.ConfigMismatchError: ``out_dir`` holds another run.
  """
  total = num_shards(config, num_images)
  validate_generate_config(config, '<GenerateConfig>')
  out = check_run_dir(out_dir, overwrite=overwrite)
  parallel = backend != 'serial' and workers > 1
  if parallel:
    config = dataclasses.replace(config, settle=config.settle.replace(nthread=1))  # one core per worker
  # The objects are checked (NoObjectsError) before a new run writes anything, so a bad source leaves no manifest
  # of its config behind; this makes the caches (parallel) or this process's generator (serial, reused by tasks).
  prepare = (lambda: warm_caches(config, cache_dir, progress, backend=backend, workers=workers,
                                 ray_address=ray_address)) if parallel else (
      lambda: process_generator(config, cache_dir))
  manifest = out / MANIFEST_NAME
  foreign = manifest.exists() and manifest_problem(manifest) is not None  # only with --overwrite (check_run_dir)
  new_run = foreign or not manifest.exists()
  if new_run:
    prepare()
  open_manifest(out, fingerprint(config), config.seed, total, replace_foreign=overwrite)
  write_run_config(out, config)
  todo = pending_shards(out, total, fingerprint(config), assignment, seed=config.seed, verify=verify)
  mine = len(range(assignment[0], total, assignment[1]))
  if todo and not new_run:
    prepare()
  stats, heap_counts = RowStats(), {'heaps': 0, 'diverged_heaps': 0, 'objects_left_bin': 0, 'images': 0}
  stage_seconds = {stage: 0.0 for stage in stage_names(config)}

  workers_seen: dict[int, list[float]] = {}  # pid -> [warm rows, warm seconds]

  def on_result(index: int, result: dict[str, Any]) -> None:
    del index
    raise_file_system_error(result)  # disk full: stop at once (finished shards are kept), one error line
    stats.add(result['rows'])
    if result.get('warm'):
      entry = workers_seen.setdefault(result['pid'], [0.0, 0.0])
      entry[0] += len(result['rows']['gripper'])
      entry[1] += result['wall_seconds']
    for k in heap_counts:
      heap_counts[k] += result[k]
    for k, v in result['seconds'].items():
      stage_seconds[k] += v

  clock = time.perf_counter()
  task = functools.partial(_shard_task, config=config, out_dir=os.fspath(out), cache_dir=cache_dir)
  try:
    result = run_tasks(task, todo, backend=backend if parallel else 'serial', workers=workers, progress=progress,
                       on_result=on_result, ray_address=ray_address)
  finally:
    close_process_generators()  # serial runs made the generator in this process
  seconds = time.perf_counter() - clock
  summary = stats.to_dict(seconds)
  summary.update(heap_counts)
  summary['stage_seconds'] = stage_seconds
  # Steady rate: each worker's rows over its busy time, without its first shard (start-up, compiling), summed.
  summary['warm_rows_per_s'] = sum(r / t for r, t in workers_seen.values() if t > 0) or None
  summary['shards'] = {'total': total, 'assigned': mine, 'skipped': mine - len(todo),
                       'written': len(result.results), 'failed': {str(k): v for k, v in result.failures.items()}}
  summary['out_dir'] = os.fspath(out)
  if preview:
    summary['preview'] = _preview(out, total, assignment)
  return summary


def _preview(out: Path, total: int, assignment: tuple[int, int]) -> str | None:
  """Writes ``preview.png`` from the first finished shard of this worker; returns its path (None if none)."""
  from dexjax.generate.report import save_generation_png  # pylint: disable=g-import-not-at-top (matplotlib)
  for index in range(assignment[0], total, assignment[1]):
    path = shard_path(out, index)
    if path.exists():
      save_generation_png(out / PREVIEW_NAME, read_shard(path), 0)
      return os.fspath(out / PREVIEW_NAME)
  return None


__all__ = ['CONFIG_NAME', 'FILE_SYSTEM_ERRNOS', 'PREVIEW_NAME', 'check_run_dir', 'file_system_error',
           'generate_dataset', 'load_run_config', 'num_shards', 'raise_file_system_error', 'warm_caches',
           'write_run_config']
