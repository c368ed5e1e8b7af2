"""``python -m dexjax.generate`` end to end on two worker processes, in a subprocess, and its resume.

Marked ``heavy`` (a label: the suite and CI run it): each worker compiles the labeller (~3 minutes here in all).
``tests/test_generate.py`` covers the same CLI in-process, ``tests/test_parallel.py`` the process and Ray backends
with small tasks.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from dexjax.data import GRIPPER_NAMES, list_shards, load_manifest
from dexjax.generate.__main__ import main

sys.path.insert(0, os.path.dirname(__file__))
from test_generate import NUM_IMAGES, SMALL  # pylint: disable=g-import-not-at-top,wrong-import-position

SMALL_OBJECTS = ('cube', 'cylinder', 'l_shape', 'L1/0', 'L1/1', 'L1/2')
TIMEOUT = 600  # seconds; the run takes ~1-2 minutes here


@pytest.fixture
def small_yaml(tmp_path) -> Path:
  path = tmp_path / 'small.yaml'
  path.write_text(yaml.safe_dump(SMALL))
  return path


def _cli(*args: str, cache: Path) -> subprocess.CompletedProcess:
  env = {**os.environ, 'DEXJAX_CACHE': str(cache)}
  return subprocess.run([sys.executable, '-m', 'dexjax.generate', *args], capture_output=True, text=True, env=env,
                        timeout=TIMEOUT, check=False)


def _digests(out: Path) -> dict[str, str]:
  return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in list_shards(out)}


@pytest.mark.heavy
def test_parallel_run_writes_shards_summary_and_preview_then_resumes_without_rewriting(small_yaml, tmp_path,
                                                                                        capsys):
  out, cache = tmp_path / 'out', tmp_path / 'cache'
  command = ('--config', str(small_yaml), '--out', str(out), '--num-images', str(NUM_IMAGES), '--workers', '2',
             '--backend', 'process', '--cache-dir', str(cache), '--json')
  first = _cli(*command, cache=cache)
  assert first.returncode == 0, first.stderr[-3000:]
  assert 'parts failed' not in first.stderr
  summary = json.loads(first.stdout)
  assert summary['shards'] == {'total': 2, 'assigned': 2, 'skipped': 0, 'written': 2, 'failed': {}}
  assert summary['images'] == NUM_IMAGES and summary['heaps'] == NUM_IMAGES
  rows = 0
  for name in GRIPPER_NAMES:
    stats = summary['grippers'][name]
    assert stats['rows'] > 0
    assert 0.0 < stats['positive_rate'] < 1.0, (name, stats)
    assert sum(stats['failures'].values()) == stats['rows'], (name, stats)
    rows += stats['rows']
  assert rows == summary['rows'] > 0
  assert [p.name for p in list_shards(out)] == ['shard-000000.npz', 'shard-000001.npz']
  assert sorted(load_manifest(out).shards) == [0, 1]
  assert (out / 'manifest.json').is_file() and (out / 'config.json').is_file()
  assert summary['preview'] == str(out / 'preview.png') and (out / 'preview.png').stat().st_size > 10_000
  assert not list(out.glob('*.tmp-*'))
  # The object caches were built on the two workers (interleaved parts), one supervisor set per object.
  assert len(list((cache / 'supervisor').glob('supervisor-*.npz'))) == len(SMALL_OBJECTS)
  digests = _digests(out)

  # The same command again (in-process: it generates nothing, so the interpreter start would be most of its
  # time): every shard is already done, nothing is rewritten.
  capsys.readouterr()
  assert main(list(command)) == 0
  summary = json.loads(capsys.readouterr().out)
  assert summary['shards'] == {'total': 2, 'assigned': 2, 'skipped': 2, 'written': 0, 'failed': {}}
  assert summary['rows'] == 0
  assert _digests(out) == digests

  # Worker 1 of 2 owns shard 1 only (done): in-process, no generation.
  assert main([*command, '--shard', '1/2', '--no-preview']) == 0
  summary = json.loads(capsys.readouterr().out)
  assert summary['shards'] == {'total': 2, 'assigned': 1, 'skipped': 1, 'written': 0, 'failed': {}}
  assert _digests(out) == digests
