"""Grid queries against exact geometry: box distance, ray/sphere and line/box intersections."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from dexjax.geometry.sdf import first_crossing, ray_cast, sdf_value, surface_normal
from dexjax.objects import builtin_mesh

HALF = 0.02  # the built-in cube is 4 cm


def _box_sdf(p, half):
  q = np.abs(p) - half
  return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(np.max(q, axis=-1), 0.0)


_values = jax.jit(jax.vmap(sdf_value, in_axes=(None, 0)))
_normals = jax.jit(jax.vmap(surface_normal, in_axes=(None, 0)))


def test_sdf_matches_exact_box_distance_near_faces(cube):
  rng = np.random.default_rng(0)
  # Within 4 mm inside and 10 mm outside one face, at least 1 cm from the others (the distance is linear
  # there, so trilinear interpolation of exact voxel values must reproduce it).
  p = rng.uniform(-0.01, 0.01, (500, 3))
  axis = rng.integers(0, 3, 500)
  p[np.arange(500), axis] = rng.choice([-1, 1], 500) * rng.uniform(0.016, 0.03, 500)
  got = np.asarray(_values(cube, jnp.asarray(p, jnp.float32)))
  np.testing.assert_allclose(got, _box_sdf(p, HALF), atol=2e-5)


def test_sdf_outside_grid_continues_as_a_tight_upper_bound(cube):
  p = np.array([[0.5, 0.0, 0.0], [0.3, -0.4, 0.2], [0.0, 0.03, 0.0]])
  got = np.asarray(_values(cube, jnp.asarray(p, jnp.float32)))
  exact = _box_sdf(p, HALF)
  assert np.all(got >= exact - 1e-5) and np.all(got <= 1.01 * exact)
  np.testing.assert_allclose(got[[0, 2]], exact[[0, 2]], atol=1e-5)  # exact straight out from a face


def test_normals_on_cube_faces_are_outward_axes(cube):
  pts = jnp.array([[HALF, 0.003, -0.004], [-HALF, 0.0, 0.01], [0.0, HALF, 0.0], [0.005, 0.0, -HALF]])
  expect = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, 0, -1]], np.float32)
  np.testing.assert_allclose(np.asarray(_normals(cube, pts)), expect, atol=1e-3)


def test_first_crossing_finds_cube_face_to_sub_voxel_accuracy(cube):
  rng = np.random.default_rng(1)
  for _ in range(20):
    y, z = rng.uniform(-0.015, 0.015, 2)
    start = jnp.array([-0.025, y, z])
    t, hit, inside, deepest = first_crossing(cube, start, jnp.array([1.0, 0.0, 0.0]), 0.025, 32)
    assert bool(hit) and not bool(inside)
    assert abs(float(t) - 0.005) < 2e-5
    # the deepest sample is the segment's end (x = 0), HALF - max(|y|, |z|) inside the exact cube
    assert abs(float(deepest) + (HALF - max(abs(y), abs(z)))) < 2e-4
  t, hit, inside, deepest = first_crossing(cube, jnp.array([0.0, 0.0, 0.0]), jnp.array([1.0, 0.0, 0.0]), 0.03, 32,
                                           exiting=True)
  assert bool(hit) and abs(float(t) - HALF) < 2e-5
  assert abs(float(deepest) + (0.03 - HALF)) < 2e-4  # exiting: the farthest sample, 1 cm outside
  _, hit, inside, _ = first_crossing(cube, jnp.array([-0.01, 0.0, 0.0]), jnp.array([1.0, 0.0, 0.0]), 0.02, 32)
  assert bool(inside) and not bool(hit)


def test_ray_cast_matches_exact_mesh_intersection(sphere):
  mesh = builtin_mesh("sphere")
  rng = np.random.default_rng(2)
  origins = rng.normal(size=(200, 3))
  origins = 0.2 * origins / np.linalg.norm(origins, axis=1, keepdims=True)
  targets = rng.uniform(-0.035, 0.035, (200, 3))
  dirs = targets - origins
  dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
  t, hit, nearest = jax.jit(jax.vmap(lambda o, d: ray_cast(sphere, o, d, num_steps=48)))(
      jnp.asarray(origins, jnp.float32), jnp.asarray(dirs, jnp.float32))
  locs, ray_idx, _ = mesh.ray.intersects_location(origins, dirs, multiple_hits=False)
  ref_t = np.full(200, np.inf)
  ref_t[ray_idx] = np.linalg.norm(locs - origins[ray_idx], axis=1)
  ref_hit = np.isfinite(ref_t)
  # Rays that graze the silhouette within a voxel may differ; all others must agree exactly on hit/miss.
  closest = np.linalg.norm(np.cross(origins, dirs), axis=1)  # distance of the ray line from the centre
  clear = np.abs(closest - 0.03) > 1e-3
  np.testing.assert_array_equal(np.asarray(hit)[clear], ref_hit[clear])
  both = np.asarray(hit) & ref_hit & clear
  assert both.sum() > 50
  np.testing.assert_allclose(np.asarray(t)[both], ref_t[both], atol=2e-4)
  # A miss reports its closest marching point to the sphere: never nearer than the exact closest approach (the
  # line's distance from the centre minus R), and within 0.3 mm of it for near misses (the ones a margin needs).
  missed = ~np.asarray(hit) & clear
  exact, sampled = closest[missed] - 0.03, np.asarray(nearest)[missed]
  assert missed.sum() > 20 and np.sum(exact < 0.005) > 5
  assert np.all(sampled >= exact - 1e-4)
  np.testing.assert_allclose(sampled[exact < 0.005], exact[exact < 0.005], atol=3e-4)
  assert np.all(np.asarray(nearest)[np.asarray(hit)] < 0.1 * sphere.voxel_size)  # a hit: within the step floor


def test_a_ray_outside_the_grid_box_reports_a_finite_closest_distance(sphere):
  """Axis-parallel rays that never enter the grid box (once reported as millions of metres: the distance at the
  far-away crossing of a slab they are parallel to) report about their true closest approach, with a gradient."""
  half = 0.5 * sphere.sdf.shape[0] * float(sphere.voxel_size)  # the box's half-width about the sphere's centre
  offsets = np.array([half + 0.002, half + 0.01, 0.1], np.float32)
  centre = np.asarray(sphere.origin) + half - 0.5 * float(sphere.voxel_size)

  def closest(x):
    origin = jnp.asarray(centre) + jnp.array([x, 0.0, -0.2])
    return ray_cast(sphere, origin, jnp.array([0.0, 0.0, 1.0]), num_steps=16)[2]

  values = np.asarray(jax.vmap(closest)(jnp.asarray(offsets)))
  slopes = np.asarray(jax.vmap(jax.grad(closest))(jnp.asarray(offsets)))
  exact = offsets - 0.03  # the line's distance from the centre minus R
  assert np.all(values >= exact - 1e-4) and np.all(values <= 1.2 * exact), (values, exact)
  np.testing.assert_allclose(slopes, 1.0, atol=0.05)


def test_sdf_value_is_differentiable_inside_and_outside_the_grid(cube):
  """`jax.grad` of the distance is finite everywhere and equals the exact box gradient near a face."""
  grad = jax.jit(jax.vmap(jax.grad(sdf_value, argnums=1), in_axes=(None, 0)))
  p = np.array([[0.025, 0.001, -0.002], [-0.003, 0.017, 0.004], [0.0, 0.0, 0.2], [0.3, -0.004, 0.002]],
               np.float32)
  g = np.asarray(grad(cube, jnp.asarray(p)))
  assert np.all(np.isfinite(g))
  exact = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [1.0, 0, 0]])
  np.testing.assert_allclose(g, exact, atol=0.02)


def test_a_model_selected_from_a_stack_reads_exactly_what_the_model_itself_reads(cube, sphere, box):
  from dexjax.geometry import select_model, sdf_gradient
  from dexjax.quality.heap_reward import stack_models
  models = [cube, sphere, box]
  stack = stack_models(models)
  rng = np.random.default_rng(3)
  points = jnp.asarray(rng.uniform(-0.06, 0.06, (300, 3)), jnp.float32)  # inside and outside the grid boxes
  dirs = rng.normal(size=(300, 3))
  dirs = jnp.asarray(dirs / np.linalg.norm(dirs, axis=1, keepdims=True), jnp.float32)
  ids = jnp.asarray(rng.integers(0, 3, 300), jnp.int32)

  def read(model, p, d):
    t, hit, closest = ray_cast(model, p - 0.1 * d, d)
    return sdf_value(model, p), sdf_gradient(model, p), jnp.where(hit, t, -1.0), closest

  # One program per form: the view's index batched with the points (as the heap reward selects a target per
  # grasp), the plain models one at a time. The two programs fuse differently: equal to float32 rounding.
  viewed = jax.jit(jax.vmap(lambda i, p, d: read(select_model(stack, i), p, d)))(ids, points, dirs)
  plain = jax.jit(jax.vmap(read, in_axes=(None, 0, 0)))
  for i, model in enumerate(models):
    rows = np.flatnonzero(np.asarray(ids) == i)
    expected = plain(model, points[rows], dirs[rows])
    for got, want in zip(viewed, expected):
      np.testing.assert_allclose(np.asarray(got)[rows], np.asarray(want), rtol=0, atol=1e-6)
  # The view is not the first model's grid read at a wrong offset: the three objects differ at these points.
  assert len({round(float(sdf_value(m, points[0])), 6) for m in models}) == 3
