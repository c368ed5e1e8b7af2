"""The physics judge: grasps executed in MuJoCo on known boxes, checked against what must happen and against the
analytic reward; the suction-ring limits and the tool path against known answers."""

from __future__ import annotations

import math

import jax
import numpy as np
import pytest
import trimesh

from dexjax.bench.execution import execute_grasp, ring_violation
from dexjax.bench.picking_metrics import MotionModel, move_seconds
from dexjax.bench.tool_path import PHASES, PathSettings, tool_path, trapezoid_fraction
from dexjax.geometry import build_object_model
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality.heap_reward import REWARD_FAILURES, heap_grasp_reward, heap_scene
from dexjax.sim.bodies import heap_object
from dexjax.sim.heap import Bin, HeapState

P = 2
DOWN = np.array([0.0, 0.0, -1.0])
DIAMOND = [math.cos(math.pi / 8), 0.0, 0.0, math.sin(math.pi / 8)]  # 45 degrees about z


def _box(extents, density):
  mesh = trimesh.creation.box(extents=extents)
  return heap_object(mesh, density=density, name=f'box{extents}'), build_object_model(mesh, grid_size=32)


@pytest.fixture(scope='module')
def boxes():
  """A 20 x 4 x 4 cm bar of 0.32 kg, a 5 cm cube of 62 g and a 10 cm cube of 1.5 kg (over the 0.9 kg payload)."""
  return {'bar': _box((0.2, 0.04, 0.04), 1000.0), 'cube': _box((0.05, 0.05, 0.05), 500.0),
          'heavy': _box((0.1, 0.1, 0.1), 1500.0)}


def _heap(quat=(1.0, 0.0, 0.0, 0.0), height=0.05):
  """One object resting on the bin floor at the origin (slot 0 of P) with friction 0.8."""
  heap = HeapState(object_ids=np.zeros(P, np.int32), mask=np.arange(P) == 0, positions=np.zeros((P, 3), np.float32),
                   quaternions=np.tile([1.0, 0.0, 0.0, 0.0], (P, 1)).astype(np.float32),
                   friction=np.array([0.8, 0.0], np.float32))
  poses = np.tile([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0], (P, 1))
  poses[0, :3], poses[0, 3:] = (0.0, 0.0, 0.5 * height), quat
  return heap, poses


_reward = jax.jit(heap_grasp_reward)


def _analytic(box, grasp, gripper, heap, poses, known_mass=False):
  body, model = box
  mass = np.full(P, body.mass) if known_mass else None
  scene = heap_scene([model], heap.object_ids, heap.mask, poses, heap.friction, mass)
  return jax.device_get(_reward(jax.random.key(0), grasp, scene, Bin(), gripper))


def _both(box, grasp, gripper, quat=(1.0, 0.0, 0.0, 0.0), height=0.05, known_mass=False):
  """(physics outcome, analytic reward record) of one grasp on one resting box."""
  body, model = box
  heap, poses = _heap(quat, height)
  physics = execute_grasp([body], [model], heap, poses, grasp, gripper)
  return physics, _analytic(box, grasp, gripper, heap, poses, known_mass)


def _jaws(x, z, width=0.05):
  return ParallelJawGrasp(center=np.array([x, 0.0, z]), axis=np.array([0.0, 1.0, 0.0]), approach=DOWN,
                          width=np.float32(width))


def test_jaws_lift_a_bar_held_across_its_middle(boxes):
  physics, analytic = _both(boxes['bar'], _jaws(0.0, 0.02), ParallelJawGripper(), height=0.04)
  assert physics.success and physics.reason == 'none' and physics.target_slot == 0
  assert physics.detail['phase'] == 'hold' and physics.detail['lifted'] == [0]
  # Carried 0.2 m up to above the bin's centre (it started there), level between the pads.
  assert physics.poses[0, 2] == pytest.approx(0.02 + MotionModel().lift_height, abs=0.01)
  assert abs(physics.poses[0, 4]) < 0.05 and abs(physics.poses[0, 5]) < 0.05
  assert int(analytic.reward) == 1  # the judges agree


def test_jaws_closing_on_a_corner_squeeze_the_cube_out(boxes):
  # A cube turned 45 degrees: the jaws close on its corner, whose faces meet the closing direction at 45 degrees,
  # outside the friction cone (atan 0.8 = 39 degrees): the cube is pushed out of the jaws, nothing is lifted.
  physics, analytic = _both(boxes['cube'], _jaws(0.02, 0.03), ParallelJawGripper(), quat=DIAMOND)
  assert not physics.success and physics.reason in ('no_object', 'dropped') and physics.detail['lifted'] == []
  assert int(analytic.reward) == 0 and REWARD_FAILURES[int(analytic.failure)] == 'not_robust'


def test_suction_lifts_a_light_cube_from_the_centre_of_its_top(boxes):
  grasp = SuctionGrasp(center=np.array([0.0, 0.0, 0.05]), approach=DOWN)
  physics, analytic = _both(boxes['cube'], grasp, SuctionGripper())
  assert physics.success and physics.detail['sealed'] and physics.detail['max_strain'] < 0.01
  assert physics.poses[0, 2] > 0.025 + 0.15
  assert int(analytic.reward) == 1


def test_suction_fails_on_an_object_heavier_than_its_payload(boxes):
  grasp = SuctionGrasp(center=np.array([0.0, 0.0, 0.1]), approach=DOWN)
  physics, analytic = _both(boxes['heavy'], grasp, SuctionGripper(), height=0.1, known_mass=True)
  assert physics.detail['sealed']  # a flat top seals: the vacuum cannot hold 1.5 kg
  assert not physics.success and physics.reason == 'seal_lost' and physics.detail['limit'] == 'vacuum'
  assert physics.poses[0, 2] < 0.06  # it never left the floor
  assert int(analytic.reward) == 0  # the analytic judge that knows the mass agrees
  # The labels' reward draws the mass (Gamma, mean 0.25 kg) and cannot tell: the disagreement the physics judge
  # exists to expose.
  heap, poses = _heap(height=0.1)
  assert int(_analytic(boxes['heavy'], grasp, SuctionGripper(), heap, poses).reward) == 1


def test_suction_off_the_edge_does_not_seal(boxes):
  grasp = SuctionGrasp(center=np.array([0.0, 0.024, 0.05]), approach=DOWN)  # the lip hangs over the edge
  physics, analytic = _both(boxes['cube'], grasp, SuctionGripper())
  assert physics.reason == 'no_seal' and not physics.detail['sealed'] and int(analytic.reward) == 0


def test_a_grasp_into_the_floor_is_a_bin_collision(boxes):
  physics, analytic = _both(boxes['cube'], _jaws(0.0, 0.005), ParallelJawGripper())  # fingertips 5 mm deep
  assert physics.reason == 'collision_bin' and REWARD_FAILURES[int(analytic.failure)] == 'collision_bin'


def test_ring_limits_known_answers():
  g = SuctionGripper()
  frame = np.eye(3)  # approach along +z
  v, r, mu = float(g.vacuum_force), float(g.cup_radius), 0.5
  wrench = lambda f=(0, 0, 0), t=(0, 0, 0): np.array([*f, *t], np.float64)
  assert ring_violation(wrench(f=(0, 0, -0.99 * v)), frame, mu, g) is None
  assert ring_violation(wrench(f=(0, 0, -1.01 * v)), frame, mu, g) == 'vacuum'
  # Shear: mu times the lip load f_z + V, in any tangent direction (the limit surface, not a box).
  load = v + 2.0
  shear = 0.99 * mu * load / math.sqrt(2.0)
  assert ring_violation(wrench(f=(shear, shear, 2.0)), frame, mu, g) is None
  assert ring_violation(wrench(f=(1.02 * shear, 1.02 * shear, 2.0)), frame, mu, g) == 'friction'
  assert ring_violation(wrench(t=(0, 0, 0.99 * mu * r * v)), frame, mu, g) is None
  assert ring_violation(wrench(t=(0, 0, 1.01 * mu * r * v)), frame, mu, g) == 'torsion'
  bend = math.pi * r * float(g.elastic_limit)
  assert ring_violation(wrench(t=(0.99 * bend, 0, 0)), frame, mu, g) is None
  assert ring_violation(wrench(t=(0, 1.01 * bend, 0)), frame, mu, g) == 'bending'
  # The frame maps world wrenches: the same pull along a tilted approach.
  tilted = np.linalg.qr(np.random.default_rng(0).normal(size=(3, 3)))[0]
  assert ring_violation(np.concatenate([tilted @ [0, 0, -1.01 * v], np.zeros(3)]), tilted, mu, g) == 'vacuum'


@pytest.mark.parametrize('distance', [0.01, 0.05, 0.4])
def test_trapezoid_profile_respects_speed_and_acceleration(distance):
  speed, accel, dt = 1.5, 5.0, 1e-4
  total = move_seconds(distance, speed, accel)
  t = np.arange(0.0, total + 2 * dt, dt)
  s = distance * trapezoid_fraction(t, distance, speed, accel)
  assert s[0] == 0.0 and s[-1] == pytest.approx(distance)
  v = np.diff(s) / dt
  a = np.diff(v) / dt
  assert v.min() >= -1e-9 and v.max() <= speed + 1e-6 and np.abs(a).max() <= accel * 1.01
  assert v.max() == pytest.approx(min(speed, math.sqrt(accel * distance)), rel=1e-3)


def test_tool_path_phases():
  m = MotionModel()
  path = tool_path(np.array([0.0, 0.0, 0.15]), np.array([0.05, 0.0, 0.1]), np.array([0.0, 0.0]), 0.002)
  assert [PHASES[p] for p in dict.fromkeys(path.phase.tolist())] == list(PHASES)
  end = path.phase_end
  np.testing.assert_allclose(path.positions[end('approach')], [0.05, 0.0, 0.1])
  np.testing.assert_allclose(path.positions[end('lift')], [0.05, 0.0, 0.1 + m.lift_height])
  np.testing.assert_allclose(path.positions[end('transport')], [0.0, 0.0, 0.1 + m.lift_height])
  np.testing.assert_allclose(path.positions[-1], [0.0, 0.0, 0.1 + m.lift_height])
  assert path.grip[end('approach')] == 0.0 and path.grip[end('grip')] == 1.0 and np.all(np.diff(path.grip) >= 0)
  shake = path.positions[path.phase == PHASES.index('shake')]
  radius = np.linalg.norm(shake[:, :2], axis=1)
  assert radius.max() == pytest.approx(PathSettings().shake_amplitude, rel=0.02)
  with pytest.raises(ValueError, match='PathSettings.shake_cycles: expected an int >= 0'):
    tool_path(np.zeros(3), np.ones(3), np.zeros(2), 0.002, PathSettings(shake_cycles=-1))
