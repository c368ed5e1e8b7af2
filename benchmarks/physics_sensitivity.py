"""How the physics judge's verdicts depend on its estimated constants, one JSON object on stdout.

  python benchmarks/physics_sensitivity.py [--masses 0.1 0.3 0.6]

Every constant of the physics judge has a source (docs/benchmark.md, "Where every number comes from"); five are
estimates, not measurements: the bellows' bending stiffness open and sealed, its damping ratio and its angle range,
and (derived from the seed's payload rather than measured on its robot) the tool acceleration. This runs a fixed set
of grasps on objects lying alone in the bin (the canonical cases of tests/test_physics_judge.py and a few that sit
near the limits: suction 2 cm and 5 cm off the centre of mass, a tall can held at its top, jaws at a bar's end)
under the default judge and under each estimate scaled or swapped for an extreme (a sealed bellows contracted
onto its folds, 4 and 14 times stiffer than the open one; the YuMi's maximum acceleration of 11 m/s²), and
reports which grasps succeed in each variant, the outcome counts, and the agreement of each variant with the
default: how much the verdicts rest on the guesses.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import time

import numpy as np
import trimesh

from dexjax.bench import PhysicsSettings, execute_grasp
from dexjax.bench.gripper_bodies import ToolSettings
from dexjax.geometry import build_object_model
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.sim.bodies import heap_object
from dexjax.sim.heap import HeapState

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from _machine import describe  # noqa: E402

DOWN = np.array([0.0, 0.0, -1.0])
LYING = (math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0)
UPRIGHT = (1.0, 0.0, 0.0, 0.0)


def _shapes() -> dict:
  lying = trimesh.creation.cylinder(radius=0.035, height=0.12, sections=48)
  return {'box 10x8x6': (trimesh.creation.box(extents=(0.1, 0.08, 0.06)), 0.06, UPRIGHT),
          'flat box 14x8x4': (trimesh.creation.box(extents=(0.14, 0.08, 0.04)), 0.04, UPRIGHT),
          'can lying d7': (lying, 0.07, LYING), 'can upright d7 h12': (lying, 0.12, UPRIGHT),
          'bar 20x4x4': (trimesh.creation.box(extents=(0.2, 0.04, 0.04)), 0.04, UPRIGHT)}


def _cases(masses):
  jaws = lambda x, z: ParallelJawGrasp(center=np.array([x, 0.0, z]), axis=np.array([0.0, 1.0, 0.0]), approach=DOWN,
                                       width=np.float32(0.05))
  cup = lambda x, z: SuctionGrasp(center=np.array([x, 0.0, z]), approach=DOWN)
  out = []
  for mass in masses:
    out += [(f'suction box top centre {mass} kg', 'box 10x8x6', mass, cup(0.0, 0.06)),
            (f'suction lying can top {mass} kg', 'can lying d7', mass, cup(0.0, 0.07)),
            (f'suction upright can top {mass} kg', 'can upright d7 h12', mass, cup(0.0, 0.12)),
            (f'suction flat box 2 cm off {mass} kg', 'flat box 14x8x4', mass, cup(0.02, 0.04)),
            (f'suction flat box 5 cm off {mass} kg', 'flat box 14x8x4', mass, cup(0.05, 0.04)),
            (f'jaws bar middle {mass} kg', 'bar 20x4x4', mass, jaws(0.0, 0.02)),
            (f'jaws bar 8 cm off {mass} kg', 'bar 20x4x4', mass, jaws(0.08, 0.02))]
  return out


def _variants() -> dict:
  base = PhysicsSettings()
  tool, motion = base.tool, base.path.motion
  with_tool = lambda **kw: dataclasses.replace(base, tool=dataclasses.replace(tool, **kw))
  with_acc = lambda a: dataclasses.replace(base, path=dataclasses.replace(
      base.path, motion=dataclasses.replace(motion, acceleration=a)))
  return {'default': base,
          'stiffness x0.5': with_tool(bellows_stiffness=0.5 * tool.bellows_stiffness,
                                      sealed_stiffness=0.5 * tool.sealed_stiffness),
          'stiffness x2': with_tool(bellows_stiffness=2.0 * tool.bellows_stiffness,
                                    sealed_stiffness=2.0 * tool.sealed_stiffness),
          'sealed stiffness 0.2 (partly contracted)': with_tool(sealed_stiffness=0.2),
          'sealed stiffness 0.7 (folds stacked: a solid tube)': with_tool(sealed_stiffness=0.7),
          'damping ratio 0.1': with_tool(bellows_damping_ratio=0.1),
          'damping ratio 0.7': with_tool(bellows_damping_ratio=0.7),
          'angle range 0.3 rad': with_tool(bellows_max_angle=0.3),
          'acceleration x2': with_acc(2.0 * motion.acceleration),
          'acceleration 11 m/s2 (YuMi maximum)': with_acc(11.0)}


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
  p.add_argument('--masses', type=float, nargs='+', default=[0.1, 0.3, 0.6])
  args = p.parse_args()
  shapes = _shapes()
  models = {name: build_object_model(mesh, grid_size=48) for name, (mesh, _, _) in shapes.items()}
  heap = HeapState(object_ids=np.zeros(2, np.int32), mask=np.array([True, False]),
                   positions=np.zeros((2, 3), np.float32),
                   quaternions=np.tile([1.0, 0, 0, 0], (2, 1)).astype(np.float32),
                   friction=np.array([0.8, 0.0], np.float32))
  results, seconds = {}, {}
  cases = _cases(args.masses)
  for name, settings in _variants().items():
    start = time.perf_counter()
    outcomes = {}
    for label, shape, mass, grasp in cases:
      mesh, height, quat = shapes[shape]
      body = heap_object(mesh, density=mass / mesh.volume, name=shape)
      poses = np.tile([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0], (2, 1))
      poses[0, 2], poses[0, 3:] = 0.5 * height, quat
      gripper = SuctionGripper() if isinstance(grasp, SuctionGrasp) else ParallelJawGripper()
      out = execute_grasp([body], [models[shape]], heap, poses, grasp, gripper, settings)
      outcomes[label] = out.reason + (f"/{out.detail['limit']}" if 'limit' in out.detail else '')
    results[name] = outcomes
    seconds[name] = round(time.perf_counter() - start, 2)
  default = results['default']
  agree = {name: sum((v == 'none') == (default[k] == 'none') for k, v in r.items()) / len(r)
           for name, r in results.items()}
  summary = {name: {'successes': sum(v == 'none' for v in r.values()), 'agreement_with_default': agree[name],
                    'seconds': seconds[name]} for name, r in results.items()}
  print(json.dumps({'machine': describe(), 'cases': len(cases), 'summary': summary, 'outcomes': results}, indent=1))


if __name__ == '__main__':
  main()
