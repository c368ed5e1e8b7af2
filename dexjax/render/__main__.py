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
camera. A posed camera must be above the floor and look down at the bin, and a rendered image without a valid
pixel is an error. Outputs are checked before any computing; an existing file is only replaced if this command
wrote it, or with ``--overwrite``. Exit code 0 on success, 2 for bad input (docs/errors.md).
"""

from __future__ import annotations

import argparse
import json
import sys

import jax
import numpy as np

from dexjax.cli import (add_overwrite_flag, atomic_write, check_distinct, check_output_file, command,
                        is_dexjax_png, owned_npz)
from dexjax.objects.sets import load_object_set, prepare_object_set
from dexjax.render import gl
from dexjax.render.camera import Camera
from dexjax.render.distribution import sample_camera
from dexjax.render.intrinsics_io import check_camera_view, load_camera_or_intrinsics
from dexjax.render.noise import SensorNoise, apply_sensor_noise
from dexjax.render.rendering import DepthImage, DepthRenderer, RenderSettings, settled_heap_scene
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
  add_overwrite_flag(h)
  sub.add_parser('backends', help='which headless GL platforms work here, and why not')
  return p


#: Arrays of a ``--npz`` file: an existing file with all of them is this command's own output.
NPZ_ARRAYS = ('depth', 'mask', 'object_names', 'intrinsics', 'rotation', 'position')


def _camera(path: str | None, sampled: Camera) -> Camera:
  """The camera of ``path`` (with pose; checked to see the bin), or the sampled pose with the file's intrinsics,
  or ``sampled``."""
  if path is None:
    return sampled
  intrinsics, camera = load_camera_or_intrinsics(path)
  if camera is not None:
    return check_camera_view(path, camera, far=RenderSettings().far)
  return sampled.replace(intrinsics=intrinsics)


def _check_image(image: DepthImage, camera_source: str) -> None:
  """Raises ValueError (naming the camera) when no pixel saw a surface; warns when no object is in view."""
  if not np.isfinite(image.depth).any():
    raise ValueError(f'{camera_source}: position, rotation: no pixel of the rendered image sees a surface within '
                     'the depth range (all depth invalid); expected a camera above the bin looking at it')
  if not (image.mask >= 0).any():
    print(f'warning: {camera_source}: no object is in view (only the bin)', file=sys.stderr)


def _heap(args: argparse.Namespace) -> int:
  check_distinct(('OUT.png', args.out), ('--npz', args.npz))
  out = check_output_file(args.out, option='OUT.png', owned=is_dexjax_png, overwrite=args.overwrite)
  npz = args.npz and check_output_file(args.npz, option='--npz', owned=owned_npz(*NPZ_ARRAYS),
                                       overwrite=args.overwrite)
  key_heap, key_camera, key_noise = jax.random.split(jax.random.key(args.seed), 3)
  camera = _camera(args.camera, sample_camera(key_camera))
  prepared, rejected = prepare_object_set(load_object_set(args.objects), model=False)
  for r in rejected:
    print(f'rejected {r}', file=sys.stderr)
  if not prepared:
    raise ValueError(f'--objects: no object of {" ".join(args.objects)} could be used (see the rejections above)')
  states = sample_heap_states(key_heap, 1, len(prepared))
  result = settle(heap_objects(prepared), states, backend='rollout')
  scene = settled_heap_scene([p.mesh for p in prepared], states.object_ids, result, 0)
  k = camera.intrinsics
  with DepthRenderer(k.width, k.height, backend=args.backend) as renderer:
    image = renderer.render(scene, camera)
  _check_image(image, args.camera or 'the sampled camera')
  if args.noise:
    image = DepthImage(depth=np.asarray(apply_sensor_noise(key_noise, image.depth, _ALL_NOISE)), mask=image.mask,
                       backend=image.backend)
  from dexjax.render.preview import save_depth_png  # pylint: disable=g-import-not-at-top
  names = [prepared[int(i)].name for i in np.asarray(states.object_ids[0]) if i >= 0]
  save_depth_png(out, image, title=f'seed {args.seed}: {len(names)} objects, {k.width} x {k.height}, '
                                   f'f = {float(k.fx):.0f} px')
  if npz:
    arrays = dict(depth=image.depth, mask=image.mask, object_names=np.array(names),
                  intrinsics=np.array([float(k.fx), float(k.fy), float(k.cx), float(k.cy)]),
                  rotation=np.asarray(camera.rotation), position=np.asarray(camera.position))
    atomic_write(npz, lambda f: np.savez_compressed(f, **arrays))
  valid = np.isfinite(image.depth)
  print(f'{len(names)} objects ({", ".join(names)}); {image.backend}; depth {np.nanmin(image.depth):.3f}-'
        f'{np.nanmax(image.depth):.3f} m, {valid.mean():.1%} valid, {(image.mask >= 0).mean():.1%} object pixels; '
        f'wrote {args.out}' + (f' and {args.npz}' if args.npz else ''))
  return 0


@command
def main(argv: list[str] | None = None) -> int:
  args = _parser().parse_args(argv)
  if args.command == 'backends':
    print(json.dumps({'available': list(gl.available_platforms()), 'unavailable': gl.unavailable_reasons()}))
    return 0
  return _heap(args)


if __name__ == '__main__':
  sys.exit(main())
