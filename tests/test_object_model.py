"""Tests for mesh loading / repair, `build_object_model`, the model cache and the built-in objects."""

from __future__ import annotations

import os
import time

import igl
import jax
import numpy as np
import pytest
import trimesh

from dexjax import geometry
from dexjax import objects
from dexjax.geometry import ImperfectMeshWarning, MeshError
from dexjax.geometry import build_object_model
from dexjax.geometry import cache as cache_mod
from dexjax.geometry import cached_object_model
from dexjax.geometry import load_mesh
from dexjax.geometry import validate_and_repair

GRID = 40


@pytest.fixture(scope='module')
def models() -> dict[str, geometry.ObjectModel]:
  return {name: build_object_model(objects.builtin_mesh(name), grid_size=GRID, num_surface_samples=512)
          for name in objects.BUILTIN_OBJECTS}


def _voxel_centres(model: geometry.ObjectModel) -> np.ndarray:
  """(D, D, D, 3) float64 voxel centre positions, metres."""
  d = model.grid_size
  axis = np.arange(d) * float(model.voxel_size)
  origin = np.asarray(model.origin, np.float64)
  return np.stack(np.meshgrid(*(origin[i] + axis for i in range(3)), indexing='ij'), axis=-1)


def _box_sdf(points: np.ndarray, half: np.ndarray) -> np.ndarray:
  """Exact signed distance (negative inside) to an origin-centred box with half extents ``half``."""
  q = np.abs(points) - half
  outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
  inside = np.minimum(np.max(q, axis=-1), 0.0)
  return outside + inside


def _point_triangle_distance(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
  """Exact distance from point (3,) to each of (T, 3, 3) triangles (Ericson, Real-Time Collision Detection)."""
  a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
  ab, ac, ap, bp, cp = b - a, c - a, p - a, p - b, p - c
  dot = lambda x, y: np.einsum('ij,ij->i', x, y)
  d1, d2, d3, d4, d5, d6 = dot(ab, ap), dot(ac, ap), dot(ab, bp), dot(ac, bp), dot(ab, cp), dot(ac, cp)
  va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
  with np.errstate(divide='ignore', invalid='ignore'):
    on_ab = a + (d1 / (d1 - d3))[:, None] * ab
    on_ac = a + (d2 / (d2 - d6))[:, None] * ac
    on_bc = b + ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[:, None] * (c - b)
    denom = 1.0 / (va + vb + vc)
    on_face = a + (vb * denom)[:, None] * ab + (vc * denom)[:, None] * ac
  conditions = [
      (d1 <= 0) & (d2 <= 0), (d3 >= 0) & (d4 <= d3), (vc <= 0) & (d1 >= 0) & (d3 <= 0),
      (d6 >= 0) & (d5 <= d6), (vb <= 0) & (d2 >= 0) & (d6 <= 0), (va <= 0) & (d4 >= d3) & (d5 >= d6),
  ]
  closest = np.select([m[:, None] for m in conditions], [a, b, on_ab, c, on_ac, on_bc], on_face)
  return np.linalg.norm(closest - p, axis=1)


def _reference_signed_distance(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
  """Brute-force signed distance (negative inside), independent of libigl.

  The magnitude is the exact point-triangle distance minimised over *all* faces; the sign comes from the
  generalised winding number (libigl, but not the pseudonormal test the builder uses). Neither
  `trimesh.proximity.signed_distance` nor `trimesh.triangles.closest_point` is used for the magnitude:
  both were seen to be off by up to 1.8e-5 m on the icosphere.
  """
  tri = np.asarray(mesh.triangles, np.float64)
  dist = np.array([np.min(_point_triangle_distance(p, tri)) for p in points])
  return np.where(_winding(mesh, points) > 0.5, -dist, dist)


def _winding(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
  """(P,) generalised winding number of ``points`` w.r.t. a closed mesh (1 inside, 0 outside)."""
  return igl.winding_number(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64),
                            np.asarray(points, np.float64))


def _random_voxels(model: geometry.ObjectModel, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
  rng = np.random.default_rng(seed)
  idx = rng.integers(0, model.grid_size, size=(n, 3))
  points = _voxel_centres(model)[idx[:, 0], idx[:, 1], idx[:, 2]]
  values = np.asarray(model.sdf)[idx[:, 0], idx[:, 1], idx[:, 2]]
  return points, values


# ----------------------------------------------------------------------------------------------- grid / SDF


def test_model_fields_have_documented_shapes_and_dtypes(models):
  model, d, s = models['box'], GRID, 512
  expected = {
      'sdf': (d, d, d), 'sdf_grad': (d, d, d, 3), 'origin': (3,), 'voxel_size': (),
      'surface_points': (s, 3), 'surface_normals': (s, 3), 'center_of_mass': (3,), 'volume': (),
      'inertia': (3, 3), 'bounds': (2, 3),
  }
  for field, shape in expected.items():
    value = getattr(model, field)
    assert isinstance(value, jax.Array), field
    assert value.shape == shape and value.dtype == np.float32, (field, value.shape, value.dtype)
  stacked = jax.tree.map(lambda a, b: np.stack([a, b]), models['box'], models['cube'])
  assert stacked.sdf.shape == (2, d, d, d)


def test_grid_frame_follows_sdfgen_convention(models):
  model = models['box']  # Largest extent 8 cm along x.
  delta = 0.08 / (GRID - 2 * 5)
  np.testing.assert_allclose(float(model.voxel_size), delta, rtol=1e-6)
  centres = _voxel_centres(model)
  # The grid is centred on the bounding-box centre (the origin for builtins).
  np.testing.assert_allclose(centres[0, 0, 0] + centres[-1, -1, -1], 0.0, atol=1e-7)
  np.testing.assert_allclose(centres[-1, 0, 0, 0] - centres[0, 0, 0, 0], (GRID - 1) * delta, rtol=1e-6)
  # Along the longest axis the padding is (2 * padding - 1) / 2 voxels between the mesh and the last centre.
  np.testing.assert_allclose(centres[-1, 0, 0, 0] - 0.04, 4.5 * delta, rtol=1e-5)


@pytest.mark.parametrize('name', ['sphere', 'l_shape', 'box_with_hole'])
def test_sdf_matches_brute_force_reference(models, name):
  model, mesh = models[name], objects.builtin_mesh(name)
  points, values = _random_voxels(model, 300, seed=1)
  np.testing.assert_allclose(values, _reference_signed_distance(mesh, points), atol=1e-5)
  assert (values < 0).any() and (values > 0).any()


@pytest.mark.parametrize('name', ['sphere', 'box_with_hole'])
def test_sdf_matches_trimesh_proximity(models, name):
  import rtree  # noqa: F401  trimesh.proximity needs it (the test extra installs it)
  model, mesh = models[name], objects.builtin_mesh(name)
  points, values = _random_voxels(model, 300, seed=1)
  # trimesh is positive inside; its nearest-face search is approximate (seen: 1.8e-5 m on the sphere).
  np.testing.assert_allclose(values, -trimesh.proximity.signed_distance(mesh, points), atol=5e-5)


def test_cube_sdf_equals_exact_box_distance(models):
  model = models['cube']
  expected = _box_sdf(_voxel_centres(model), np.full(3, 0.02))
  np.testing.assert_allclose(np.asarray(model.sdf), expected, atol=1e-5)


def test_sdf_sign_inside_outside_box_and_sphere(models):
  box_points, box_values = _random_voxels(models['box'], 2000, seed=2)
  box_truth = _box_sdf(box_points, np.array([0.04, 0.03, 0.02]))
  clear = np.abs(box_truth) > 1e-4
  assert (np.sign(box_values[clear]) == np.sign(box_truth[clear])).all()
  assert (box_truth[clear] < 0).sum() > 20  # Enough inside points for the test to mean something.
  sphere_points, sphere_values = _random_voxels(models['sphere'], 2000, seed=3)
  sphere_truth = np.linalg.norm(sphere_points, axis=-1) - 0.03
  clear = np.abs(sphere_truth) > 1e-4  # The icosphere deviates from the sphere by < 2e-5 m.
  assert (np.sign(sphere_values[clear]) == np.sign(sphere_truth[clear])).all()
  assert (sphere_truth[clear] < 0).sum() > 20


def test_gradient_unit_norm_and_outward_near_box_faces(models):
  model = models['box']
  delta = float(model.voxel_size)
  half = np.array([0.04, 0.03, 0.02])
  p = _voxel_centres(model)
  grad = np.asarray(model.sdf_grad)
  q = np.abs(p) - half
  axis = np.argmax(q, axis=-1)
  near = np.abs(np.max(q, axis=-1)) < 1.5 * delta
  # Away from edges (outside) and from the medial planes (inside): every other coordinate at least 3
  # voxels inside its faces, so all six finite-difference neighbours have the same nearest face.
  others = np.ones(q.shape[:-1], bool)
  for a in range(3):
    others &= (axis == a) | (q[..., a] < -3 * delta)
  mask = near & others
  assert mask.sum() > 100
  normal = np.zeros_like(p)
  np.put_along_axis(normal, axis[..., None], np.sign(np.take_along_axis(p, axis[..., None], -1)), -1)
  norms = np.linalg.norm(grad[mask], axis=-1)
  np.testing.assert_allclose(norms, 1.0, atol=0.05)
  cosine = np.sum(grad[mask] * normal[mask], axis=-1) / norms
  assert (cosine > 0.99).all()


def test_gradient_radial_near_sphere_and_one_sided_at_border(models):
  model = models['sphere']
  sdf, grad = np.asarray(model.sdf, np.float64), np.asarray(model.sdf_grad)
  delta = float(model.voxel_size)
  p = _voxel_centres(model)
  mask = np.abs(sdf) < 1.5 * delta
  assert mask.sum() > 100
  norms = np.linalg.norm(grad[mask], axis=-1)
  np.testing.assert_allclose(norms, 1.0, atol=0.05)
  radial = p[mask] / np.linalg.norm(p[mask], axis=-1, keepdims=True)
  assert (np.sum(grad[mask] * radial, axis=-1) / norms > 0.99).all()
  # Central differences inside, one-sided differences on the border faces of the grid.
  np.testing.assert_allclose(grad[5, 7, 9, 0], (sdf[6, 7, 9] - sdf[4, 7, 9]) / (2 * delta), atol=1e-5)
  np.testing.assert_allclose(grad[0, 7, 9, 0], (sdf[1, 7, 9] - sdf[0, 7, 9]) / delta, atol=1e-5)
  np.testing.assert_allclose(grad[3, 7, -1, 2], (sdf[3, 7, -1] - sdf[3, 7, -2]) / delta, atol=1e-5)


# ------------------------------------------------------------------------------------------ mass properties


def test_box_mass_properties_analytic(models):
  model = models['box']
  a, b, c = 0.08, 0.06, 0.04
  np.testing.assert_allclose(float(model.volume), a * b * c, rtol=1e-6)
  np.testing.assert_allclose(np.asarray(model.center_of_mass), 0.0, atol=1e-9)
  expected = np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) / 12.0
  np.testing.assert_allclose(np.asarray(model.inertia), expected, rtol=1e-5, atol=1e-12)
  np.testing.assert_allclose(np.asarray(model.bounds), [[-a / 2, -b / 2, -c / 2], [a / 2, b / 2, c / 2]],
                             atol=1e-9)


def test_l_shape_com_off_centre_matches_hand_computation(models):
  model = models['l_shape']
  # Before centring: foot [0, 8] x [-2, 2] x [0, 2] cm; the upright adds [6, 8] x [-2, 2] x [2, 8] cm.
  foot_volume, foot_com = 0.08 * 0.04 * 0.02, np.array([0.04, 0.0, 0.01])
  upper_volume, upper_com = 0.02 * 0.04 * 0.06, np.array([0.07, 0.0, 0.05])
  volume = foot_volume + upper_volume
  com = (foot_volume * foot_com + upper_volume * upper_com) / volume
  bbox_centre = np.array([0.04, 0.0, 0.04])
  np.testing.assert_allclose(float(model.volume), volume, rtol=1e-6)
  np.testing.assert_allclose(np.asarray(model.center_of_mass), com - bbox_centre, atol=1e-7)
  assert abs(float(model.center_of_mass[0])) > 0.01 and abs(float(model.center_of_mass[2])) > 0.01
  np.testing.assert_allclose(np.asarray(model.bounds).mean(axis=0), 0.0, atol=1e-9)


# ---------------------------------------------------------------------------------------- surface samples


@pytest.mark.parametrize('name', ['sphere', 'box_with_hole'])
def test_surface_samples_on_surface_with_outward_normals(models, name):
  model, mesh = models[name], objects.builtin_mesh(name)
  points = np.asarray(model.surface_points, np.float64)
  normals = np.asarray(model.surface_normals, np.float64)
  assert points.shape == (512, 3)
  np.testing.assert_allclose(_reference_signed_distance(mesh, points), 0.0, atol=1e-7)
  np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-5)
  eps = 2e-4
  assert (_winding(mesh, points + eps * normals) < 0.5).all()  # Outside.
  assert (_winding(mesh, points - eps * normals) > 0.5).all()  # Inside.


def test_surface_samples_deterministic_by_seed_and_area_uniform():
  mesh = objects.builtin_mesh('box')
  first = build_object_model(mesh, grid_size=16, num_surface_samples=4000, seed=7)
  second = build_object_model(mesh, grid_size=16, num_surface_samples=4000, seed=7)
  other = build_object_model(mesh, grid_size=16, num_surface_samples=4000, seed=8)
  np.testing.assert_array_equal(np.asarray(first.surface_points), np.asarray(second.surface_points))
  assert not np.allclose(np.asarray(first.surface_points), np.asarray(other.surface_points))
  # Area-uniform: the fraction of samples on the +-z faces is (2 * 8 * 6) / total area.
  normals = np.asarray(first.surface_normals)
  on_z = np.mean(np.abs(normals[:, 2]) > 0.99)
  expected = 2 * 48 / (2 * (48 + 32 + 24))
  assert abs(on_z - expected) < 0.03


# ------------------------------------------------------------------------------------------ mesh loading


def _write(path, text: str) -> str:
  path.write_text(text)
  return str(path)


def test_empty_files_rejected(tmp_path):
  empty = tmp_path / 'empty.obj'
  empty.write_bytes(b'')
  with pytest.raises(MeshError, match='empty file') as info:
    load_mesh(empty)
  assert info.value.file == str(empty)
  comments = _write(tmp_path / 'comments.obj', '# nothing here\n')
  with pytest.raises(MeshError, match='no triangle faces') as info:
    load_mesh(comments)
  assert info.value.file == comments and 'comments.obj' in str(info.value)


def test_nan_vertices_rejected(tmp_path):
  text = 'v 0 0 0\nv 0.01 0 nan\nv 0 0.01 0\nv 0 0 0.01\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n'
  path = _write(tmp_path / 'nan.obj', text)
  with pytest.raises(MeshError, match='NaN') as info:
    load_mesh(path)
  assert info.value.file == path and '1 vertices' in info.value.reason


def test_flat_mesh_rejected(tmp_path):
  # A closed but flat "pillow": the same square wound both ways.
  text = 'v 0 0 0\nv 0.01 0 0\nv 0.01 0.01 0\nv 0 0.01 0\nf 1 2 3\nf 1 3 4\nf 1 3 2\nf 1 4 3\n'
  path = _write(tmp_path / 'flat.obj', text)
  with pytest.raises(MeshError, match='zero volume') as info:
    load_mesh(path)
  assert info.value.file == path


def test_small_hole_repaired_large_hole_rejected(tmp_path):
  box = trimesh.creation.box(extents=(0.08, 0.06, 0.04))
  top = box.face_normals[:, 2] > 0.9
  assert top.sum() == 2
  open_box = trimesh.Trimesh(box.vertices, box.faces[~top], process=False)
  assert not open_box.is_watertight
  repaired = validate_and_repair(open_box, 'open_box.obj')
  assert repaired.is_watertight
  np.testing.assert_allclose(repaired.volume, box.volume, rtol=1e-9)

  # A large hole is not an error: the mesh loads as the solid its winding number encloses, with a warning.
  sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
  shell = trimesh.Trimesh(sphere.vertices, sphere.faces[sphere.triangles_center[:, 2] > 0], process=False)
  path = str(tmp_path / 'hemisphere.stl')
  shell.export(path)
  with pytest.warns(ImperfectMeshWarning, match=r"hemisphere.stl': not watertight after repair \(\d+ open edges"):
    solid = load_mesh(path)
  assert solid.is_watertight and solid.is_winding_consistent
  assert 0.8 < solid.volume / (0.5 * sphere.volume) < 1.05  # about the half ball under the shell


def test_unsupported_extension_rejected(tmp_path):
  path = _write(tmp_path / 'mesh.txt', 'v 0 0 0\n')
  with pytest.raises(MeshError, match=r"'\.txt'.*\.obj.*\.stl") as info:
    load_mesh(path)
  assert info.value.file == path
  with pytest.raises(MeshError, match='file not found'):
    load_mesh(tmp_path / 'missing.obj')


def test_winding_and_inversion_repaired():
  box = trimesh.creation.box(extents=(0.08, 0.06, 0.04))
  faces = np.asarray(box.faces).copy()
  faces[[0, 3, 7]] = faces[[0, 3, 7], ::-1]
  scrambled = validate_and_repair(trimesh.Trimesh(box.vertices, faces, process=False))
  assert scrambled.is_winding_consistent and scrambled.volume == pytest.approx(box.volume, rel=1e-9)
  inverted = validate_and_repair(trimesh.Trimesh(box.vertices, box.faces[:, ::-1], process=False))
  assert inverted.volume == pytest.approx(box.volume, rel=1e-9)
  soup = trimesh.Trimesh(box.triangles.reshape(-1, 3), np.arange(36).reshape(-1, 3), process=False)
  assert validate_and_repair(soup).volume == pytest.approx(box.volume, rel=1e-9)


def test_overlapping_parts_are_unioned():
  import manifold3d  # noqa: F401  a dexjax dependency
  a = trimesh.creation.box(extents=(0.08, 0.06, 0.04))
  b = a.copy()
  b.apply_translation([0.04, 0.0, 0.0])
  merged = validate_and_repair(trimesh.util.concatenate([a, b]), 'two_boxes.glb')
  assert merged.is_watertight
  np.testing.assert_allclose(merged.volume, 0.12 * 0.06 * 0.04, rtol=1e-5)


def test_nested_cavity_kept_as_cavity():
  outer = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
  inner = trimesh.creation.box(extents=(0.04, 0.04, 0.04))  # Both wound outward in the input.
  hollow = validate_and_repair(trimesh.util.concatenate([outer, inner]))
  np.testing.assert_allclose(hollow.volume, 0.1**3 - 0.04**3, rtol=1e-9)
  model = build_object_model(hollow, grid_size=24, num_surface_samples=16)
  centre = np.asarray(model.sdf)[11:13, 11:13, 11:13]
  assert (centre > 0).all()  # The cavity is outside the material.


@pytest.mark.parametrize('ext', ['obj', 'stl', 'ply', 'glb', 'off'])
def test_formats_round_trip(tmp_path, ext):
  mesh = objects.builtin_mesh('box_with_hole')
  path = str(tmp_path / f'part.{ext}')
  mesh.export(path)
  loaded = load_mesh(path)
  assert loaded.is_watertight
  np.testing.assert_allclose(loaded.volume, mesh.volume, rtol=1e-5)


def test_millimetre_scale(tmp_path):
  mesh = objects.builtin_mesh('l_shape')
  mesh_mm = trimesh.Trimesh(mesh.vertices * 1000.0, mesh.faces, process=False)
  path = str(tmp_path / 'l_mm.stl')
  mesh_mm.export(path)
  loaded = load_mesh(path, scale=0.001)
  np.testing.assert_allclose(loaded.volume, mesh.volume, rtol=1e-5)
  np.testing.assert_allclose(loaded.bounds, mesh.bounds, atol=1e-7)
  with pytest.raises(ValueError, match='scale'):
    load_mesh(path, scale=-1.0)


def test_glb_scene_transforms_applied(tmp_path):
  scene = trimesh.Scene()
  box = trimesh.creation.box(extents=(0.02, 0.02, 0.02))
  scene.add_geometry(box, node_name='a', transform=trimesh.transformations.translation_matrix([0.1, 0, 0]))
  scene.add_geometry(box, node_name='b', transform=trimesh.transformations.translation_matrix([-0.1, 0, 0]))
  path = str(tmp_path / 'scene.glb')
  scene.export(path)
  loaded = load_mesh(path)
  np.testing.assert_allclose(loaded.volume, 2 * 0.02**3, rtol=1e-5)
  np.testing.assert_allclose(loaded.bounds, [[-0.11, -0.01, -0.01], [0.11, 0.01, 0.01]], atol=1e-6)


# ------------------------------------------------------------------------------------------------- cache


@pytest.fixture
def count_builds(monkeypatch):
  calls = []
  real = cache_mod.build_object_model

  def counting(*args, **kwargs):
    calls.append(kwargs)
    return real(*args, **kwargs)

  monkeypatch.setattr(cache_mod, 'build_object_model', counting)
  return calls


def _assert_models_equal(a: geometry.ObjectModel, b: geometry.ObjectModel) -> None:
  for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
    np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_cache_hit_and_new_entry_for_changed_parameter(tmp_path, count_builds):
  mesh = objects.builtin_mesh('cylinder')
  first = cached_object_model(mesh, cache_dir=tmp_path, grid_size=24, num_surface_samples=64)
  second = cached_object_model(mesh, cache_dir=tmp_path, grid_size=24, num_surface_samples=64, name='x')
  assert len(count_builds) == 1
  _assert_models_equal(first, second)
  _assert_models_equal(first, build_object_model(mesh, grid_size=24, num_surface_samples=64))
  cached_object_model(mesh, cache_dir=tmp_path, grid_size=24, num_surface_samples=64, seed=1)
  cached_object_model(mesh, cache_dir=tmp_path, grid_size=26, num_surface_samples=64)
  moved = mesh.copy()
  moved.apply_translation([0.001, 0, 0])
  cached_object_model(moved, cache_dir=tmp_path, grid_size=24, num_surface_samples=64)
  assert len(count_builds) == 4
  entries = os.listdir(tmp_path)
  assert len(entries) == 4 and not any(f.startswith('.tmp-') for f in entries)  # No temporary files.
  # Explicit default values share the entry with omitted ones.
  assert cache_mod.cache_key(mesh, grid_size=100) == cache_mod.cache_key(mesh)


@pytest.mark.parametrize('damage', ['garbage', 'truncate'])
def test_corrupt_cache_file_rebuilt(tmp_path, count_builds, damage):
  mesh = objects.builtin_mesh('cube')
  kwargs = dict(grid_size=20, num_surface_samples=32)
  good = cached_object_model(mesh, cache_dir=tmp_path, **kwargs)
  (path,) = [tmp_path / f for f in os.listdir(tmp_path)]
  data = path.read_bytes()
  path.write_bytes(b'not an npz file' if damage == 'garbage' else data[: len(data) // 2])
  with pytest.warns(RuntimeWarning, match='corrupt'):
    rebuilt = cached_object_model(mesh, cache_dir=tmp_path, **kwargs)
  assert len(count_builds) == 2
  _assert_models_equal(good, rebuilt)
  cached_object_model(mesh, cache_dir=tmp_path, **kwargs)  # The replaced file is valid again.
  assert len(count_builds) == 2


def test_default_cache_dir_from_environment(tmp_path, monkeypatch, count_builds):
  monkeypatch.setenv('DEXJAX_CACHE', str(tmp_path / 'env_cache'))
  assert geometry.default_cache_dir() == str(tmp_path / 'env_cache')
  objects.load_object_model('builtin:cube', grid_size=16, num_surface_samples=8)
  assert len(os.listdir(tmp_path / 'env_cache')) == 1
  start = time.perf_counter()
  objects.load_object_model('builtin:cube', grid_size=16, num_surface_samples=8)
  assert time.perf_counter() - start < 5.0
  assert len(count_builds) == 1
  monkeypatch.delenv('DEXJAX_CACHE')
  assert geometry.default_cache_dir() == os.path.expanduser('~/.cache/dexjax/objects')


# ----------------------------------------------------------------------------------------------- builtins


def test_builtins_watertight_centred_and_sized():
  expected_extents = {
      'cube': (0.04, 0.04, 0.04), 'box': (0.08, 0.06, 0.04), 'box_with_hole': (0.08, 0.06, 0.04),
      'cylinder': (0.05, 0.05, 0.08), 'sphere': (0.06, 0.06, 0.06), 'l_shape': (0.08, 0.04, 0.08),
  }
  assert set(objects.BUILTIN_OBJECTS) == set(expected_extents)
  for name, extents in expected_extents.items():
    mesh = objects.builtin_mesh(name)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0, name
    np.testing.assert_allclose(mesh.bounds.mean(axis=0), 0.0, atol=1e-9, err_msg=name)
    np.testing.assert_allclose(mesh.extents, extents, atol=2e-4, err_msg=name)  # Polygonal curves.
  np.testing.assert_allclose(objects.builtin_mesh('cylinder').volume, np.pi * 0.025**2 * 0.08, rtol=0.01)
  np.testing.assert_allclose(objects.builtin_mesh('sphere').volume, 4 / 3 * np.pi * 0.03**3, rtol=0.01)


def test_resolve_mesh_specs(tmp_path):
  mesh, name = objects.resolve_mesh('builtin:box')
  assert name == 'builtin:box' and mesh.volume == pytest.approx(0.08 * 0.06 * 0.04)
  scaled, _ = objects.resolve_mesh('builtin:cube', scale=2.0)
  assert scaled.volume == pytest.approx(0.08**3)
  with pytest.raises(ValueError, match='unknown builtin.*cube.*sphere'):
    objects.resolve_mesh('builtin:teapot')
  path = str(tmp_path / 'cube.obj')
  objects.builtin_mesh('cube').export(path)
  loaded, name = objects.resolve_mesh(path)
  assert name == path and loaded.volume == pytest.approx(0.04**3)
  model = objects.load_object_model(path, cache_dir=tmp_path / 'cache', grid_size=16, num_surface_samples=8)
  assert model.grid_size == 16


def test_box_with_hole_is_open_along_the_axis():
  mesh = objects.builtin_mesh('box_with_hole')
  np.testing.assert_allclose(mesh.volume, 0.08 * 0.06 * 0.04 - np.pi * 0.006**2 * 0.04, rtol=0.02)
  # An odd grid puts a column of voxel centres exactly on the hole axis.
  model = build_object_model(mesh, grid_size=41, num_surface_samples=16)
  sdf = np.asarray(model.sdf)
  centre = np.asarray(_voxel_centres(model))[20, 20]
  np.testing.assert_allclose(centre[:, :2], 0.0, atol=1e-7)
  assert (sdf[20, 20, :] > 0).all()
  inside_material = np.abs(centre[:, 2]) < 0.02 - float(model.voxel_size)
  np.testing.assert_allclose(sdf[20, 20, inside_material], 0.006, atol=2e-5)  # Distance to the bore.
  # The plain box is solid along the same line, so the check above can fail.
  solid = build_object_model(objects.builtin_mesh('box'), grid_size=41, num_surface_samples=16)
  assert (np.asarray(solid.sdf)[20, 20, :] < 0).any()
  # Exactly on the axis (not just at voxel centres), a vertical line through the object never touches
  # material: it stays outside and at least the bore's inradius away from the surface.
  line = np.c_[np.zeros((81, 2)), np.linspace(-0.04, 0.04, 81)]
  assert (_winding(mesh, line) < 0.5).all()
  assert (_reference_signed_distance(mesh, line) > 0.9 * 0.006).all()
  beside = line + np.array([0.02, 0.0, 0.0])  # A parallel line through the material does enter it.
  assert (_winding(mesh, beside) > 0.5).any()
