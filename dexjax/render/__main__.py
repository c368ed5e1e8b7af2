"""``python -m dexjax.render``: render a settled heap's depth image and mask for a seed; list GL backends.

  python -m dexjax.render heap OUT.png [--seed S] [--objects SOURCE ...] [--camera FILE] [--backend B]
                                       [--noise] [--npz OUT.npz]
  python -m dexjax.render backends

``heap`` draws one heap from the Dex-Net 4.0 state distribution over the objects (default: the first 12
level-2 procedural objects; any sources of `dexjax.objects.load_object_set`), settles it with the MuJoCo C
engine, samples a camera from the seed's distribution and writes the depth image beside its mask. ``--camera``
takes a camera file (intrinsics and pose, `dexjax.render.save_camera`) or an intrinsics-only file (JSON, or a
ROS CameraInfo as JSON/YAML), whose intrinsics then replace the sampled ones. ``--noise`` adds the optional
sensor noise (Gamma, correlated Gaussian process and 1 % dropout). ``--npz`` also saves depth, mask and
camera. Exit code 0 on success, 1 when the image could not be written, 2 for bad input.
"""

from __future__ import annotations

import argparse
import json
import sys

import jax
import numpy as np

from dexjax.objects.sets import load_object_set, prepare_object_set
from dexjax.render import gl
from dexjax.render.camera import Camera
from dexjax.render.distribution import sample_camera
from dexjax.render.intrinsics_io import load_camera_or_intrinsics
from dexjax.render.noise import SensorNoise, apply_sensor_noise
from dexjax.render.rendering import DepthImage, DepthRenderer, settled_heap_scene
from dexjax.sim.bodies import heap_objects
from dexjax.sim.heap import sample_heap_states
from dexjax.sim.settling import settle

_DEFAULT_OBJECTS = ['procedural:L2/0:12']
_ALL_NOISE = SensorNoise(use_gamma=True, use_gp=True, use_dropout=True)


def _parser() -> argparse.ArgumentParser:
  p = argparse.ArgumentParser(prog='python -m dexjax.render', description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
  sub = p.add_subparsers(dest='command', metavar='{heap,backends}', required=True)
  h = sub.add_parser('heap', help="render a settled heap's depth image and mask")
  h.add_argument('out', metavar='OUT.png', help='output PNG (depth beside mask)')
  h.add_argument('--seed', type=int, default=0, help='seed of the heap and the camera (default 0)')
  h.add_argument('--objects', nargs='+', default=_DEFAULT_OBJECTS, metavar='SOURCE',
                 help='object sources (default procedural:L2/0:12)')
  h.add_argument('--camera', metavar='FILE', help='camera or intrinsics file (JSON, or ROS CameraInfo JSON/YAML)')
  h.add_argument('--backend', choices=('auto', 'gl', 'raycast'), default='auto', help='renderer (default auto)')
  h.add_argument('--noise', action='store_true', help='add Gamma, correlated and dropout sensor noise')
  h.add_argument('--npz', metavar='OUT.npz', help='also save depth, mask and camera')
  sub.add_parser('backends', help='which headless GL platforms work here, and why not')
  return p


def _camera(path: str | None, sampled: Camera) -> Camera:
  """The camera of ``path`` (with pose), or the sampled pose with the file's intrinsics, or ``sampled``."""
  if path is None:
    return sampled
  intrinsics, camera = load_camera_or_intrinsics(path)
  return camera if camera is not None else sampled.replace(intrinsics=intrinsics)


def _heap(args: argparse.Namespace) -> int:
  try:
    prepared, rejected = prepare_object_set(load_object_set(args.objects), model=False)
    for r in rejected:
      print(f'rejected {r}', file=sys.stderr)
    key_heap, key_camera, key_noise = jax.random.split(jax.random.key(args.seed), 3)
    states = sample_heap_states(key_heap, 1, len(prepared))
    camera = _camera(args.camera, sample_camera(key_camera))
  except (OSError, ValueError) as e:
    print(f'error: {e}', file=sys.stderr)
    return 2
  result = settle(heap_objects(prepared), states, backend='rollout')
  scene = settled_heap_scene([p.mesh for p in prepared], states.object_ids, result, 0)
  k = camera.intrinsics
  with DepthRenderer(k.width, k.height, backend=args.backend) as renderer:
    image = renderer.render(scene, camera)
  if args.noise:
    image = DepthImage(depth=np.asarray(apply_sensor_noise(key_noise, image.depth, _ALL_NOISE)), mask=image.mask,
                       backend=image.backend)
  from dexjax.render.preview import save_depth_png  # pylint: disable=g-import-not-at-top
  names = [prepared[int(i)].name for i in np.asarray(states.object_ids[0]) if i >= 0]
  try:
    save_depth_png(args.out, image, title=f'seed {args.seed}: {len(names)} objects, {k.width} x {k.height}, '
                                          f'f = {float(k.fx):.0f} px')
    if args.npz:
      np.savez_compressed(args.npz, depth=image.depth, mask=image.mask, object_names=np.array(names),
                          intrinsics=np.array([float(k.fx), float(k.fy), float(k.cx), float(k.cy)]),
                          rotation=np.asarray(camera.rotation), position=np.asarray(camera.position))
  except OSError as e:
    print(f'error: cannot write {e.filename}: {e.strerror}', file=sys.stderr)
    return 1
  valid = np.isfinite(image.depth)
  print(f'{len(names)} objects ({", ".join(names)}); {image.backend}; depth {np.nanmin(image.depth):.3f}-'
        f'{np.nanmax(image.depth):.3f} m, {valid.mean():.1%} valid, {(image.mask >= 0).mean():.1%} object pixels; '
        f'wrote {args.out}' + (f' and {args.npz}' if args.npz else ''))
  return 0


def main(argv: list[str] | None = None) -> int:
  args = _parser().parse_args(argv)
  if args.command == 'backends':
    print(json.dumps({'available': list(gl.available_platforms()), 'unavailable': gl.unavailable_reasons()}))
    return 0
  return _heap(args)


if __name__ == '__main__':
  sys.exit(main())
