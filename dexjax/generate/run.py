"""A whole generation run: plan the shards, skip the finished ones, run the rest in parallel, summarise.

`generate_dataset` is the library side of ``python -m dexjax.generate``. The run is ``ceil(num_images /
images_per_shard)`` shards; worker i of N (``--shard i/N``) takes the shards with ``index % N == i``. Shards
already finished in ``out_dir`` (valid file of the same config and seed) are skipped, so rerunning a killed
run resumes it with no lost or duplicated rows. The resolved config is written to ``out_dir/config.json``.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import time
from pathlib import Path
from typing import Any

from dexjax.config import as_dict
from dexjax.data.manifest import open_manifest, pending_shards
from dexjax.data.shards import MANIFEST_NAME, read_shard, shard_path
from dexjax.generate.config import GenerateConfig, fingerprint
from dexjax.geometry.cache import atomic_write_text
from dexjax.generate.parallel import run_tasks
from dexjax.generate.pipeline import (close_process_generators, generate_shard, process_generator,
                                      supervisor_sets, usable_objects)
from dexjax.generate.report import RowStats

CONFIG_NAME = 'config.json'
PREVIEW_NAME = 'preview.png'


def num_shards(config: GenerateConfig, num_images: int) -> int:
  """Shards needed for at least ``num_images`` images (whole shards: the last one is not cut short)."""
  if num_images < 1:
    raise ValueError(f'--num-images: expected an integer >= 1, got {num_images}')
  return math.ceil(num_images / config.dataset.images_per_shard)


def _write_config(out_dir: Path, config: GenerateConfig) -> None:
  data = {'fingerprint': fingerprint(config), 'config': as_dict(config)}
  atomic_write_text(out_dir / CONFIG_NAME, json.dumps(data, indent=1, sort_keys=True, default=str))


def warm_caches(config: GenerateConfig, cache_dir: str | None = None, progress: bool = False) -> int:
  """Builds the object models, collision hulls and supervisor grasp sets into the cache once, before worker
  processes start (so they load instead of each computing them). Returns the number of usable objects.

  Raises:
    NoObjectsError: no object of the run's sources could be used.
  """
  prepared, _ = usable_objects(config, cache_dir, progress)
  supervisor_sets(config, [p.model for p in prepared], cache_dir)
  return len(prepared)


def generate_dataset(config: GenerateConfig, out_dir: str | os.PathLike[str], num_images: int, *,
                     assignment: tuple[int, int] = (0, 1), backend: str = 'serial', workers: int = 1,
                     ray_address: str | None = None, cache_dir: str | None = None, progress: bool = True,
                     preview: bool = True, verify: bool = False) -> dict[str, Any]:
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
    dexjax.data.ConfigMismatchError: ``out_dir`` holds another run.
  """
  out = Path(out_dir)
  total = num_shards(config, num_images)
  parallel = backend != 'serial' and workers > 1
  if parallel:
    config = dataclasses.replace(config, settle=config.settle.replace(nthread=1))  # one core per worker
  # The objects are checked (NoObjectsError) before a new run writes anything, so a bad source leaves no manifest
  # of its config behind; this makes the caches (parallel) or this process's generator (serial, reused by tasks).
  prepare = (lambda: warm_caches(config, cache_dir, progress)) if parallel else (
      lambda: process_generator(config, cache_dir))
  new_run = not (out / MANIFEST_NAME).exists()
  if new_run:
    prepare()
  open_manifest(out, fingerprint(config), config.seed, total)
  _write_config(out, config)
  todo = pending_shards(out, total, fingerprint(config), assignment, seed=config.seed, verify=verify)
  mine = len(range(assignment[0], total, assignment[1]))
  if todo and not new_run:
    prepare()
  stats, heap_counts = RowStats(), {'heaps': 0, 'diverged_heaps': 0, 'objects_left_bin': 0, 'images': 0}
  stage_seconds = {'settle': 0.0, 'render': 0.0, 'label': 0.0, 'write': 0.0}

  workers_seen: dict[int, list[float]] = {}  # pid -> [warm rows, warm seconds]

  def on_result(index: int, result: dict[str, Any]) -> None:
    del index
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
  task = functools.partial(generate_shard, config=config, out_dir=os.fspath(out), cache_dir=cache_dir)
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


__all__ = ['CONFIG_NAME', 'PREVIEW_NAME', 'generate_dataset', 'num_shards', 'warm_caches']
