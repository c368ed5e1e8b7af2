"""Imperfect meshes (open, non-manifold, mis-wound) load as the solid their winding number encloses.

References: libigl's pseudonormal signed distance and trimesh's exact proximity on the closed originals; the
robust labels of the closed originals for the same grasps and keys.
"""

from __future__ import annotations

import warnings

import jax
import numpy as np
import pytest
import trimesh

from dexjax.geometry import (ImperfectMeshWarning, MeshError, build_object_model, load_mesh, solidify,
                             validate_and_repair, winding_signed_distance)
from dexjax.geometry.winding import cached_solidify, orient_patches
from dexjax.objects import defects, load_mesh_folder, prepare_object
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality import evaluate_grasps, parallel_jaw_perturbations, suction_perturbations
from dexjax.sampling import sample_antipodal_grasps, sample_suction_grasps

GRID = 64  # as tests/conftest.py: shares compiled quality functions with the other tests of this worker


def _pj_prob(model, key, grasps):
  return evaluate_grasps(key, model, grasps, ParallelJawGripper(), parallel_jaw_perturbations()).probability


def _suction_prob(model, key, grasps):
  return evaluate_grasps(key, model, grasps, SuctionGripper(), suction_perturbations()).probability


def _can(sections=48, radius=0.02, height=0.09):
  """A closed slim-can-like cylinder (fits the 5 cm jaws), tessellated like an asset (edges <= 6 mm)."""
  return trimesh.creation.cylinder(radius, height, sections=sections).subdivide_to_size(0.006)


def _box():
  return trimesh.creation.box((0.06, 0.04, 0.03)).subdivide_to_size(0.004)


def _load(mesh, name):
  with pytest.warns(ImperfectMeshWarning, match=name):
    return validate_and_repair(mesh, name)


def test_winding_distance_equals_exact_distance_and_inside_test_on_closed_meshes():
  rng = np.random.default_rng(0)
  for mesh in (_box(), trimesh.creation.icosphere(3, radius=0.04), _can()):
    points = rng.uniform(mesh.bounds[0] - 0.01, mesh.bounds[1] + 0.01, (400, 3))
    ours = winding_signed_distance(mesh.vertices, mesh.faces, points)
    triangles = np.asarray(mesh.triangles)
    exact = np.array([np.linalg.norm(trimesh.triangles.closest_point(triangles, np.repeat(p[None], len(triangles), 0))
                                     - p, axis=1).min() for p in points])  # brute force over every triangle
    np.testing.assert_allclose(np.abs(ours), exact, atol=1e-5)  # 10 um: trimesh's closest point is float-fuzzy
    clear = exact > 1e-5
    assert np.array_equal((ours < 0)[clear], mesh.contains(points)[clear])  # trimesh's ray-parity test


def test_solidify_reproduces_a_closed_mesh_within_a_fraction_of_a_voxel():
  mesh = _can()
  vertices, faces = solidify(mesh.vertices, mesh.faces, resolution=64)
  solid = trimesh.Trimesh(vertices, faces, process=False)
  assert solid.is_watertight and solid.is_winding_consistent and solid.volume > 0
  assert len(faces) <= 20_000
  voxel = 0.09 / 64
  np.testing.assert_allclose(solid.volume, mesh.volume, rtol=0.01)
  # every rebuilt vertex lies on the original surface to within half a voxel (edges are rounded, faces exact)
  on_surface = np.abs(trimesh.proximity.signed_distance(mesh, vertices[::7]))
  assert on_surface.max() < 0.5 * voxel and np.median(on_surface) < 0.05 * voxel


def test_patches_wound_the_wrong_way_are_turned_outward():
  can = _can()
  open_can = defects.remove_facing(can, (0, 0, 1), 10.0)  # no lid: one open patch (side + bottom)
  lid_side = trimesh.Trimesh(can.vertices, can.faces[can.face_normals[:, 2] > 0.99], process=False)
  # a separate, inverted lid patch floating just above (a disconnected part of the soup)
  lid = trimesh.Trimesh(lid_side.vertices + [0, 0, 0.002], lid_side.faces[:, ::-1], process=False)
  soup = trimesh.util.concatenate([defects.flip_faces(open_can, 0.5, seed=3), lid])
  faces, patches = orient_patches(np.asarray(soup.vertices), np.asarray(soup.faces))
  assert patches >= 2
  oriented = trimesh.Trimesh(soup.vertices, faces, process=False)
  radial = oriented.triangles_center - [0, 0, oriented.triangles_center[:, 2].mean()]
  radial[:, 2] *= 4.0  # caps: mostly along z
  assert np.mean(np.einsum('ij,ij->i', oriented.face_normals, radial) > 0) > 0.99


@pytest.mark.parametrize('defect', ['holes', 'missing_side', 'seam', 'fins', 'duplicated', 'holes_flipped'])
def test_imperfect_copies_load_with_a_warning_and_keep_their_labels(defect):
  key = jax.random.key(7)
  agreements = {}
  for name, mesh in (('box', _box()), ('can', _can())):
    broken = {
        'holes': lambda m: defects.open_holes(m, num_holes=2, radius=0.1, seed=1),
        'missing_side': lambda m: defects.remove_facing(m, (0.0, 0.0, 1.0), 30.0),
        'seam': lambda m: defects.split_seam(m, axis=0),
        'fins': lambda m: defects.add_fins(m, num_fins=6, seed=1),
        'duplicated': lambda m: defects.duplicate_faces(m, fraction=0.2, seed=1),
        'holes_flipped': lambda m: defects.flip_faces(defects.open_holes(m, 2, 0.1, seed=2), 0.3, seed=2),
    }[defect](mesh)
    solid = _load(broken, f'{name}-{defect}.obj')
    assert solid.is_watertight and solid.is_winding_consistent
    np.testing.assert_allclose(solid.volume, mesh.volume, rtol=0.03)
    original = build_object_model(mesh, grid_size=GRID)
    imperfect = build_object_model(solid, grid_size=GRID)
    for gripper, sampler, prob in (('pj', sample_antipodal_grasps, _pj_prob),
                                   ('suction', sample_suction_grasps, _suction_prob)):
      grasps, valid = sampler(jax.random.fold_in(key, 1), original, 256)
      idx = np.nonzero(np.asarray(valid))[0][:128]
      assert len(idx) >= 64, (name, gripper)
      grasps = jax.tree.map(lambda x: x[idx], grasps)
      k = jax.random.fold_in(key, 2)
      same = np.asarray(prob(original, k, grasps) > 0.5) == np.asarray(prob(imperfect, k, grasps) > 0.5)
      agreements[name, gripper] = float(same.mean())
  assert min(agreements.values()) >= 0.95, agreements


def test_unusable_meshes_are_still_rejected():
  x, y = np.meshgrid(np.linspace(-0.03, 0.03, 11), np.linspace(-0.03, 0.03, 11), indexing='ij')
  vertices = np.stack([x.ravel(), y.ravel(), 20 * x.ravel() * y.ravel()], axis=1)  # a saddle: curved, no volume
  ij = np.arange(121).reshape(11, 11)
  quads = np.stack([ij[:-1, :-1], ij[1:, :-1], ij[1:, 1:], ij[:-1, 1:]], axis=-1).reshape(-1, 4)
  faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
  with pytest.raises(MeshError, match=r"saddle.obj'.*open edges.*no volume is inside it"):
    validate_and_repair(trimesh.Trimesh(vertices, faces, process=False), 'saddle.obj')
  with pytest.raises(MeshError, match='NaN'):
    validate_and_repair(trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0], [0, 0, 1]],
                                        [[0, 1, 2], [0, 1, 3]], process=False), 'nan.obj')


def test_solids_are_cached_by_content(tmp_path, monkeypatch):
  from dexjax.geometry import winding as solidify_mod
  mesh = defects.remove_facing(_box(), (0, 0, 1), 10.0)
  calls = []
  real = solidify_mod.solidify
  monkeypatch.setattr(solidify_mod, 'solidify', lambda *a, **k: calls.append(1) or real(*a, **k))
  first = cached_solidify(mesh.vertices, mesh.faces, cache_dir=str(tmp_path), resolution=32)
  second = cached_solidify(mesh.vertices, mesh.faces, cache_dir=str(tmp_path), resolution=32)
  assert len(calls) == 1
  np.testing.assert_array_equal(first[0], second[0])
  np.testing.assert_array_equal(first[1], second[1])
  (cached,) = list((tmp_path / 'solids').iterdir())
  cached.write_bytes(b'corrupt')
  third = cached_solidify(mesh.vertices, mesh.faces, cache_dir=str(tmp_path), resolution=32)
  assert len(calls) == 2 and np.array_equal(third[1], first[1])


def _asset_folder(directory):
  """Downloaded-style assets: a soda can with a loose lid (open seams), a bottle whose neck and body share an
  internal disc (non-manifold), a mug with an open top and a handle pushed into its wall, and a closed box."""
  can = trimesh.creation.cylinder(0.022, 0.11, sections=40)  # slim: fits the 5 cm jaws
  lid = can.face_normals[:, 2] > 0.99
  body = trimesh.Trimesh(can.vertices, can.faces[~lid], process=False)
  loose_lid = trimesh.Trimesh(can.vertices + [0, 0, 2e-5], can.faces[lid], process=False)
  trimesh.util.concatenate([body, loose_lid]).export(directory / 'soda_can.obj')

  profile = [[0, 0], [0.03, 0], [0.03, 0.1], [0.012, 0.13], [0.012, 0.16], [0, 0.16]]  # (radius, height)
  bottle = trimesh.creation.revolve(profile, sections=32)
  shoulder = np.nonzero(np.isclose(bottle.vertices[:, 2], 0.1) & (bottle.vertices[:, 0] ** 2 > 1e-8))[0]
  ring = shoulder[np.argsort(np.arctan2(bottle.vertices[shoulder, 1], bottle.vertices[shoulder, 0]))]
  centre = len(bottle.vertices)
  disc = [[ring[i], ring[(i + 1) % len(ring)], centre] for i in range(len(ring))]  # an inner wall on the ring
  trimesh.Trimesh(np.concatenate([bottle.vertices, [[0, 0, 0.1]]]), np.concatenate([bottle.faces, disc]),
                  process=False).export(directory / 'bottle.stl')

  outer = trimesh.creation.cylinder(0.022, 0.08, sections=40)
  inner = trimesh.creation.cylinder(0.018, 0.08, sections=40)
  inner.apply_translation([0, 0, 0.005])
  cup = trimesh.util.concatenate([defects.remove_facing(outer, (0, 0, 1), 10.0), inner])
  cup.faces[len(outer.faces):] = cup.faces[len(outer.faces):][:, ::-1]
  handle = trimesh.creation.torus(0.02, 0.005, major_sections=24, minor_sections=8)
  handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
  handle.apply_translation([0.03, 0, 0])
  trimesh.util.concatenate([cup, handle]).export(directory / 'mug.ply')

  trimesh.creation.box((0.05, 0.04, 0.03)).export(directory / 'box.glb')


def test_a_folder_of_imperfect_assets_loads_and_gives_robust_grasps(tmp_path):
  folder = tmp_path / 'assets'
  folder.mkdir()
  _asset_folder(folder)
  report = load_mesh_folder(folder)
  assert not report.rejected, report.rejected
  assert [o.name for o in report.loaded] == ['bottle', 'box', 'mug', 'soda_can']
  assert {o.name for o in report.loaded if o.warnings} == {'bottle', 'mug', 'soda_can'}
  key = jax.random.key(3)
  for obj in report.loaded:
    prepared = prepare_object(obj, cache_dir=tmp_path / 'cache', grid_size=GRID)
    assert prepared.mesh.is_watertight and len(prepared.hulls) >= 1
    model = prepared.model
    for sampler, prob in ((sample_antipodal_grasps, _pj_prob), (sample_suction_grasps, _suction_prob)):
      grasps, valid = sampler(key, model, 512)
      idx = np.nonzero(np.asarray(valid))[0][:128]
      grasps = jax.tree.map(lambda x: x[idx], grasps)
      robust = np.asarray(prob(model, key, grasps)) > 0.5
      assert robust.sum() >= 1, (obj.name, sampler.__name__, len(idx))


def test_load_mesh_warns_once_with_file_and_problem(tmp_path):
  path = tmp_path / 'bottle.stl'
  body = trimesh.creation.cylinder(0.035, 0.15, sections=24)
  fin = defects.add_fins(body, num_fins=3, seed=0)
  fin.export(path)
  with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter('always')
    solid = load_mesh(path)
  messages = [str(w.message) for w in caught if issubclass(w.category, ImperfectMeshWarning)]
  assert len(messages) == 1 and str(path) in messages[0] and 'non-manifold edges' in messages[0]
  assert solid.is_watertight
