"""The benchmark's analytic judge: a planned image action taken to the world and scored on the true heap."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dexjax.bench.analytic_judge import analytic_verdict, world_grasp
from dexjax.generate.labels import LabelParams
from dexjax.policy import action_from_grasp, observation
from dexjax.quality.heap_reward import REWARD_FAILURES, HeapScene, parallel_jaw_collisions, stack_models
from dexjax.render.camera import Intrinsics, project
from dexjax.render.distribution import camera_from_spherical
from dexjax.sampling.image_grasps import ImageParallelJawGrasp, ImageSuctionGrasp

P = 4
KEY = jax.random.key(3)


@pytest.fixture(scope='module')
def cube_scene(tmp_path_factory):
  """A 4 cm cube resting at (0.05, -0.03) on the bin floor, seen from 0.6 m at 30 degrees off vertical."""
  from dexjax.objects import load_object_model
  model = load_object_model('builtin:cube', cache_dir=tmp_path_factory.mktemp('judge_cache'), grid_size=32)
  ids, mask = np.zeros(P, np.int32), np.arange(P) == 0
  poses = np.tile(np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0], np.float32), (P, 1))
  poses[0, :3] = (0.05, -0.03, 0.02)
  scene = HeapScene(models=stack_models([model]), object_ids=jnp.asarray(ids), mask=jnp.asarray(mask),
                    poses=jnp.asarray(poses), friction=jnp.where(jnp.asarray(mask), 0.8, 0.0).astype(jnp.float32))
  camera = camera_from_spherical(jnp.zeros(3), 0.6, 0.4, 0.5, Intrinsics(fx=520.0, fy=520.0, cx=200.0, cy=150.0,
                                                                         width=400, height=300))
  return scene, camera


def _pixel_and_depth(camera, point):
  uv, z = project(camera, jnp.asarray(point, jnp.float32)[None])
  return uv[0], z[0]


def test_world_grasp_inverts_the_camera_projection(cube_scene):
  _, camera = cube_scene
  obs = observation(jnp.full((300, 400), 0.6), camera)
  uv, z = _pixel_and_depth(camera, (0.05, -0.03, 0.04))
  action = action_from_grasp(obs, ImageSuctionGrasp(center=uv, angle=jnp.float32(0.3), depth=z,
                                                    approach_angle=jnp.float32(0.2)), jnp.float32(0.9), True)
  grasp = world_grasp(action, camera)
  np.testing.assert_allclose(np.asarray(grasp.center), (0.05, -0.03, 0.04), atol=1e-5)
  # The suction approach makes psi = 0.2 rad with the optical axis (world frame).
  optical = np.asarray(camera.rotation)[:, 2]
  assert np.degrees(np.arccos(np.dot(np.asarray(grasp.approach), optical))) == pytest.approx(np.degrees(0.2), abs=1e-3)


def test_jaws_across_the_cube_succeed_and_a_grasp_beside_it_finds_no_object(cube_scene):
  scene, tilted = cube_scene
  # The parallel jaw approaches along the optical axis: a camera straight above. From the tilted camera the jaw
  # axis dips 26 degrees: the lower fingertip goes into the floor and the tilted pads cut the cube's edges (the
  # reward names the object first).
  camera = camera_from_spherical(jnp.zeros(3), 0.6, 0.4, 0.0, tilted.intrinsics)
  obs = observation(jnp.full((300, 400), 0.6), camera)
  centre = np.array([0.05, -0.03, 0.02])
  uv, z = _pixel_and_depth(camera, centre)
  # Jaw axis along the cube's x face normal as seen in the image: project the world x direction.
  tip, _ = _pixel_and_depth(camera, centre + np.array([0.01, 0.0, 0.0]))
  angle = jnp.arctan2(tip[1] - uv[1], tip[0] - uv[0])
  across = action_from_grasp(obs, ImageParallelJawGrasp(center=uv, angle=angle, depth=z, width=jnp.float32(0.05)),
                             jnp.float32(0.9), True)
  record = analytic_verdict(KEY, across, camera, scene)
  assert REWARD_FAILURES[int(record.failure)] == 'none' and int(record.reward) == 1 and int(record.target_slot) == 0
  tilted_action = action_from_grasp(observation(obs.depth, tilted), ImageParallelJawGrasp(
      center=_pixel_and_depth(tilted, centre)[0], angle=angle, depth=_pixel_and_depth(tilted, centre)[1],
      width=jnp.float32(0.05)), jnp.float32(0.9), True)
  assert REWARD_FAILURES[int(analytic_verdict(KEY, tilted_action, tilted, scene).failure)] == 'collision_object'
  params = LabelParams()
  hits = parallel_jaw_collisions(world_grasp(tilted_action, tilted), scene, params.bin, params.parallel_jaw,
                                 params.reward)
  assert [bool(hit) for hit in hits] == [True, True]
  assert [bool(hit) for hit in parallel_jaw_collisions(world_grasp(across, camera), scene, params.bin,
                                                       params.parallel_jaw, params.reward)] == [False, False]
  far_uv, far_z = _pixel_and_depth(camera, (-0.12, 0.1, 0.0))
  beside = action_from_grasp(obs, ImageParallelJawGrasp(center=far_uv, angle=angle, depth=far_z + 0.01,
                                                        width=jnp.float32(0.05)), jnp.float32(0.9), True)
  record = analytic_verdict(KEY, beside, camera, scene)
  assert int(record.reward) == 0 and int(record.target_slot) == -1


def test_suction_on_the_top_face_succeeds_and_on_the_floor_fails(cube_scene):
  scene, camera = cube_scene
  obs = observation(jnp.full((300, 400), 0.6), camera)
  optical = np.asarray(camera.rotation)[:, 2]
  psi = float(np.arccos(np.dot(-np.array([0.0, 0.0, 1.0]), optical)))  # approach straight down
  down_cam = np.asarray(camera.rotation).T @ np.array([0.0, 0.0, -1.0])
  angle = float(np.arctan2(-down_cam[0], down_cam[1]))  # crop angle of r = a x z_hat = (a_y, -a_x)
  uv, z = _pixel_and_depth(camera, (0.05, -0.03, 0.04))
  top = action_from_grasp(obs, ImageSuctionGrasp(center=uv, angle=jnp.float32(angle), depth=z,
                                                 approach_angle=jnp.float32(psi)), jnp.float32(0.9), True)
  np.testing.assert_allclose(np.asarray(world_grasp(top, camera).approach), (0.0, 0.0, -1.0), atol=1e-4)
  record = analytic_verdict(KEY, top, camera, scene)
  assert int(record.reward) == 1 and int(record.target_slot) == 0
  uv, z = _pixel_and_depth(camera, (-0.1, 0.1, 0.0))
  floor = action_from_grasp(obs, ImageSuctionGrasp(center=uv, angle=jnp.float32(angle), depth=z,
                                                   approach_angle=jnp.float32(psi)), jnp.float32(0.9), True)
  record = analytic_verdict(KEY, floor, camera, scene)
  assert int(record.reward) == 0 and REWARD_FAILURES[int(record.failure)] in ('no_object', 'collision_bin')
