"""Tests for the convex collision decomposition (`dexjax.objects.collision`)."""

from __future__ import annotations

import os

import numpy as np
import pytest
import scipy.spatial
import trimesh

from dexjax.objects import builtin_mesh, cached_collision_hulls, collision_hulls
from dexjax.objects import collision as collision_mod


def _assert_on_own_hull(points: np.ndarray, tol: float = 1e-9) -> None:
  """Every point is a vertex of the convex hull of the points (none strictly inside)."""
  hull = scipy.spatial.ConvexHull(points)
  # Facet equations: n . p + d <= 0 inside; a hull vertex has max over facets ~ 0.
  height = points @ hull.equations[:, :3].T + hull.equations[:, 3]
  assert height.max() <= tol
  np.testing.assert_array_less(-tol, height.max(axis=1))
  assert len(hull.vertices) == len(points)


def _union(hulls) -> trimesh.Trimesh:
  pieces = [trimesh.convex.convex_hull(h) for h in hulls]
  return trimesh.boolean.union(pieces, engine='manifold') if len(pieces) > 1 else pieces[0]


@pytest.fixture(scope='module')
def l_shape_hulls():
  return collision_hulls(builtin_mesh('l_shape'))


def test_convex_box_gives_one_hull_with_the_box_volume():
  hulls = collision_hulls(builtin_mesh('box'))
  assert len(hulls) == 1
  assert hulls[0].shape == (8, 3) and hulls[0].dtype == np.float64
  np.testing.assert_allclose(trimesh.convex.convex_hull(hulls[0]).volume, 0.08 * 0.06 * 0.04, rtol=1e-9)
  _assert_on_own_hull(hulls[0])


def test_l_shape_decomposes_into_convex_pieces_covering_it(l_shape_hulls):
  mesh = builtin_mesh('l_shape')
  assert 2 <= len(l_shape_hulls) <= 8
  for hull in l_shape_hulls:
    assert hull.ndim == 2 and hull.shape[1] == 3 and 4 <= len(hull) <= 64 and hull.dtype == np.float64
    _assert_on_own_hull(hull)
  union = _union(l_shape_hulls)
  assert abs(union.volume / mesh.volume - 1.0) < 0.15
  # The single convex hull of the L would be 64 % too large: the decomposition must follow the concavity.
  assert union.volume < 0.9 * mesh.convex_hull.volume
  points, _ = trimesh.sample.sample_surface_even(mesh, 1000, seed=0)
  # trimesh's signed distance is positive inside; the distance outside a hull is max(0, -signed).
  outside = [np.maximum(-trimesh.convex.convex_hull(h).nearest.signed_distance(points), 0.0)
             for h in l_shape_hulls]
  distance = np.min(outside, axis=0)
  assert np.mean(distance <= 0.002) >= 0.95


def test_vertex_cap_respected_and_volume_loss_as_documented():
  sphere = builtin_mesh('sphere')  # 2562 hull vertices.
  full = sphere.convex_hull.volume
  for cap, max_loss in ((64, 0.10), (16, 0.36)):
    (hull,) = collision_hulls(sphere, max_vertices=cap)
    assert len(hull) == cap
    _assert_on_own_hull(hull)
    loss = 1.0 - trimesh.convex.convex_hull(hull).volume / full
    assert 0.0 < loss < max_loss
  for hull in collision_hulls(builtin_mesh('l_shape'), max_vertices=6):
    assert 4 <= len(hull) <= 6
    _assert_on_own_hull(hull)


def test_single_hull_is_the_convex_hull(l_shape_hulls):
  mesh = builtin_mesh('l_shape')
  (hull,) = collision_hulls(mesh, max_hulls=1)
  np.testing.assert_allclose(trimesh.convex.convex_hull(hull).volume, mesh.convex_hull.volume, rtol=1e-9)


def test_deterministic(l_shape_hulls):
  again = collision_hulls(builtin_mesh('l_shape'))
  assert len(again) == len(l_shape_hulls)
  for a, b in zip(again, l_shape_hulls):
    np.testing.assert_array_equal(a, b)


def test_merge_keeps_the_hull_count_contract():
  boxes = [trimesh.creation.box((0.01,) * 3, trimesh.transformations.translation_matrix(t)).vertices
           for t in ((0, 0, 0), (0.01, 0, 0), (0.1, 0, 0))]
  merged = collision_mod._merge_to([np.asarray(b, np.float64) for b in boxes], 2, 64)
  assert len(merged) == 2
  # The two touching cubes merge (no volume added); the far one stays alone.
  np.testing.assert_allclose(sorted(trimesh.convex.convex_hull(h).volume for h in merged), [1e-6, 2e-6])


def test_bad_parameters_name_the_field():
  with pytest.raises(ValueError, match='max_vertices: expected an integer >= 4, got 3'):
    collision_hulls(builtin_mesh('box'), max_vertices=3)
  with pytest.raises(ValueError, match='max_hulls'):
    collision_hulls(builtin_mesh('box'), max_hulls=0)


def test_cache_round_trip_hit_miss_and_corrupt_entry(tmp_path, monkeypatch, l_shape_hulls):
  calls = []
  real = collision_mod.collision_hulls
  monkeypatch.setattr(collision_mod, 'collision_hulls', lambda mesh, **kw: calls.append(kw) or real(mesh, **kw))
  mesh = builtin_mesh('l_shape')
  first = cached_collision_hulls(mesh, cache_dir=tmp_path)
  second = cached_collision_hulls(mesh, cache_dir=tmp_path)
  assert len(calls) == 1
  for a, b, c in zip(first, second, l_shape_hulls, strict=True):
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, c)
    assert b.dtype == np.float64
  entries = os.listdir(tmp_path / 'hulls')
  assert entries == [collision_mod.hulls_cache_key(mesh) + '.npz']
  cached_collision_hulls(mesh, cache_dir=tmp_path, max_vertices=6)  # Other parameters: a new entry.
  assert len(calls) == 2 and len(os.listdir(tmp_path / 'hulls')) == 2
  path = tmp_path / 'hulls' / entries[0]
  path.write_bytes(b'not an npz file')
  with pytest.warns(RuntimeWarning, match='corrupt or unreadable'):
    rebuilt = cached_collision_hulls(mesh, cache_dir=tmp_path)
  assert len(calls) == 3 and len(rebuilt) == len(first)
  cached_collision_hulls(mesh, cache_dir=tmp_path)  # The rewritten entry is valid again.
  assert len(calls) == 3
