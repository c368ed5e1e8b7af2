"""3-D samplers: candidates are what they claim to be, checked with exact geometry in NumPy."""

from __future__ import annotations

import jax
import numpy as np

from dexjax.contacts import close_jaws
from dexjax.grippers import ParallelJawGripper
from dexjax.sampling import sample_antipodal_grasps, sample_suction_grasps

_antipodal = jax.jit(sample_antipodal_grasps, static_argnums=2)
_suction = jax.jit(sample_suction_grasps, static_argnums=2)


def test_antipodal_candidates_on_cube_are_face_to_face_and_within_the_cone(cube):
  grasps, valid = _antipodal(jax.random.key(0), cube, 256)
  assert valid.shape == (256,) and grasps.center.shape == (256, 3)
  valid = np.asarray(valid)
  assert 0.3 < valid.mean() <= 1.0
  contacts = jax.vmap(close_jaws, in_axes=(None, 0, None))(cube, grasps, ParallelJawGripper())
  pts = np.asarray(contacts.points)[valid]
  # Every valid candidate touches two opposite faces of the cube (one coordinate at -2 cm and +2 cm; the
  # interpolated surface rounds the cube's edges by up to a voxel, 0.74 mm at this grid).
  spans = np.abs(pts[:, 1] - pts[:, 0])
  assert np.all(np.max(spans, axis=1) > 0.04 - 0.0007)
  assert np.mean(np.max(spans, axis=1) > 0.0399) > 0.9
  # Nguyen: the contact line is within arctan(0.5) of both inward normals (exact cube normals here).
  line = pts[:, 1] - pts[:, 0]
  line /= np.linalg.norm(line, axis=1, keepdims=True)
  axis_idx = np.argmax(np.abs(line), axis=1)
  cos_to_face = np.abs(line[np.arange(len(line)), axis_idx])
  assert np.all(cos_to_face >= np.cos(np.arctan(0.5)) - 1e-3)
  # Approach is perpendicular to the axis; width is the gripper's opening.
  np.testing.assert_allclose(np.einsum("ij,ij->i", np.asarray(grasps.axis), np.asarray(grasps.approach)), 0, atol=1e-5)
  np.testing.assert_allclose(np.asarray(grasps.width), 0.05)


def test_antipodal_sampler_rejects_objects_wider_than_the_gripper(box):
  # The 8 x 6 x 4 cm box only fits the 5 cm jaws across its 4 cm height.
  grasps, valid = _antipodal(jax.random.key(1), box, 256)
  axes = np.abs(np.asarray(grasps.axis)[np.asarray(valid)])
  assert len(axes) > 0 and np.all(axes[:, 2] > 0.85)


def test_suction_candidates_lie_on_the_surface_with_inward_approach(sphere, box_with_hole):
  grasps, valid = _suction(jax.random.key(2), sphere, 128)
  c = np.asarray(grasps.center)
  np.testing.assert_allclose(np.linalg.norm(c, axis=1), 0.03, atol=6e-4)  # polyhedral sphere of radius 3 cm
  cos = np.einsum("ij,ij->i", -c / np.linalg.norm(c, axis=1, keepdims=True), np.asarray(grasps.approach))
  assert np.all(cos > 0.99)
  assert np.asarray(valid).all()
  # Points on the wall of the hole face a wall across the hole: the approach is blocked and they are invalid.
  grasps, valid = _suction(jax.random.key(3), box_with_hole, 512)
  c, valid = np.asarray(grasps.center), np.asarray(valid)
  in_hole = np.linalg.norm(c[:, :2], axis=1) < 0.0065
  assert in_hole.any() and not valid[in_hole].any()
  assert valid[~in_hole].mean() > 0.95
