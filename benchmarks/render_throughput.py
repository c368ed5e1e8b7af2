"""Depth + mask rendering throughput of settled heaps, dexjax vs. pyrender offscreen, one JSON object on stdout.

  python benchmarks/render_throughput.py [--images 30] [--raycast-images 10] [--repeats 3] [--heaps 2]

Heaps of 5 and 10 objects (the built-in objects of ``heap_throughput.py``, full visual meshes, settled with
`dexjax.sim.settle(backend='rollout')`) are rendered at 500 x 500 from ``--images`` cameras drawn from the
seed's camera distribution (`dexjax.render.sample_camera`; the first ``--raycast-images`` of them for ray
casting). ``images_per_s`` is the median over ``--repeats`` passes per heap of the images per second of a
pass (depth and a per-object mask per image). Every scene is built and uploaded before timing:
``model_build_s`` (scene build, median over heaps) and ``first_render_s`` (GL upload of the meshes plus one
image) are reported separately; ``object_pixel_fraction`` is the share of object pixels (mask >= 0) in the
last image of each pass.

dexjax backends: ``gl_egl`` and ``gl_osmesa`` (`DepthRenderer(backend='gl')`, MuJoCo's renderer) each run in a
child process with ``PYOPENGL_PLATFORM`` set to that platform (PyOpenGL binds one platform per process);
``raycast`` (``mj_multiRay``, ``os.cpu_count()`` threads) in this process.

Baseline, measured in the same child processes on the same platform: **pyrender offscreen**, the plain way to
render trimesh meshes with OpenGL that the original's renderer (meshrender, pyrender's predecessor) used:
a ``pyrender.Scene`` per heap with the bin and table boxes (`render_boxes`) and every object's full visual
mesh as a ``pyrender.Mesh.from_trimesh`` node at its settled pose, one ``pyrender.IntrinsicsCamera`` node
(fx, fy, cx + 0.5, cy + 0.5: pyrender puts pixel centres at half-integers, dexjax at integers; the OpenCV
camera pose is turned into OpenGL's by flipping its y and z axes), znear / zfar = dexjax's `RenderSettings`
(0.01 / 10 m), one ``pyrender.OffscreenRenderer(500, 500)`` reused for every image. Per image the camera
node's pose and intrinsics are set and one ``render(scene, flags=RenderFlags.SEG, seg_node_map=...)`` pass
returns the depth buffer and a flat-colour segmentation image (one colour per object, one for the bin),
which is decoded with NumPy into dexjax's mask convention (slot, -1 bin, -2 nothing; depth NaN where
nothing). pyrender's other settings are its defaults (back-face culling; its 4-sample framebuffer, with
multisampling switched off for SEG passes, so segment colours never blend).
``*_over_baseline`` divides a dexjax backend's images/s by pyrender's: for ``gl_<platform>`` the median of
the per-pass ratios against pyrender on the same platform (passes interleaved: dexjax, pyrender, dexjax, ...),
for ``raycast`` against the faster pyrender platform's median. ``agreement_<platform>_<count>_objects`` checks the
baseline: on every heap and camera, the median and 99th percentile of |pyrender depth - dexjax depth| over
pixels valid in both (metres) and the fraction of pixels whose masks agree.

Install of the baseline (pyrender 0.1.45 pins PyOpenGL==3.1.0, which would downgrade the PyOpenGL 3.1.10
that MuJoCo's renderer uses, so it is installed without its dependencies):

  pip install -e ".[bench]" && pip install --no-deps "pyrender==0.1.45"

(the ``bench`` extra holds pyrender's real dependencies: pyglet < 2, freetype-py, imageio, networkx, six, pillow).

pyrender 0.1.45 still uses ``np.infty`` (removed in NumPy 2); this script restores the alias before import.

Without pyrender (or when its renderer cannot start) the dexjax backends are measured all the same: the child's
``pyrender`` entry says ``"status": "missing"`` (or ``"failed"``) with the reason, ``baseline_missing`` repeats it
per platform, and the baseline's figures and every ``*_over_baseline`` ratio are null.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import jax
import numpy as np
import trimesh

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from _machine import describe  # noqa: E402
from _optional import missing, version  # noqa: E402
import heap_throughput  # pylint: disable=g-import-not-at-top,wrong-import-position

import dexjax.sim as sim  # pylint: disable=wrong-import-position
from dexjax.objects import builtin_mesh  # pylint: disable=wrong-import-position
from dexjax.render import rendering  # pylint: disable=wrong-import-position
from dexjax.render.camera import Camera  # pylint: disable=wrong-import-position
from dexjax.render.distribution import sample_camera  # pylint: disable=wrong-import-position
from dexjax.render.rendering import BIN_LABEL, INVALID_LABEL, RenderSettings, render_boxes  # pylint: disable=wrong-import-position

SIZE = 500
_BIN_RED = 255  # segmentation colour (red channel) of the bin; object slot s is s + 1, nothing is 0


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


def _pose_matrix(pose: np.ndarray) -> np.ndarray:
  """(4, 4) world-from-object transform of a (7,) pose: position, quaternion wxyz."""
  out = np.eye(4)
  out[:3, :3] = sim.quat_to_matrix(np.asarray(pose[3:], np.float64) / np.linalg.norm(pose[3:]))
  out[:3, 3] = pose[:3]
  return out


class PyrenderBaseline:
  """pyrender offscreen rendering of one heap at a time: depth + per-object mask (see the module doc)."""

  def __init__(self, width: int, height: int, settings: RenderSettings = RenderSettings()):
    if not hasattr(np, 'infty'):  # pyrender 0.1.45 uses np.infty, removed in NumPy 2
      np.infty = np.inf
    import pyrender  # pylint: disable=g-import-not-at-top,import-outside-toplevel
    self.pyrender = pyrender
    self.settings = settings
    self.renderer = pyrender.OffscreenRenderer(width, height)
    self.scene, self.camera_node, self.seg_map = None, None, None

  def build(self, mesh_list, object_ids, poses, mask) -> None:
    """The scene of one heap: bin and table boxes, every object's full mesh at its pose, one camera node."""
    pr = self.pyrender
    scene = pr.Scene(bg_color=[0.0, 0.0, 0.0, 0.0])
    seg = {}
    for centre, half in render_boxes(sim.Bin()):
      transform = np.eye(4)
      transform[:3, 3] = centre
      node = scene.add(pr.Mesh.from_trimesh(trimesh.creation.box(extents=2 * np.asarray(half))), pose=transform)
      seg[node] = (_BIN_RED, 0, 0)
    for slot in np.flatnonzero(np.asarray(mask, bool)):
      node = scene.add(pr.Mesh.from_trimesh(mesh_list[int(object_ids[slot])]), pose=_pose_matrix(poses[slot]))
      seg[node] = (int(slot) + 1, 0, 0)
    camera = pr.IntrinsicsCamera(fx=500.0, fy=500.0, cx=250.0, cy=250.0, znear=self.settings.near,
                                 zfar=self.settings.far)
    self.camera_node = scene.add(camera, pose=np.eye(4))
    self.scene, self.seg_map = scene, seg

  def render(self, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(depth (H, W) float32 metres, NaN where nothing; mask (H, W) int32 in dexjax's convention)."""
    k = camera.intrinsics
    cam = self.camera_node.camera
    cam.fx, cam.fy = float(k.fx), float(k.fy)
    cam.cx, cam.cy = float(k.cx) + 0.5, float(k.cy) + 0.5  # pyrender: pixel centres at half-integers
    pose = np.eye(4)
    pose[:3, :3] = np.asarray(camera.rotation, np.float64) @ np.diag([1.0, -1.0, -1.0])  # OpenCV -> OpenGL axes
    pose[:3, 3] = np.asarray(camera.position, np.float64)
    self.scene.set_pose(self.camera_node, pose)
    color, depth = self.renderer.render(self.scene, flags=self.pyrender.RenderFlags.SEG, seg_node_map=self.seg_map)
    red = color[..., 0].astype(np.int32)
    valid = depth > 0
    mask = np.where(~valid | (red == 0), INVALID_LABEL, np.where(red == _BIN_RED, BIN_LABEL, red - 1))
    return np.where(valid, depth, np.nan).astype(np.float32), mask.astype(np.int32)

  def close(self) -> None:
    self.renderer.delete()


def start_baseline(width: int, height: int) -> tuple[PyrenderBaseline | None, dict | None]:
  """(the pyrender baseline, None), or (None, its ``missing`` / ``failed`` entry) without pyrender or its
  offscreen renderer."""
  try:
    return PyrenderBaseline(width, height), None
  except ImportError as e:
    return None, missing(f'{type(e).__name__}: {e}')
  except Exception as e:  # pylint: disable=broad-except  # e.g. no EGL / OSMesa context for pyrender
    return None, {'status': 'failed', 'error': f'{type(e).__name__}: {e}'}


def _agreement(pairs: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]) -> dict:
  """Depth and mask agreement of (depth_a, mask_a, depth_b, mask_b) image pairs."""
  diffs, mask_agree, valid_agree = [], [], []
  for da, ma, db, mb in pairs:
    both = np.isfinite(da) & np.isfinite(db)
    diffs.append(np.abs(da[both] - db[both]))
    mask_agree.append(float(np.mean(ma == mb)))
    valid_agree.append(float(np.mean(np.isfinite(da) == np.isfinite(db))))
  d = np.concatenate(diffs)
  return {'images': len(pairs), 'depth_abs_diff_median_m': float(np.median(d)),
          'depth_abs_diff_p99_m': float(np.percentile(d, 99)), 'depth_abs_diff_max_m': float(np.max(d)),
          'depth_abs_diff_over_1mm_fraction': float(np.mean(d > 1e-3)),
          'mask_agreement_fraction': float(np.mean(mask_agree)),
          'mask_agreement_fraction_min': float(np.min(mask_agree)),
          'valid_pixel_agreement_fraction': float(np.mean(valid_agree))}


def bench_backend(backend: str, gl_platform: str | None, args: argparse.Namespace) -> dict:
  """Throughput of one dexjax backend for heaps of 5 and 10 objects; with GL, pyrender on the same platform."""
  renderer = rendering.DepthRenderer(SIZE, SIZE, backend=backend, gl_platform=gl_platform)
  views = cameras(args.images if backend == 'gl' else args.raycast_images)
  base, base_status = start_baseline(SIZE, SIZE) if backend == 'gl' else (None, None)
  out = {'backend': renderer.backend}
  if base_status is not None:
    out['pyrender'] = base_status
  for count in (5, 10):
    mesh_list, ids, result = settled_heaps(count, args.heaps)
    builds, firsts, rates, objects = [], [], [], []
    b_builds, b_firsts, b_rates, ratios, pairs = [], [], [], [], []
    for heap in range(args.heaps):
      t = time.perf_counter()
      scene = rendering.settled_heap_scene(mesh_list, ids, result, heap)
      builds.append(time.perf_counter() - t)
      t = time.perf_counter()
      renderer.render(scene, views[0])
      firsts.append(time.perf_counter() - t)
      if base is not None:
        t = time.perf_counter()
        base.build(mesh_list, ids[heap], result.poses[heap], result.mask[heap])
        b_builds.append(time.perf_counter() - t)
        t = time.perf_counter()
        base.render(views[0])
        b_firsts.append(time.perf_counter() - t)
        for camera in views:  # correctness of the baseline, untimed
          image = renderer.render(scene, camera)
          pairs.append((*base.render(camera), image.depth, image.mask))
      for _ in range(args.repeats):
        t = time.perf_counter()
        for camera in views:
          image = renderer.render(scene, camera)
        rates.append(len(views) / (time.perf_counter() - t))
        objects.append(float(np.mean(image.mask >= 0)))
        if base is not None:
          t = time.perf_counter()
          for camera in views:
            base.render(camera)
          b_rates.append(len(views) / (time.perf_counter() - t))
          ratios.append(rates[-1] / b_rates[-1])
    faces = sum(len(mesh_list[i].faces) for i in ids[0][result.mask[0]])
    out[f'objects_{count}'] = {'images_per_s': float(np.median(rates)), 'model_build_s': float(np.median(builds)),
                               'first_render_s': float(np.median(firsts)), 'heaps': args.heaps,
                               'images_per_pass': len(views), 'faces_per_heap': int(faces),
                               'object_pixel_fraction': float(np.mean(objects))}
    if base is not None:
      out[f'pyrender_objects_{count}'] = {'images_per_s': float(np.median(b_rates)),
                                          'scene_build_s': float(np.median(b_builds)),
                                          'first_render_s': float(np.median(b_firsts)),
                                          'dexjax_over_pyrender_median_pass_ratio': float(np.median(ratios))}
      out[f'agreement_{count}_objects'] = _agreement(pairs)
  renderer.close()
  if base is not None:
    base.close()
  return out


def _child(gl_platform: str, args: argparse.Namespace) -> dict:
  """Runs ``--worker <platform>`` in a fresh process with PYOPENGL_PLATFORM set; its JSON, or the failure."""
  env = {k: v for k, v in os.environ.items() if k not in ('PYOPENGL_PLATFORM', 'MUJOCO_GL')}
  env['PYOPENGL_PLATFORM'] = gl_platform
  cmd = [sys.executable, os.path.abspath(__file__), '--worker', gl_platform, '--images', str(args.images),
         '--repeats', str(args.repeats), '--heaps', str(args.heaps)]
  run = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False, timeout=3600)
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
  out = {'image_size': [SIZE, SIZE], 'machine': describe(),
         'jax_backend': jax.default_backend(),
         'versions': {k: version(k) for k in ('pyrender', 'PyOpenGL', 'pyglet', 'mujoco', 'trimesh', 'numpy')},
         'baseline': 'pyrender OffscreenRenderer, one RenderFlags.SEG pass per image (depth + segmentation colours '
                     'decoded to the mask), same heaps, meshes, cameras and size, scenes built before timing'}
  backends = {f'gl_{p}': _child(p, args) for p in ('egl', 'osmesa')}
  backends['raycast'] = bench_backend('raycast', None, args)
  without = {p: backends[f'gl_{p}']['pyrender']['error'] for p in ('egl', 'osmesa')
             if 'pyrender' in backends[f'gl_{p}']}
  if without:
    out['baseline_missing'] = without
  for count in (5, 10):
    base_rates = {}
    for p in ('egl', 'osmesa'):
      res = backends[f'gl_{p}'].get(f'pyrender_objects_{count}')
      if res is not None:
        base_rates[p] = res['images_per_s']
      out[f'pyrender_{p}_{count}_objects_images_per_s'] = None if res is None else res['images_per_s']
    out[f'baseline_{count}_objects_images_per_s'] = max(base_rates.values()) if base_rates else None
    for name, res in backends.items():
      if f'objects_{count}' not in res:
        continue
      out[f'{name}_{count}_objects_images_per_s'] = res[f'objects_{count}']['images_per_s']
      ratio = None
      if name.startswith('gl_'):
        if f'pyrender_objects_{count}' in res:
          ratio = res[f'pyrender_objects_{count}']['dexjax_over_pyrender_median_pass_ratio']
      elif base_rates:
        ratio = res[f'objects_{count}']['images_per_s'] / max(base_rates.values())
      out[f'{name}_{count}_objects_over_baseline'] = ratio
    for p in ('egl', 'osmesa'):
      agreement = backends[f'gl_{p}'].get(f'agreement_{count}_objects')
      if agreement is not None:
        out[f'agreement_{p}_{count}_objects'] = agreement
  out['backends'] = backends
  print(json.dumps(out, indent=1))


if __name__ == '__main__':
  main()
