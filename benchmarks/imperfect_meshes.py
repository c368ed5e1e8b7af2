"""Imperfect meshes (open, non-manifold, mis-wound) loaded as solids: how close are their grids and labels to the
closed originals? One JSON object on stdout.

  python benchmarks/imperfect_meshes.py [--objects builtin:box builtin:cylinder ...] [--grasps 400]
                                        [--grid-size 64] [--seed 0] [--defects holes fins ...] [--no-grids]

For every object (default: the built-in shapes and procedural objects of levels 1-3):

* **grids** (``watertight``): the closed mesh is also passed through `dexjax.geometry.winding` (the path an
  imperfect mesh takes: visibility orientation, winding-number inside test, marching cubes at 1/128 of the
  largest extent, decimation to 20,000 faces) and both are built at ``--grid-size``; reported: the largest and
  the 99th-percentile |difference| of the signed distance grids in voxels, within 3 voxels of the surface
  (``near_surface``) and everywhere, and the fraction of grid points whose inside/outside agrees (points
  closer than 1/1000 voxel to the surface, e.g. exactly on a box's face, excluded);
  ``winding_vs_pseudonormal``: `winding_signed_distance` of the closed mesh against libigl's pseudonormal
  signed distance at the same grid points (same magnitudes; the fraction of signs that agree);
* **labels**: imperfect copies of the mesh subdivided to edges of at most 1/25 of its extent (as assets are
  tessellated; `dexjax.objects.defects`: two large holes, a missing side, a seam gap, six non-manifold fins, a
  double wall of duplicated faces, holes with 30 % of faces flipped) are loaded with `validate_and_repair`
  like a file, built at ``--grid-size``, and ``--grasps`` antipodal and suction grasps sampled on the original
  are labelled robust (M = 10, threshold 0.5, the same keys) on both; reported: the fraction of labels that
  agree, the positive rates, and the mean |probability difference| (a copy that no longer encloses a volume
  is reported as ``rejected`` with the reason; a gripper without valid grasps on the object has
  ``grasps: 0``); ``--defects`` and ``--no-grids`` run a subset;
* ``solidify_s``: seconds to load each copy, solidifying included (run with an empty ``$DEXJAX_CACHE``: solids
  are cached by content).

Reading: the grid differences are the reconstruction's (marching cubes; sharp edges are rounded by up to
about half a reconstruction voxel, 1/128 of the extent, i.e. ~0.25 of a 64^3 grid voxel); the label
agreement includes the change of geometry the defect makes (a missing cap is closed by the winding
number's 0.5 level, which is not exactly the original cap).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
import zlib

import igl
import jax
import numpy as np
import trimesh

from dexjax.geometry import (ImperfectMeshWarning, MeshError, build_object_model, grid_frame, solidify, validate_and_repair,
                             winding_signed_distance)
from dexjax.objects import defects, resolve_mesh
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality import evaluate_grasps, parallel_jaw_perturbations, suction_perturbations
from dexjax.sampling import sample_antipodal_grasps, sample_suction_grasps

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from _machine import describe  # noqa: E402

DEFAULT_OBJECTS = ['builtin:box', 'builtin:cylinder', 'builtin:l_shape', 'builtin:box_with_hole', 'builtin:sphere',
                   'procedural:L1/0', 'procedural:L2/0', 'procedural:L2/1', 'procedural:L3/0']


def _defects(mesh):
  # Assets are finely tessellated: subdivide to edges <= 1/25 of the extent first (same surface).
  mesh = mesh.subdivide_to_size(max_edge=float(np.max(mesh.extents)) / 25, max_iter=20)
  return {
      'holes': defects.open_holes(mesh, num_holes=2, radius=0.15, seed=1),
      'missing_side': defects.remove_facing(mesh, (0.0, 0.0, 1.0), 30.0),
      'seam': defects.split_seam(mesh, axis=0),
      'fins': defects.add_fins(mesh, num_fins=6, seed=1),
      'duplicated': defects.duplicate_faces(mesh, fraction=0.2, seed=1),
      'holes_flipped': defects.flip_faces(defects.open_holes(mesh, num_holes=2, radius=0.15, seed=2), 0.3, seed=2),
  }


def _pj_prob(model, key, grasps):
  return evaluate_grasps(key, model, grasps, ParallelJawGripper(), parallel_jaw_perturbations()).probability


def _suction_prob(model, key, grasps):
  return evaluate_grasps(key, model, grasps, SuctionGripper(), suction_perturbations()).probability


def _grid_points(model):
  d = model.sdf.shape[0]
  axis = np.arange(d) * float(model.voxel_size)
  origin = np.asarray(model.origin, np.float64)
  g = np.stack(np.meshgrid(*[origin[i] + axis for i in range(3)], indexing='ij'), axis=-1)
  return g.reshape(-1, 3)


def _grid_comparison(mesh, original, grid_size):
  v, f = solidify(mesh.vertices, mesh.faces)
  rebuilt_mesh = validate_and_repair(trimesh.Trimesh(v, f, process=False))
  points = _grid_points(original)
  a = np.asarray(original.sdf, np.float64).reshape(-1)
  dist, *_ = igl.signed_distance(points, np.asarray(rebuilt_mesh.vertices, np.float64),
                                 np.asarray(rebuilt_mesh.faces, np.int64),
                                 sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)
  voxel = float(original.voxel_size)
  diff = np.abs(a - dist) / voxel
  near = np.abs(a) <= 3 * voxel
  wn = winding_signed_distance(mesh.vertices, mesh.faces, points)
  return {
      'rebuilt_faces': int(len(rebuilt_mesh.faces)),
      'volume_ratio': float(rebuilt_mesh.volume / mesh.volume),
      'rebuilt_grid_frame_voxel_ratio': grid_frame(rebuilt_mesh.bounds, grid_size, 5)[1] / float(original.voxel_size),
      'max_abs_diff_voxels_near_surface': float(diff[near].max()),
      'p99_abs_diff_voxels_near_surface': float(np.quantile(diff[near], 0.99)),
      'max_abs_diff_voxels': float(diff.max()),
      'inside_agreement_beyond_1e-3_voxel': float(np.mean(((a < 0) == (dist < 0))[np.abs(a) > 1e-3 * voxel])),
      'winding_vs_pseudonormal': {
          'max_abs_magnitude_diff_m': float(np.abs(np.abs(wn) - np.abs(a)).max()),
          'sign_agreement': float(np.mean((wn < 0) == (a < 0))),
          'sign_agreement_beyond_1e-4_voxel': float(np.mean(((wn < 0) == (a < 0))[np.abs(a) > 1e-4 * voxel])),
      },
  }


def _labels(model_a, model_b, key, n):
  k_pj, k_s, k_q = jax.random.split(key, 3)
  out = {}
  for gripper, sampler, prob in (('parallel_jaw', sample_antipodal_grasps, _pj_prob),
                                 ('suction', sample_suction_grasps, _suction_prob)):
    grasps, valid = sampler(k_pj if gripper == 'parallel_jaw' else k_s, model_a, 4 * n)
    idx = np.nonzero(np.asarray(valid))[0][:n]
    if len(idx) == 0:  # e.g. an object wider than the jaws everywhere
      out[gripper] = {'grasps': 0}
      continue
    grasps = jax.tree.map(lambda x: x[idx], grasps)
    pa, pb = np.asarray(prob(model_a, k_q, grasps)), np.asarray(prob(model_b, k_q, grasps))
    la, lb = pa > 0.5, pb > 0.5
    out[gripper] = {'grasps': int(len(idx)), 'agreement': float(np.mean(la == lb)),
                    'positive_rate_original': float(la.mean()), 'positive_rate_imperfect': float(lb.mean()),
                    'mean_abs_probability_difference': float(np.mean(np.abs(pa - pb)))}
  return out


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  p.add_argument('--objects', nargs='+', default=DEFAULT_OBJECTS)
  p.add_argument('--grasps', type=int, default=400)
  p.add_argument('--grid-size', type=int, default=64)
  p.add_argument('--seed', type=int, default=0)
  p.add_argument('--defects', nargs='+', default=None, help='only these kinds of defect (default: all)')
  p.add_argument('--no-grids', action='store_true', help='skip the watertight grid comparison')
  args = p.parse_args()
  result = {'benchmark': 'imperfect_meshes', 'grid_size': args.grid_size, 'grasps': args.grasps,
            'machine': describe(), 'objects': {}}
  key = jax.random.key(args.seed)
  for spec in args.objects:
    mesh, _ = resolve_mesh(spec)
    entry = {'faces': int(len(mesh.faces)), 'defects': {}}
    original = build_object_model(mesh, grid_size=args.grid_size)
    if not args.no_grids:
      entry['watertight'] = _grid_comparison(mesh, original, args.grid_size)
    for name, broken in _defects(mesh).items():
      if args.defects and name not in args.defects:
        continue
      t = time.perf_counter()
      with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always', ImperfectMeshWarning)
        try:
          solid = validate_and_repair(broken, f'{spec}:{name}')
        except MeshError as e:  # e.g. a dome whose top third is gone encloses nothing any more
          entry['defects'][name] = {'rejected': e.reason}
          print(f'{spec} {name}: rejected: {e.reason}', file=sys.stderr)
          continue
      seconds = time.perf_counter() - t
      model = build_object_model(solid, grid_size=args.grid_size)
      # The same grid frame as the original (labels compare the same grasps; the frame follows the bounds).
      entry['defects'][name] = {
          'warned': any(issubclass(w.category, ImperfectMeshWarning) for w in caught),
          'solidify_s': round(seconds, 3), 'volume_ratio': float(solid.volume / mesh.volume),
          **_labels(original, model, jax.random.fold_in(key, zlib.crc32(name.encode())), args.grasps)}
      print(f'{spec} {name}: {json.dumps(entry["defects"][name])}', file=sys.stderr)
    result['objects'][spec] = entry
  for gripper in ('parallel_jaw', 'suction'):
    agreements = [d[gripper]['agreement'] for e in result['objects'].values() for d in e['defects'].values()
                  if 'rejected' not in d and d[gripper]['grasps'] > 0]
    result[f'{gripper}_agreement_min'] = min(agreements)
    result[f'{gripper}_agreement_median'] = float(np.median(agreements))
    result[f'{gripper}_agreement_at_least_95_percent'] = float(np.mean(np.asarray(agreements) >= 0.95))
  result['rejected_copies'] = sum('rejected' in d for e in result['objects'].values() for d in e['defects'].values())
  print(json.dumps(result))


if __name__ == '__main__':
  main()
