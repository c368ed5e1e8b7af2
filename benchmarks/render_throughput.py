"""Depth + mask rendering throughput of settled heaps, per backend, one JSON object on stdout.

  python benchmarks/render_throughput.py [--images 30] [--raycast-images 10] [--repeats 3] [--heaps 2]

Heaps of 5 and 10 objects (the built-in objects of ``heap_throughput.py``, full visual meshes, settled with
`dexjax.sim.settle(backend='rollout')`) are rendered at 500 x 500 from ``--images`` cameras circling the bin
(drawn from the seed's camera distribution, `dexjax.render.sample_camera`; the first ``--raycast-images`` of
them for ray casting). ``images_per_s`` is the median over ``--repeats`` passes per heap of the images per second of a pass
(depth and slot mask, the `DepthImage` returned). The scene is built and uploaded before timing:
``model_build_s`` (MuJoCo model compile, median over heaps) and ``first_render_s`` (GL upload of the meshes
plus one image) are reported separately; ``object_pixel_fraction`` is the share of object pixels (mask >= 0)
in the last image of each pass. ``*_over_baseline`` divides a backend's images/s by the baseline's.

Backends: ``gl_egl`` and ``gl_osmesa`` each run in a child process (PyOpenGL binds one platform per process),
``raycast`` in this process (``mj_multiRay``, ``os.cpu_count()`` threads). ``baseline_images_per_s``: plain
trimesh/NumPy ray casting (``trimesh.ray.ray_triangle``, one ray per pixel against all triangles of the scene
with an R-tree) of one 10-object heap, timed on every 10th pixel row and scaled to the full image.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time

import jax
import numpy as np
import trimesh

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import heap_throughput  # pylint: disable=g-import-not-at-top,wrong-import-position

import dexjax.sim as sim  # pylint: disable=wrong-import-position
from dexjax.objects import builtin_mesh  # pylint: disable=wrong-import-position
from dexjax.render import rendering  # pylint: disable=wrong-import-position
from dexjax.render.camera import Camera  # pylint: disable=wrong-import-position
from dexjax.render.distribution import sample_camera  # pylint: disable=wrong-import-position
from dexjax.render.rendering import render_boxes  # pylint: disable=wrong-import-position

SIZE = 500


def meshes(count: int) -> list[trimesh.Trimesh]:
  """The full visual meshes of `heap_throughput.objects(count)`, in the same order and scale."""
  out = []
  for scale in (1.0, 0.75):
    for name in heap_throughput._BASE:  # pylint: disable=protected-access
      out.append(builtin_mesh(name).apply_scale(scale))
  return out[:count]


def settled_heaps(count: int, num_heaps: int) -> tuple[list[trimesh.Trimesh], np.ndarray, sim.SettleResult]:
  """(meshes, object ids (B, P), settle result) of ``num_heaps`` heaps of ``count`` objects."""
  states = heap_throughput.states(count, num_heaps)
  result = sim.settle(heap_throughput.objects(count), states, backend='rollout')
  return meshes(count), np.asarray(states.object_ids), result


def cameras(num: int) -> list[Camera]:
  """``num`` cameras drawn from the Dex-Net 4.0 camera distribution (`dexjax.render.sample_camera`)."""
  keys = jax.random.split(jax.random.key(0), num)
  return [sample_camera(k) for k in keys]


def bench_backend(backend: str, gl_platform: str | None, args: argparse.Namespace) -> dict:
  """Throughput of one backend for heaps of 5 and 10 objects."""
  renderer = rendering.DepthRenderer(SIZE, SIZE, backend=backend, gl_platform=gl_platform)
  views = cameras(args.images if backend == 'gl' else args.raycast_images)
  out = {'backend': renderer.backend}
  for count in (5, 10):
    mesh_list, ids, result = settled_heaps(count, args.heaps)
    builds, firsts, rates, objects = [], [], [], []
    for heap in range(args.heaps):
      t = time.perf_counter()
      scene = rendering.settled_heap_scene(mesh_list, ids, result, heap)
      builds.append(time.perf_counter() - t)
      t = time.perf_counter()
      renderer.render(scene, views[0])
      firsts.append(time.perf_counter() - t)
      for _ in range(args.repeats):
        t = time.perf_counter()
        for camera in views:
          image = renderer.render(scene, camera)
        rates.append(len(views) / (time.perf_counter() - t))
        objects.append(float(np.mean(image.mask >= 0)))
    faces = sum(len(mesh_list[i].faces) for i in ids[0][result.mask[0]])
    out[f'objects_{count}'] = {'images_per_s': float(np.median(rates)), 'model_build_s': float(np.median(builds)),
                               'first_render_s': float(np.median(firsts)), 'heaps': args.heaps,
                               'images_per_pass': len(views), 'faces_per_heap': int(faces),
                               'object_pixel_fraction': float(np.mean(objects))}
  renderer.close()
  return out


def baseline(args: argparse.Namespace) -> dict:
  """trimesh ray casting (NumPy + R-tree) of one 10-object heap, every 10th row, scaled to a full image."""
  mesh_list, ids, result = settled_heaps(10, 1)
  parts = [trimesh.creation.box(extents=2 * half).apply_translation(centre) for centre, half in render_boxes(sim.Bin())]
  parts += [m for _, m in sim.posed_meshes(mesh_list, ids[0], result.poses[0], result.mask[0])]
  scene = trimesh.util.concatenate(parts)
  camera = cameras(args.images)[0]
  rows = np.arange(0, SIZE, 10)
  v, u = np.meshgrid(rows.astype(float), np.arange(SIZE, dtype=float), indexing='ij')
  k = camera.intrinsics
  rays = np.stack([(u - float(k.cx)) / float(k.fx), (v - float(k.cy)) / float(k.fy), np.ones_like(u)], -1).reshape(-1, 3)
  dirs = rays @ np.asarray(camera.rotation, np.float64).T
  origins = np.tile(np.asarray(camera.position, np.float64), (len(dirs), 1))
  intersector = trimesh.ray.ray_triangle.RayMeshIntersector(scene)
  t = time.perf_counter()
  intersector.intersects_location(origins, dirs, multiple_hits=False)
  seconds = (time.perf_counter() - t) * SIZE / len(rows)
  return {'baseline_images_per_s': 1.0 / seconds, 'baseline_method': 'trimesh.ray.ray_triangle (NumPy, R-tree)',
          'baseline_rows_timed': int(len(rows)), 'baseline_faces': int(len(scene.faces))}


def _child(gl_platform: str, args: argparse.Namespace) -> dict:
  """Runs ``--worker gl_<platform>`` in a fresh process; its JSON, or the failure."""
  env = {k: v for k, v in os.environ.items() if k not in ('PYOPENGL_PLATFORM', 'MUJOCO_GL')}
  cmd = [sys.executable, os.path.abspath(__file__), '--worker', gl_platform, '--images', str(args.images),
         '--repeats', str(args.repeats), '--heaps', str(args.heaps)]
  run = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False, timeout=1800)
  if run.returncode != 0:
    return {'status': 'failed', 'error': (run.stderr.strip().splitlines() or ['?'])[-1]}
  return json.loads(run.stdout.strip().splitlines()[-1])


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--images', type=int, default=30)
  parser.add_argument('--repeats', type=int, default=3)
  parser.add_argument('--heaps', type=int, default=2)
  parser.add_argument('--raycast-images', type=int, default=10)
  parser.add_argument('--worker', choices=('egl', 'osmesa'), default=None, help=argparse.SUPPRESS)
  args = parser.parse_args()
  if args.worker is not None:
    print(json.dumps(bench_backend('gl', args.worker, args)))
    return
  out = {'image_size': [SIZE, SIZE], 'cpu_count': os.cpu_count(), 'machine': platform.machine(),
         'jax_backend': jax.default_backend()}
  backends = {f'gl_{p}': _child(p, args) for p in ('egl', 'osmesa')}
  backends['raycast'] = bench_backend('raycast', None, args)
  out.update(baseline(args))
  for name, res in backends.items():
    for count in (5, 10):
      if f'objects_{count}' in res:
        rate = res[f'objects_{count}']['images_per_s']
        out[f'{name}_{count}_objects_images_per_s'] = rate
        out[f'{name}_{count}_objects_over_baseline'] = rate / out['baseline_images_per_s']
  out['backends'] = backends
  print(json.dumps(out, indent=1))


if __name__ == '__main__':
  main()
