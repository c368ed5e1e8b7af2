"""Records the label rows of tests/test_generate.py's small run, made by the dexjax this imports, as the reference
that `test_labels_match_the_recorded_rows` compares every later version with (re-record it, and say why in the
test, only when what a run makes is meant to change).

  # in a checkout of the reference commit (e.g. git worktree add ../ref 07484d8), with the tests of this one:
  PYTHONPATH=../ref python scripts/record_generate_reference.py tests/data/generate_small_rows_<commit>.npz --repo ../ref
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile

import numpy as np



def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
  p.add_argument('out', help='the .npz to write')
  p.add_argument('--repo', default='.', help='checkout whose commit is recorded (the one on PYTHONPATH)')
  args = p.parse_args()
  sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'tests'))
  from test_generate import NUM_IMAGES, SMALL  # pylint: disable=import-outside-toplevel
  import dexjax  # pylint: disable=import-outside-toplevel
  from dexjax.data import ROW_SCHEMA, read_shard, shard_path  # pylint: disable=import-outside-toplevel
  from dexjax.generate.config import config_from_dict  # pylint: disable=import-outside-toplevel
  from dexjax.generate.run import generate_dataset, num_shards  # pylint: disable=import-outside-toplevel
  from dexjax.render import DepthRenderer  # pylint: disable=import-outside-toplevel
  config = config_from_dict(SMALL, 'small.yaml')
  with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
    generate_dataset(config, out, NUM_IMAGES, cache_dir=cache, progress=False, preview=False)
    shards = [read_shard(shard_path(out, i)) for i in range(num_shards(config, NUM_IMAGES))]
  fields = [k for k in ROW_SCHEMA if k != 'image_index']  # the labels; image indices depend only on the layout
  rows = {k: np.concatenate([s.rows[k] for s in shards]) for k in fields}
  commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], capture_output=True, text=True, check=True,
                          cwd=args.repo).stdout.strip()
  renderer = DepthRenderer(8, 8)
  backend = renderer.backend
  renderer.close()
  np.savez_compressed(args.out, commit=np.array(commit), render_backend=np.array(backend), **rows)
  print(f'{args.out}: {len(rows["gripper"])} rows of dexjax {commit} ({dexjax.__file__})')


if __name__ == '__main__':
  main()
