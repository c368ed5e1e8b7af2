"""Neighbours' loads at rest (`dexjax.sim.resting_loads`) on a settled hand-built heap, against statics.

A 0.4 kg brick lies on a 0.03 kg plate, off its centre; a third object stands alone. At rest the plate carries the
brick's weight, with the torque of its lever about the plate's centre of mass; the brick and the lone object carry
nothing (the plate holds the brick up: a support, which a lift removes, is not a load).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import dexjax.sim as sim
from dexjax.sim.contact_loads import resting_loads

G = 9.81


def _box(name, extents, mass):
  mesh = trimesh.creation.box(extents=extents)
  return sim.heap_object(mesh, density=mass / float(np.prod(extents)), name=name)


@pytest.fixture(scope='module')
def settled():
  objects = [_box('plate', (0.10, 0.10, 0.02), 0.03), _box('brick', (0.06, 0.06, 0.04), 0.40),
             _box('lone', (0.04, 0.04, 0.04), 0.10)]
  p = sim.MAX_OBJECTS
  ids, mask = np.zeros(p, np.int32), np.zeros(p, bool)
  ids[:3], mask[:3] = (0, 1, 2), True
  poses = np.tile(np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]), (p, 1))
  poses[0, :3], poses[1, :3], poses[2, :3] = (0.0, 0.0, 0.0102), (0.02, 0.0, 0.0405), (0.12, 0.0, 0.0202)
  state = sim.HeapState(object_ids=ids, mask=mask, positions=poses[:, :3].astype(np.float32),
                        quaternions=poses[:, 3:].astype(np.float32), friction=np.where(mask, 0.8, 0.0).astype(np.float32))
  result = sim.settle(objects, state, backend='rollout', start_poses=poses)
  assert bool(result.settled[0]) and not result.left_bin[0].any()
  return objects, state, np.asarray(result.poses[0], np.float64), np.asarray(result.centers[0])


def test_plate_carries_the_brick_with_its_lever(settled):
  objects, state, poses, centers = settled
  loads = resting_loads(objects, state, poses)
  assert loads.shape == (sim.MAX_OBJECTS, 6) and loads.dtype == np.float32
  weight = objects[1].mass * G
  np.testing.assert_allclose(loads[0, :3], [0.0, 0.0, -weight], atol=0.03 * weight)
  # The brick's weight acts at its centre of mass's x, y (its centre of pressure at rest): tau = r x F.
  lever = centers[1] - centers[0]
  assert lever[0] > 0.015
  expected = np.cross(lever, [0.0, 0.0, -weight])
  np.testing.assert_allclose(loads[0, 3:5], expected[:2], atol=0.1 * abs(expected[1]))
  # The plate holds the brick up (a support) and nothing touches the lone cube; empty slots stay zero.
  np.testing.assert_array_equal(loads[1:], 0.0)


def test_no_objects_means_no_loads(settled):
  objects, state, poses, _ = settled
  empty = state.replace(mask=np.zeros_like(state.mask))
  np.testing.assert_array_equal(resting_loads(objects, empty, poses), 0.0)
