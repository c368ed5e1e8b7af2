"""On-policy rounds: train, collect with the trained policy, train again (Satish, Mahler and Goldberg 2019).

Round r lives in ``OUT/round-<r>``: ``data`` (a `dexjax.generate` run) and ``train`` (a `dexjax.train` run).

* Round 0 collects with the generation config's own collection policy (the seed's tau, unless the config says
  otherwise) or, given ``init`` (a trained run, a saved model, ``'pretrained'``), on-policy with ``init``; it
  trains from scratch, or from ``init``.
* Round r > 0 collects on-policy with round r - 1's models (`dexjax.generate.on_policy`: the grasps their CEM
  scores on each image, the top ``policy.top_k`` first, the supervisor's mixed in with probability epsilon) and
  fine-tunes round r - 1's models on that data: on that round's data alone, or (``aggregate``, as DAgger: Ross,
  Gordon and Bagnell 2011) on every round's data so far; ``base_data`` (e.g. the set ``init`` was trained on) is
  added to every round's training data, so the models keep seeing the candidates they were first trained on.

Every step resumes: a generation run rerun with the same config continues it (`dexjax.generate.generate_dataset`),
a training run without ``summary.json`` continues from its checkpoints, a finished one is skipped; so the same
call after an interruption goes on where it stopped. ``OUT/rounds.json`` records each finished step (data
summary, training summary, seconds).
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from collections.abc import Sequence
from typing import Any, Callable

from dexjax.data.loader import require_shards
from dexjax.geometry.cache import atomic_write_text
from dexjax.generate.config import GenerateConfig, with_collection
from dexjax.train.config import TrainConfig
from dexjax.train.run import CONFIG_FILE, SUMMARY_FILE

ROUNDS_FILE = 'rounds.json'


def round_dirs(out_dir: str | os.PathLike[str], r: int) -> tuple[Path, Path]:
  """(data directory, training directory) of round ``r`` under ``out_dir``."""
  base = Path(out_dir) / f'round-{r}'
  return base / 'data', base / 'train'


def round_configs(generate: GenerateConfig, train: TrainConfig, out_dir: str | os.PathLike[str], r: int,
                  init: str | None = None) -> tuple[GenerateConfig, TrainConfig]:
  """The generation and training configs of round ``r`` (see the module docstring); the generation seed is
  ``generate.seed + r``, so rounds label other heaps. Loads the collecting model (its digest)."""
  previous = os.fspath(round_dirs(out_dir, r - 1)[1]) if r > 0 else init
  gen = dataclasses.replace(generate, seed=generate.seed + r)
  if previous:
    gen = with_collection(gen, 'on_policy', previous, source=f'round {r}')
  return gen, dataclasses.replace(train, init=previous or train.init)


def round_training_data(out_dir: str | os.PathLike[str], r: int, base_data: Sequence[str | os.PathLike[str]] = (),
                        aggregate: bool = False) -> list[Path]:
  """The dataset directories round ``r`` trains on: ``base_data``, then round ``r``'s collection, or with
  ``aggregate`` the collections of rounds 0..r."""
  rounds = range(r + 1) if aggregate else (r,)
  return [Path(d) for d in base_data] + [round_dirs(out_dir, k)[0] for k in rounds]


def _training_state(train_dir: Path) -> str:
  if (train_dir / SUMMARY_FILE).is_file():
    return 'done'
  return 'resume' if (train_dir / CONFIG_FILE).is_file() else 'new'


def _record(out: Path, entry: dict[str, Any]) -> None:
  path = out / ROUNDS_FILE
  records = json.loads(path.read_text()) if path.is_file() else []
  records = [e for e in records if (e['round'], e['step']) != (entry['round'], entry['step'])] + [entry]
  atomic_write_text(path, json.dumps(records, indent=1) + '\n')


def run_rounds(generate: GenerateConfig, train: TrainConfig, out_dir: str | os.PathLike[str], rounds: int,
               images_per_round: int, *, init: str | None = None, base_data: Sequence[str | os.PathLike[str]] = (),
               aggregate: bool = False, workers: int = 1, backend: str = 'process', cache_dir: str | None = None,
               progress: bool = True, log: Callable[..., None] = print) -> list[dict[str, Any]]:
  """Runs (or resumes) ``rounds`` on-policy rounds into ``out_dir``; returns the records of ``rounds.json``.

  Args:
    generate: the generation config of every round (its collection policy is replaced from round 1 on, and in
      round 0 when ``init`` is given).
    train: the training config of every round (``init`` replaced from round 1 on).
    out_dir: the rounds' directory (``round-<r>/data``, ``round-<r>/train``, ``rounds.json``).
    rounds: number of rounds >= 1.
    images_per_round: images each round's collection renders.
    init: models to collect round 0 with and start its training from (None: the config's tau, from scratch).
    base_data: dataset directories every round also trains on (`round_training_data`).
    aggregate: each round trains on every round's collection so far, not only its own.
    workers, backend, cache_dir, progress: as `dexjax.generate.generate_dataset`.
    log: receives one line per step.

  Raises:
    FileNotFoundError: a ``base_data`` directory holds no shards.
    ValueError: ``rounds`` or ``images_per_round`` < 1; what `generate_dataset` and `train_run` raise.
    RuntimeError: some shards of a round's collection failed (rerun to retry them; nothing is trained on a
      partial round).
  """
  from dexjax.generate.run import generate_dataset  # pylint: disable=g-import-not-at-top (slow imports)
  from dexjax.train.run import train_run  # pylint: disable=g-import-not-at-top
  if rounds < 1 or images_per_round < 1:
    raise ValueError(f'rounds, images_per_round: expected integers >= 1, got {rounds}, {images_per_round}')
  if base_data:  # before the first (long) collection
    require_shards(base_data, 'every round trains on it (--base-data): expected a python -m dexjax.generate run')
  out = Path(out_dir)
  out.mkdir(parents=True, exist_ok=True)
  for r in range(rounds):
    data_dir, train_dir = round_dirs(out, r)
    state = _training_state(train_dir)
    if state == 'done':
      log(f'round {r}: done ({train_dir})')
      continue
    gen, tr = round_configs(generate, train, out, r, init)
    how = f'on-policy with {gen.collection.model}' if gen.collection.policy == 'on_policy' else 'with tau'
    log(f'round {r}: collecting {images_per_round} images {how} into {data_dir}')
    data = generate_dataset(gen, data_dir, images_per_round, backend=backend, workers=workers, cache_dir=cache_dir,
                            progress=progress, preview=False)
    if data['shards']['failed']:
      raise RuntimeError(f'round {r}: {len(data["shards"]["failed"])} shards of {data_dir} failed '
                         f'({data["shards"]["failed"]}); rerun to retry them')
    _record(out, {'round': r, 'step': 'collect', 'data': os.fspath(data_dir), 'rows': data['rows'],
                  'collection': dataclasses.asdict(gen.collection), 'grippers': data['grippers'],
                  'seconds': data['seconds']})
    start = 'resumed' if state == 'resume' else f'from {tr.init or "scratch"}'
    data_dirs = round_training_data(out, r, base_data, aggregate)
    log(f'round {r}: training into {train_dir} ({start}) on {len(data_dirs)} dataset(s)')
    summary = train_run(tr, data_dirs, train_dir, resume=state == 'resume', progress=progress, log=log)
    _record(out, {'round': r, 'step': 'train', 'out': os.fspath(train_dir), 'init': tr.init,
                  'data': [os.fspath(d) for d in data_dirs],
                  'grippers': summary['grippers'], 'seconds': summary['seconds']})
  path = out / ROUNDS_FILE
  return json.loads(path.read_text()) if path.is_file() else []


__all__ = ['ROUNDS_FILE', 'round_configs', 'round_dirs', 'round_training_data', 'run_rounds']
