"""Writes the meshes from outside the project that the shipped models are scored and fine-tuned on (docs/models.md).

Usage: ``python scripts/external_meshes.py OUT_DIR`` (needs ``pip install -e ".[bench]"`` for ``pybullet_data``).

``OUT_DIR/external``: ``pybullet_data``'s ``random_urdfs`` 000-049 at the 0.015 scale their URDFs give (≈ 6-12 cm),
and its duck, bunny and torus scaled to a largest side of 10, 10 and 8 cm. ``OUT_DIR/finetune``: ``random_urdfs``
050-099 the same way. STL files (trimesh), one per object; nothing of pybullet ships with dexjax.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import trimesh

URDF_SCALE = 0.015  # random_urdfs/NNN/NNN.urdf: <mesh filename="NNN.obj" scale="0.015 0.015 0.015"/>
EXTERNAL_URDFS = range(0, 50)
FINETUNE_URDFS = range(50, 100)
SHAPES = {'duck': ('duck.obj', 0.10), 'bunny': ('bunny.obj', 0.10), 'torus': ('torus/torus_textured.obj', 0.08)}


def _random_urdf(root: Path, index: int) -> trimesh.Trimesh:
  name = f'{index:03d}'
  mesh = trimesh.load(root / 'random_urdfs' / name / f'{name}.obj', force='mesh')
  mesh.apply_scale(URDF_SCALE)
  return mesh


def _shape(root: Path, path: str, size: float) -> trimesh.Trimesh:
  mesh = trimesh.load(root / path, force='mesh')
  mesh.apply_scale(size / mesh.extents.max())
  return mesh


def write_meshes(out: Path) -> dict[str, int]:
  """Writes ``out/external`` and ``out/finetune``; returns the number of files in each."""
  import pybullet_data  # pylint: disable=g-import-not-at-top (bench extra)
  root = Path(pybullet_data.getDataPath())
  sets = {'external': {f'{i:03d}': _random_urdf(root, i) for i in EXTERNAL_URDFS},
          'finetune': {f'{i:03d}': _random_urdf(root, i) for i in FINETUNE_URDFS}}
  sets['external'].update({name: _shape(root, path, size) for name, (path, size) in SHAPES.items()})
  for name, meshes in sets.items():
    (out / name).mkdir(parents=True, exist_ok=True)
    for stem, mesh in meshes.items():
      mesh.export(out / name / f'{stem}.stl')
  return {name: len(meshes) for name, meshes in sets.items()}


def main(argv: list[str] | None = None) -> int:
  parser = argparse.ArgumentParser(prog='python scripts/external_meshes.py', description=__doc__.splitlines()[0])
  parser.add_argument('out', type=Path, help='directory for external/ and finetune/')
  args = parser.parse_args(argv)
  try:
    counts = write_meshes(args.out)
  except ImportError:
    print('error: pybullet_data is missing; expected pip install -e ".[bench]"', file=sys.stderr)
    return 2
  print(counts)
  return 0


if __name__ == '__main__':
  sys.exit(main())
