"""``python -m dexjax.plan``: plan a grasp on a depth image with a Dex-Net 4.0 policy.

  python -m dexjax.plan DEPTH --intrinsics K --out plan.json [--png plan.png] [--model pretrained|RUN|MODEL]
                        [--policy ambidextrous|parallel_jaw|suction|ranking|random|suction_heuristic|
                                  composite_heuristic]
                        [--segmask M | --background EMPTY_BIN | --segment auto|plane|none] [--depth-scale S]
                        [--camera-pose P] [--cem seed|gqcnn] [--num-candidates N] [--seed S]

DEPTH is a ``.npy`` depth image in metres ((H, W) or (H, W, 1)) or a 16-bit PNG (``--depth-scale`` metres per
unit, default 0.001: millimetres). K is an intrinsics file (JSON, ROS CameraInfo JSON/YAML, or a dexjax camera file)
sized like the image. Missing pixels (0, NaN) are inpainted and never hold a grasp. Grasps are centred on object
pixels: ``--segmask`` (a PNG or ``.npy``, non-zero = objects), else pixels closer than an empty-bin image
(``--background``), else pixels above the dominant plane (bin floor or table, ``--segment plane``, the default
``auto``); ``--segment none`` allows every pixel. ``--model`` is ``pretrained`` (the default: the GQ-CNNs shipped with
dexjax, docs/models.md), a training run (``python -m dexjax.train``; its ``<gripper>/best`` models), one gripper's
saved model or a model file; the heuristic policies need none. ``--camera-pose`` (a
dexjax camera JSON with ``rotation`` and ``position``, or a 4 x 4 world-from-camera matrix as JSON or ``.npy``)
adds the grasp's world pose. Compiled plans are kept in ``$DEXJAX_CACHE/jax`` (JAX's persistent compilation
cache): the first plan for an image size and network architecture compiles (tens of seconds), later runs much less.

Writes plan.json: ``{"gripper", "pixel": [column, row], "angle", "depth", "approach_angle", "width", "pose" (4 x
4, camera frame, metres), "probability", "policy", "plan_s", "compile_s", "grippers": {gripper: best candidate},
"observation": {...}}`` (and ``"pose_world"`` with ``--camera-pose``), and with ``--png`` the depth image with the
grasp and the policy's samples per round. When no grasp is found, plan.json has ``"gripper": null`` and a
``"reason"``, and the exit code is 1. Exit code 0 on success, 2 for bad input (docs/errors.md).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

from dexjax.cli import (FAILURE_EXIT, OK_EXIT, add_overwrite_flag, atomic_write, check_distinct, check_output_file,
                        command, is_dexjax_png, owned_json)
from dexjax.policy.presets import IMAGE_POLICIES


def _parser() -> argparse.ArgumentParser:
  p = argparse.ArgumentParser(prog='python -m dexjax.plan', description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument('depth', metavar='DEPTH', help='depth image: .npy (metres) or 16-bit PNG (see --depth-scale)')
  p.add_argument('--intrinsics', required=True, metavar='K', help='intrinsics file (JSON, ROS CameraInfo)')
  p.add_argument('--model', metavar='RUN', default='pretrained',
                 help='GQ-CNNs of the learned policies: pretrained (default: the shipped models), a training run '
                      'directory, a saved model directory or a model file')
  p.add_argument('--policy', choices=IMAGE_POLICIES, default='ambidextrous', help='policy (default ambidextrous)')
  p.add_argument('--out', required=True, metavar='plan.json', help='output JSON')
  p.add_argument('--png', metavar='plan.png', help='also draw the plan and the policy samples')
  p.add_argument('--segmask', metavar='M', help='object mask: PNG or .npy, non-zero = objects')
  p.add_argument('--background', metavar='EMPTY', help='depth image of the empty bin (same format as DEPTH)')
  p.add_argument('--segment', choices=('auto', 'plane', 'background', 'none'), default='auto',
                 help='where grasps may be centred without --segmask (default auto: --background if given, '
                      'else the pixels above the fitted floor plane)')
  p.add_argument('--threshold', type=float, default=0.005,
                 help='height above the floor plane / background that counts as an object, metres (default 0.005)')
  p.add_argument('--depth-scale', type=float, metavar='S', help='metres per unit of a PNG depth (default 0.001)')
  p.add_argument('--camera-pose', metavar='P', help='world-from-camera pose: camera JSON or 4 x 4 (JSON, .npy)')
  p.add_argument('--cem', choices=('seed', 'gqcnn'), default='seed',
                 help="CEM settings: the seed's (m 3, n 250, c 50, k 5) or gqcnn's Dex-Net 4.0 configs")
  p.add_argument('--num-candidates', type=int, default=400,
                 help='candidates per gripper of the ranking, random and heuristic policies (default 400)')
  p.add_argument('--polish', type=int, metavar='STEPS', default=0,
                 help='CEM policies: polish the best grasps with STEPS gradient steps on the GQ-CNN '
                      '(dexjax.policy.polish; default 0: off)')
  p.add_argument('--seed', type=int, default=0, help='random seed (default 0; plans are repeatable)')
  add_overwrite_flag(p)
  return p


def _check_args(args: argparse.Namespace) -> None:
  if args.num_candidates < 1:
    raise ValueError(f'--num-candidates: expected an integer >= 1, got {args.num_candidates}')
  if not (math.isfinite(args.threshold) and args.threshold > 0):
    raise ValueError(f'--threshold: expected a positive number of metres, got {args.threshold}')
  if args.depth_scale is not None and not (math.isfinite(args.depth_scale) and args.depth_scale > 0):
    raise ValueError(f'--depth-scale: expected a positive number of metres per unit, got {args.depth_scale}')
  if args.polish < 0:
    raise ValueError(f'--polish: expected a number of steps >= 0 (0: off), got {args.polish}')
  if args.polish and args.policy not in ('ambidextrous', 'parallel_jaw', 'suction'):
    raise ValueError(f'--polish: only the CEM policies (ambidextrous, parallel_jaw, suction) polish their grasps; '
                     f'got --policy {args.policy}')
  if args.segment == 'background' and not args.background:
    raise ValueError('--segment background: expected --background EMPTY (a depth image of the empty bin)')
  if args.segmask and (args.background or args.segment not in ('auto',)):
    raise ValueError('--segmask: expected no --background / --segment with it (the given mask decides)')
  for option, path in (('DEPTH', args.depth), ('--intrinsics', args.intrinsics), ('--segmask', args.segmask),
                       ('--background', args.background), ('--camera-pose', args.camera_pose),
                       ('--model', None if args.model == 'pretrained' else args.model)):
    if path is not None and not os.path.exists(path):
      raise FileNotFoundError(f"{option}: '{path}': no such file or directory")
  check_distinct(('--out', args.out), ('--png', args.png))
  check_output_file(args.out, option='--out', owned=owned_json('policy', 'gripper'), overwrite=args.overwrite)
  if args.png:
    check_output_file(args.png, option='--png', owned=is_dexjax_png, overwrite=args.overwrite)


def _load_models(spec: str, policy: str) -> dict:
  """GQ-CNNs by gripper: the shipped ones, a training run's (every gripper it holds) or one saved model."""
  from dexjax.models.shipped import load_models  # pylint: disable=g-import-not-at-top
  from dexjax.policy.presets import uses_models  # pylint: disable=g-import-not-at-top
  if not uses_models(policy):
    return {}
  return load_models(spec)  # `make_policy` names the models a learned policy misses


def _camera_pose(path: str):
  """(4, 4) world-from-camera matrix from a camera JSON (rotation, position) or a 4 x 4 matrix (JSON, .npy)."""
  import numpy as np  # pylint: disable=g-import-not-at-top
  from dexjax.config import parse_json  # pylint: disable=g-import-not-at-top
  from dexjax.render.intrinsics_io import load_pose  # pylint: disable=g-import-not-at-top
  if path.endswith('.npy'):
    matrix = np.load(path, allow_pickle=False)
  else:
    try:
      with open(path, encoding='utf-8') as f:
        text = f.read()
    except UnicodeDecodeError as e:
      raise ValueError(f'{path}: not a text file (byte {e.start} is not UTF-8); expected a camera JSON or a 4 x 4 '
                       'matrix') from None
    data = parse_json(text, path, expected='a camera JSON (rotation, position) or a 4 x 4 matrix')
    if isinstance(data, dict):  # a camera file: only its pose is read (its intrinsics, if any, are --intrinsics')
      matrix = np.eye(4)
      matrix[:3, :3], matrix[:3, 3] = load_pose(path)
    else:
      matrix = np.asarray(data, dtype=float)
  matrix = np.asarray(matrix, dtype=float)
  if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
    raise ValueError(f'{path}: expected a 4 x 4 finite world-from-camera matrix, got shape {matrix.shape}')
  rotation = matrix[:3, :3]
  if np.abs(rotation.T @ rotation - np.eye(3)).max() > 1e-4 or abs(np.linalg.det(rotation) - 1) > 1e-4:
    raise ValueError(f'{path}: rotation (upper-left 3 x 3): expected orthonormal with determinant +1')
  return matrix


def _record(action, policy: str) -> dict:
  """The JSON record of one concrete `GraspAction`."""
  import numpy as np  # pylint: disable=g-import-not-at-top
  from dexjax.policy.scorers import GRIPPERS  # pylint: disable=g-import-not-at-top
  probability = float(action.probability)
  return {'gripper': GRIPPERS[int(action.gripper)], 'pixel': [float(v) for v in np.asarray(action.center)],
          'angle': float(action.angle), 'depth': float(action.depth), 'approach_angle': float(action.approach_angle),
          'width': float(action.width), 'pose': np.asarray(action.pose, float).round(6).tolist(),
          'probability': probability if math.isfinite(probability) else None, 'policy': policy}


def _plan_json(action, policy: str, names: list[str]) -> dict:
  """plan.json's grasp fields: the chosen action, or ``gripper`` None with a reason; each gripper's candidate."""
  import jax  # pylint: disable=g-import-not-at-top
  from dexjax.policy.scorers import GRIPPERS  # pylint: disable=g-import-not-at-top
  if bool(action.valid):
    plan = _record(action, policy)
  else:
    plan = {'gripper': None, 'policy': policy,
            'reason': 'no valid grasp candidate on the object pixels (mask too small, too close to the image border '
                      '- grasps stay ceil(sqrt(2) window / 2) pixels inside it - or no antipodal edges / flat '
                      'surfaces within the approach cone)'}
  grippers = {}
  if action.per_gripper is not None:
    for i, name in enumerate(GRIPPERS):
      one = jax.tree.map(lambda x, i=i: x[i], action.per_gripper)
      if name in names:
        grippers[name] = _record(one, policy) if bool(one.valid) else None
  plan['grippers'] = grippers
  return plan


def _samples_numpy(action, names: list[str]) -> dict | None:
  import numpy as np  # pylint: disable=g-import-not-at-top
  if action.samples is None:
    return None
  out = {k: np.asarray(getattr(action.samples, k)) for k in ('center', 'angle', 'depth', 'quality', 'valid')}
  out['grippers'] = names
  return out


@command
def main(argv: list[str] | None = None) -> int:
  args = _parser().parse_args(argv)
  _check_args(args)
  import jax  # pylint: disable=g-import-not-at-top (slow imports after the checks)
  import numpy as np  # pylint: disable=g-import-not-at-top
  from dexjax.policy.composite import plan_grasp  # pylint: disable=g-import-not-at-top
  from dexjax.policy.depth_io import load_depth, load_segmask  # pylint: disable=g-import-not-at-top
  from dexjax.policy.preprocess import prepare_observation  # pylint: disable=g-import-not-at-top
  from dexjax.policy.presets import make_policy  # pylint: disable=g-import-not-at-top
  from dexjax.policy.scorers import GRIPPERS  # pylint: disable=g-import-not-at-top
  from dexjax.render.camera import Camera  # pylint: disable=g-import-not-at-top
  from dexjax.render.intrinsics_io import load_camera_or_intrinsics  # pylint: disable=g-import-not-at-top

  intrinsics, _ = load_camera_or_intrinsics(args.intrinsics)
  camera = Camera(intrinsics, np.eye(3, dtype=np.float32), np.zeros(3, np.float32))
  depth = load_depth(args.depth, args.depth_scale)
  mask = load_segmask(args.segmask, depth.shape[:2]) if args.segmask else None
  background = load_depth(args.background, args.depth_scale) if args.background else None
  world = _camera_pose(args.camera_pose) if args.camera_pose else None
  observation, info = prepare_observation(depth, camera, mask, background=background, segment=args.segment,
                                          threshold=args.threshold)
  models = _load_models(args.model, args.policy)
  from dexjax.policy.polish import PolishParams  # pylint: disable=g-import-not-at-top
  polish = PolishParams(steps=args.polish) if args.polish else None
  policy = make_policy(args.policy, models, cem=args.cem, num_candidates=args.num_candidates, polish=polish)
  names = [g for g in GRIPPERS if g in {p.gripper for p in policy.policies}]  # the order of the samples
  key = jax.random.key(args.seed)
  start = time.perf_counter()
  from dexjax.compile_cache import persistent_compilation_cache  # pylint: disable=g-import-not-at-top
  with persistent_compilation_cache():
    compiled = jax.jit(plan_grasp, static_argnames='samples').lower(key, observation, policy,
                                                                    samples=bool(args.png)).compile()
  compile_s = time.perf_counter() - start
  start = time.perf_counter()
  action = jax.block_until_ready(compiled(key, observation, policy))
  plan_s = time.perf_counter() - start
  plan = _plan_json(action, args.policy, names)
  plan.update(plan_s=round(plan_s, 4), compile_s=round(compile_s, 3), seed=args.seed, polish_steps=args.polish,
              observation=info,
              model=(args.model if args.model == 'pretrained' else os.fspath(Path(args.model).absolute()))
              if models else None)
  if world is not None and plan['gripper'] is not None:
    plan['pose_world'] = (world @ np.asarray(plan['pose'])).round(6).tolist()
  atomic_write(args.out, lambda f: f.write((json.dumps(plan, indent=1) + '\n').encode()))
  if args.png:
    from dexjax.policy.plot import save_plan_png  # pylint: disable=g-import-not-at-top
    save_plan_png(args.png, np.asarray(observation.depth), plan, float(intrinsics.fx),
                  _samples_numpy(action, names), np.asarray(observation.mask))
  print(json.dumps({k: plan[k] for k in ('gripper', 'probability', 'policy', 'plan_s') if k in plan}))
  return OK_EXIT if plan['gripper'] is not None else FAILURE_EXIT


if __name__ == '__main__':
  sys.exit(main())
