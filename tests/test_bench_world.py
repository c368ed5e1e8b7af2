"""The benchmark's simulated bin: filled and settled, seen by a camera, an object taken out, the rest settling."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

from dexjax.bench.world import BinState, PickingWorld
from dexjax.generate.config import config_from_dict
from dexjax.render.camera import Intrinsics
from dexjax.render.distribution import camera_from_spherical
from dexjax.render.rendering import BIN_LABEL

SOURCES = ['builtin:cube', 'builtin:box', 'builtin:cylinder', 'builtin:l_shape', 'procedural:L1/0:2']
CAMERA = camera_from_spherical(np.zeros(3), 0.7, 4.71, 0.05, Intrinsics(fx=300.0, fy=300.0, cx=80.0, cy=80.0,
                                                                        width=160, height=160))


@pytest.fixture(scope='module')
def world(tmp_path_factory):
  config = config_from_dict({'objects': {'sources': SOURCES, 'grid_size': 32},
                                      'camera': {'width': 160, 'height': 160}}, 'test')
  with PickingWorld(config, cache_dir=tmp_path_factory.mktemp('world_cache')) as w:
    yield w


@pytest.fixture(scope='module')
def full(world):
  return world.fill(jax.random.key(0), 6)


def test_fill_puts_every_object_at_rest_in_the_bin(world, full):
  assert full.count == 6 and sorted(full.object_ids.tolist()) == list(range(6))  # all six, each once
  assert np.all(np.abs(full.poses[:, :2]) < 0.2) and np.all(full.poses[:, 2] > 0.0)
  again = world.settle_again(full)  # already at rest: settling again moves nothing noticeably
  np.testing.assert_allclose(again.poses[:, :3], full.poses[:, :3], atol=3e-3)
  with pytest.raises(ValueError, match=r'expected an integer in \[1, 6\]'):
    world.fill(jax.random.key(0), 7)


def test_the_camera_sees_the_objects_and_the_empty_bin_is_the_background(world, full):
  depth, seg = world.observe(jax.random.key(1), full, CAMERA)
  assert depth.shape == seg.shape == (160, 160)
  seen = set(np.unique(seg).tolist()) - {BIN_LABEL, -2}
  assert seen and seen <= set(range(6))
  background = world.empty_bin(CAMERA)
  on_bin = seg == BIN_LABEL
  # Noise is off by default in a generation config: the bin's pixels match the empty-bin image exactly, object
  # pixels are nearer the camera (all but a few at the objects' feet, where they touch the floor).
  np.testing.assert_allclose(depth[on_bin], background[on_bin], atol=1e-5)
  objects = seg >= 0
  assert np.all(depth[objects] <= background[objects] + 1e-5)
  assert np.mean(depth[objects] < background[objects] - 1e-3) > 0.95


def test_remove_takes_one_object_out_and_the_state_round_trips_through_json(world, full):
  slot = int(np.flatnonzero(full.mask)[0])
  after = world.remove(full, slot)
  assert after.count == 5 and not after.mask[slot] and after.object_ids[slot] == -1
  _, seg = world.observe(jax.random.key(1), after, CAMERA)
  assert slot not in set(np.unique(seg).tolist())
  restored = BinState.from_json(json.loads(json.dumps(after.to_json())))
  for field in ('object_ids', 'mask', 'poses', 'friction'):
    np.testing.assert_array_equal(getattr(restored, field), getattr(after, field))
  with pytest.raises(ValueError, match=f'slot {slot} holds no object'):
    world.remove(after, slot)


def test_scene_stacks_each_slots_model_with_its_pose_and_friction(world, full):
  after = world.remove(full, int(np.flatnonzero(full.mask)[-1]))
  scene = world.scene(after)
  assert np.array_equal(np.asarray(scene.mask), after.mask)
  for slot in np.flatnonzero(after.mask):
    np.testing.assert_array_equal(np.asarray(scene.models.sdf[slot]), np.asarray(world.models[after.object_ids[slot]].sdf))
  np.testing.assert_allclose(np.asarray(scene.poses), after.poses, atol=1e-6)
  assert np.all(np.asarray(scene.friction)[~after.mask] == 0.0)
