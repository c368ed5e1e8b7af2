"""Closed solids from imperfect meshes: inside and outside from generalized winding numbers.

Scanned objects, CAD exports and simulator asset libraries are often open (holes, missing caps, cracks along
seams), non-manifold (edges shared by more than two faces, duplicated walls) or inconsistently wound. A signed
distance taken from the nearest face's pseudonormal is meaningless on such a surface. Dex-Net computed its
distance fields from arbitrary meshes; `solidify` turns such a triangle soup into a closed, outward-oriented,
2-manifold solid that the rest of dexjax (signed distance grid, mass properties, collision hulls, rendering)
uses like any repaired mesh:

1. **orientation** (`orient_patches`): the faces of every edge-connected manifold patch are wound
   consistently; then each patch as a whole is turned outward by visibility (the idea of libigl's
   ``reorient_facets_raycast``): rays leave sample points of the patch into both half-spaces of its faces, and
   the side from which more rays escape the mesh is the outside. A patch that no ray leaves (an inner wall)
   is turned away from the mesh's centroid.
2. **inside / outside** (`winding_signed_distance`): the generalized winding number w(x) of the oriented
   soup (Jacobson, Kavan and Sorkine-Hornung 2013; libigl) is 1 inside a closed surface and 0 outside, and
   varies smoothly across holes: its 0.5 level closes them with a minimal-like surface. A point is inside
   where w > 0.5; the distance is the unsigned distance to the nearest triangle.
3. **surface** (`solidify`): marching cubes of that signed distance on a grid of ``resolution`` voxels along
   the longest extent (libigl), then quadric edge-collapse decimation (libigl's qslim) to at most
   ``max_faces`` faces when it keeps the surface closed. Inner walls, duplicated faces and fins outside the
   solid do not change the sign, so they leave no surface. Faces of the input are reproduced to within the
   marching-cubes interpolation error (exact for flat faces, sharp edges rounded by up to about half a voxel).

Everything is deterministic (fixed sample seeds; libigl is deterministic). The cost is one winding-number
and one distance query per grid point: about a second for a ~10k-face mesh at the default resolution on the
2-core development CPU; `dexjax.geometry.load_mesh` caches the result on disk by the soup's content.
"""

from __future__ import annotations

import itertools
import os
import warnings

import igl
import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import trimesh

from dexjax.geometry.content_cache import atomic_write_npz, content_key, default_cache_dir
from dexjax.geometry.mesh_topology import consistent_winding, face_adjacency

RESOLUTION: int = 128
"""Default voxels of the reconstruction grid along the mesh's longest extent."""

MAX_FACES: int = 20_000
"""Default face budget of a reconstructed surface (decimated beyond it)."""

MIN_SOLID_WINDING: float = 0.75
"""A soup whose generalized winding number stays below this everywhere encloses no volume (an open sheet: its
winding number is about +-0.5 on either side); `solidify` returns nothing for it. A bowl-like hemisphere shell
reaches ~0.85, a can without its lid ~0.97."""

# Visibility votes per patch: sample faces, rays per half-space and sample face.
_VOTE_FACES = 32
_VOTE_RAYS = 8
# Queries times faces above which the fast (Barnes-Hut) winding number replaces the exact sum.
_EXACT_WINDING_WORK = 2e8
# Grid padding of the reconstruction, voxels on each side.
_PADDING = 2


def orient_patches(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, int]:
  """Winds every edge-connected manifold patch consistently and turns each patch outward by visibility.

  Args:
    vertices: (V, 3) float64, metres.
    faces: (F, 3) int64 triangles of any winding; edges shared by more than two faces separate patches.

  Returns:
    faces: (F, 3) int64, re-wound.
    num_patches: number of patches.
  """
  faces = consistent_winding(np.asarray(faces, np.int64))
  pairs, _ = face_adjacency(faces)
  adjacency = scipy.sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                                      shape=(len(faces), len(faces)))
  num_patches, labels = scipy.sparse.csgraph.connected_components(adjacency, directed=False)
  mesh = trimesh.Trimesh(vertices, faces, process=False)
  normals = np.asarray(mesh.face_normals)  # zero for degenerate faces
  centroids = np.asarray(mesh.triangles_center)
  areas = np.asarray(mesh.area_faces)
  scale = float(np.max(mesh.extents)) or 1.0
  intersector = mesh.ray  # Embree (embreex) when installed, else trimesh's rtree-based tracer
  rng = np.random.default_rng(0)
  centre = np.average(centroids, axis=0, weights=np.maximum(areas, 1e-300))
  # Sample faces per patch: up to _VOTE_FACES of its faces with positive area, area-weighted (zero-area
  # slivers have no normal to vote with). All rays of all patches go to the ray tracer in one call.
  chosen, owner = [], []
  for patch, idx in enumerate(np.split(np.argsort(labels, kind='stable'),
                                       np.cumsum(np.bincount(labels, minlength=num_patches))[:-1])):
    sized = idx[areas[idx] > 0]
    if len(sized):
      weights = areas[sized] / areas[sized].sum()
      pick = rng.choice(sized, size=min(_VOTE_FACES, len(sized)), replace=False, p=weights)
      chosen.append(pick)
      owner.append(np.full(len(pick), patch))
  escapes = np.zeros((2, num_patches))
  if chosen:
    chosen, owner = np.concatenate(chosen), np.concatenate(owner)
    for row, side in enumerate((1.0, -1.0)):
      dirs = side * normals[chosen][:, None, :] + 0.9 * _unit_vectors(rng, (len(chosen), _VOTE_RAYS))
      dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
      origins = np.repeat(centroids[chosen], _VOTE_RAYS, axis=0) + 1e-6 * scale * dirs.reshape(-1, 3)
      escaped = ~intersector.intersects_any(origins, dirs.reshape(-1, 3))
      escapes[row] = np.bincount(np.repeat(owner, _VOTE_RAYS), weights=escaped, minlength=num_patches)
  # Enclosed (or undecided) patches: turned away from the centroid of the whole mesh.
  away = np.bincount(labels, weights=areas * np.einsum('ij,ij->i', normals, centroids - centre),
                     minlength=num_patches)
  flip = np.where(escapes[0] != escapes[1], escapes[1] > escapes[0], away < 0.0)
  faces = faces.copy()
  flipped = flip[labels]
  faces[flipped] = faces[flipped][:, ::-1]
  return faces, int(num_patches)


def winding_signed_distance(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
  """Signed distance (P,) float64 in metres of query points (P, 3) to an oriented soup (V, 3) / (F, 3):
  negative where the generalized winding number exceeds 0.5, magnitude = distance to the nearest triangle."""
  winding, distance = _winding_and_distance(vertices, faces, points)
  return distance * np.where(_inside(winding), -1.0, 1.0)


def solidify(vertices: np.ndarray, faces: np.ndarray, *, resolution: int = RESOLUTION,
             max_faces: int = MAX_FACES) -> tuple[np.ndarray, np.ndarray]:
  """A closed, outward-oriented 2-manifold surface around what the soup's winding number calls inside.

  Args:
    vertices: (V, 3) float64, metres.
    faces: (F, 3) int64 triangles (any winding; open, non-manifold and duplicated faces allowed).
    resolution: voxels of the reconstruction grid along the longest extent (>= 8).
    max_faces: decimate the result to at most this many faces (>= 100) when that keeps it closed.

  Returns:
    (vertices (V', 3) float64, faces (F', 3) int64) of the solid; empty arrays when nothing is inside (the
    winding number stays below `MIN_SOLID_WINDING`).

  Raises:
    ValueError: ``resolution`` or ``max_faces`` out of range.
  """
  if resolution < 8 or max_faces < 100:
    raise ValueError(f'solidify: expected resolution >= 8 and max_faces >= 100, got {resolution}, {max_faces}')
  vertices = np.asarray(vertices, np.float64)
  faces, _ = orient_patches(vertices, faces)
  used = vertices[np.unique(faces)]
  lo, hi = used.min(axis=0), used.max(axis=0)
  voxel = float(np.max(hi - lo)) / resolution
  counts = np.ceil((hi - lo) / voxel).astype(int) + 1 + 2 * _PADDING
  counts += 1 - counts % 2  # odd: the coarse grid (every other point) ends on the fine grid's last point
  centre = 0.5 * (lo + hi)
  axes = [centre[i] + voxel * (np.arange(counts[i]) - 0.5 * (counts[i] - 1)) for i in range(3)]
  fine = np.stack(np.meshgrid(*axes, indexing='ij'), axis=-1)
  signed, max_winding = _signed_grid(vertices, faces, fine, voxel)
  # libigl's marching cubes takes the grid with x varying fastest.
  grid = fine.transpose(2, 1, 0, 3).reshape(-1, 3)
  signed = signed.transpose(2, 1, 0).reshape(-1)
  if max_winding < MIN_SOLID_WINDING or not (signed < 0).any():
    return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
  out_v, out_f, _ = igl.marching_cubes(signed, grid, int(counts[0]), int(counts[1]), int(counts[2]), 0.0)
  out_v, out_f = _drop_specks(np.asarray(out_v, np.float64), np.asarray(out_f, np.int64), voxel)
  if len(out_f) > max_faces:
    out_v, out_f = _decimate(out_v, out_f, max_faces)
  return out_v, out_f


SOLID_CACHE_SUBDIR: str = 'solids'
"""Sub-directory of the object cache directory (``$DEXJAX_CACHE``) holding `cached_solidify` results."""

SOLID_CACHE_FORMAT_VERSION: int = 1
"""Bump when `solidify` changes; old cache entries are then ignored."""


def cached_solidify(vertices: np.ndarray, faces: np.ndarray, *, cache_dir: str | None = None,
                    resolution: int = RESOLUTION, max_faces: int = MAX_FACES) -> tuple[np.ndarray, np.ndarray]:
  """`solidify`, read from ``<cache_dir>/solids/<key>.npz`` when there (key: the soup's content, the
  parameters and `SOLID_CACHE_FORMAT_VERSION`); written atomically after computing. An unreadable entry is
  recomputed; an unwritable cache directory only costs the recomputation next time."""
  vertices = np.asarray(vertices, np.float64)
  faces = np.asarray(faces, np.int64)
  header = {'kind': 'solid', 'version': SOLID_CACHE_FORMAT_VERSION, 'resolution': int(resolution),
            'max_faces': int(max_faces)}
  key = content_key(header, vertices, faces)
  path = os.path.join(cache_dir or default_cache_dir(), SOLID_CACHE_SUBDIR, f'{key}.npz')
  try:
    with np.load(path) as stored:
      if str(stored['key']) == key:
        return np.asarray(stored['vertices'], np.float64), np.asarray(stored['faces'], np.int64)
  except (OSError, KeyError, ValueError, EOFError):
    pass  # Missing or unreadable: compute.
  out = solidify(vertices, faces, resolution=resolution, max_faces=max_faces)
  try:
    os.makedirs(os.path.dirname(path), exist_ok=True)
    atomic_write_npz(path, {'key': np.asarray(key), 'vertices': out[0], 'faces': out[1]})
  except OSError as e:
    warnings.warn(f"solid cache '{path}' could not be written ({e}); the solid is recomputed next time",
                  RuntimeWarning, stacklevel=2)
  return out


def _signed_grid(vertices: np.ndarray, faces: np.ndarray, fine: np.ndarray,
                 voxel: float) -> tuple[np.ndarray, float]:
  """(nx, ny, nz) winding-number signed distance at the grid points ``fine`` (nx, ny, nz, 3), odd sizes, exact only
  near the surface, and the largest winding number on the grid half a voxel or more away from the soup.

  The winding number and the distance are evaluated on the coarse grid of every other point. A coarse cell
  whose eight corners are all farther than its diagonal from every triangle contains no surface, and there
  the winding number is smooth (harmonic): its fine points take the trilinear interpolation of the corners'
  winding numbers and, as distance, the smallest corner distance minus half the diagonal (a lower bound; only
  its sign matters to marching cubes away from the surface). All other fine points are evaluated exactly.
  """
  coarse = fine[::2, ::2, ::2]
  shape_c = coarse.shape[:3]
  winding_c, distance_c = _winding_and_distance(vertices, faces, coarse.reshape(-1, 3))
  winding_c, distance_c = winding_c.reshape(shape_c), distance_c.reshape(shape_c)
  diagonal = 2.0 * np.sqrt(3.0) * voxel
  # Per coarse cell: the smallest corner distance.
  corner_min = distance_c[:-1, :-1, :-1]
  for dx, dy, dz in ((1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1), (1, 1, 1)):
    corner_min = np.minimum(corner_min, distance_c[dx:dx + shape_c[0] - 1, dy:dy + shape_c[1] - 1,
                                                   dz:dz + shape_c[2] - 1])
  n = fine.shape[:3]
  index = [np.minimum(np.arange(k) // 2, (k - 1) // 2 - 1) for k in n]  # coarse cell of each fine point
  frac = [np.arange(k) / 2.0 - i for k, i in zip(n, index)]  # in [0, 1]
  ci, cj, ck = np.meshgrid(*index, indexing='ij')
  far = corner_min[ci, cj, ck] > diagonal
  fx, fy, fz = np.meshgrid(*frac, indexing='ij')
  winding = np.zeros(n)
  for dx, dy, dz in itertools.product((0, 1), repeat=3):
    weight = (fx if dx else 1 - fx) * (fy if dy else 1 - fy) * (fz if dz else 1 - fz)
    winding += weight * winding_c[ci + dx, cj + dy, ck + dz]
  distance = corner_min[ci, cj, ck] - 0.5 * diagonal
  near = ~far
  winding[near], distance[near] = _winding_and_distance(vertices, faces, fine[near])
  off_surface = distance > 0.5 * voxel  # on a triangle the winding number is undefined (0 or 1 numerically)
  max_winding = float(winding[off_surface].max()) if off_surface.any() else 0.0
  return distance * np.where(_inside(winding), -1.0, 1.0), max_winding


def _inside(winding: np.ndarray) -> np.ndarray:
  """Winding number > 0.5, rounded to 1e-9 first: points in the plane of a planar hole have exactly 0.5 up to
  summation-order noise (~1e-13, it varies between runs with threads), and must not flip between runs."""
  return np.round(winding, 9) > 0.5


def _winding_and_distance(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
  """Generalized winding number (P,) and unsigned distance (P,) in metres of points (P, 3) to a soup."""
  vertices = np.ascontiguousarray(vertices, np.float64)
  faces = np.ascontiguousarray(faces, np.int64)
  points = np.ascontiguousarray(points, np.float64)
  if len(points) == 0:
    return np.zeros(0), np.zeros(0)
  if len(points) * len(faces) <= _EXACT_WINDING_WORK:
    winding = igl.winding_number(vertices, faces, points)
  else:
    winding = igl.fast_winding_number(vertices, faces, points)
  squared, *_ = igl.point_mesh_squared_distance(points, vertices, faces)
  return np.asarray(winding, np.float64), np.sqrt(np.maximum(np.asarray(squared, np.float64), 0.0))


def _unit_vectors(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
  """Uniform random unit vectors of shape ``shape + (3,)``."""
  v = rng.normal(size=shape + (3,))
  return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _drop_specks(vertices: np.ndarray, faces: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
  """Removes closed components enclosing less than two voxels (noise of the winding number's 0.5 level)."""
  mesh = trimesh.Trimesh(vertices, faces, process=False)
  parts = mesh.split(only_watertight=False)
  if len(parts) <= 1:
    return vertices, faces
  keep = [p for p in parts if abs(p.volume) >= 2.0 * voxel**3]
  if not keep or len(keep) == len(parts):
    return vertices, faces
  merged = trimesh.util.concatenate(keep)
  return np.asarray(merged.vertices, np.float64), np.asarray(merged.faces, np.int64)


def _decimate(vertices: np.ndarray, faces: np.ndarray, max_faces: int) -> tuple[np.ndarray, np.ndarray]:
  """Quadric edge-collapse decimation to ``max_faces``; the input when the result would not be closed."""
  ok_v, ok_f, *_ = igl.qslim(np.asfortranarray(vertices), np.asfortranarray(faces, dtype=np.int32), max_faces)
  ok_v, ok_f = np.asarray(ok_v, np.float64), np.asarray(ok_f, np.int64)
  if len(ok_f) == 0 or not trimesh.Trimesh(ok_v, ok_f, process=False).is_watertight:
    return vertices, faces
  return ok_v, ok_f


__all__ = ['MAX_FACES', 'MIN_SOLID_WINDING', 'RESOLUTION', 'SOLID_CACHE_FORMAT_VERSION', 'SOLID_CACHE_SUBDIR', 'cached_solidify',
           'orient_patches', 'solidify', 'winding_signed_distance']
