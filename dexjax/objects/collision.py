"""Collision geometry for physics: a few convex hulls per object (a convex decomposition).

MuJoCo collides meshes through their convex hulls, so a concave object (an L, a mug) is given as several
convex pieces. `collision_hulls` returns each piece as a vertex array; MuJoCo takes the hull of each.

* **Convex objects** (solidity = volume / convex-hull volume >= ``convex_solidity``, default 0.97) skip
  the decomposition and get their own convex hull: boxes, cylinders, spheres, and near-convex shapes such
  as ``builtin:box_with_hole`` (solidity 0.976, so its 12 mm bore is closed for collision).
* **Concave objects** are decomposed with V-HACD 4 (the ``vhacdx`` bindings, through
  `trimesh.decomposition.convex_decomposition`) at a voxel resolution of 100,000: on the 2-core
  development CPU about 0.35 s for ``builtin:l_shape`` (4 hulls, union volume within 0.2 % of the mesh)
  and 2–4 s for a 1,300-face mug (8 hulls). CoACD gave similar hulls at equal hull counts but took 0.4 s /
  10 s, and one setting took 143 s on a 528-face box with a bore, so V-HACD is used. With 8 hulls a deep
  cavity (a mug's inside) is partly filled: the union of the hulls over-covers such a mug by ~65 % of its
  volume (16 hulls: ~30 %); raise ``max_hulls`` for hollow objects.

The output is deterministic (V-HACD and qhull are; vertex capping uses no randomness). Hulls are cached on
disk by `cached_collision_hulls`, keyed by mesh content, parameters and the vhacdx version, under
``<cache_dir>/hulls/`` (the object-model cache directory, ``$DEXJAX_CACHE``).
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import os
import warnings

import numpy as np
import trimesh
import trimesh.decomposition

from dexjax.geometry.cache import atomic_write_npz, default_cache_dir, mesh_content_key

HULL_CACHE_FORMAT_VERSION: int = 1
"""Bump when the hull computation changes; old cache entries are then ignored."""

CONVEX_SOLIDITY: float = 0.97
"""Meshes whose volume is at least this fraction of their convex hull's volume are treated as convex."""

HULL_CACHE_SUBDIR: str = 'hulls'
"""Sub-directory of the object cache directory that holds cached collision hulls."""

@dataclasses.dataclass(frozen=True)
class HullSettings:
  """The parameters of `collision_hulls` / `cached_collision_hulls` as one value (defaults: theirs; the datasets'
  heaps use them). A finer decomposition follows cavities more closely at the cost of more geoms to collide.

  Attributes:
    max_hulls: maximum number of convex pieces.
    max_vertices: maximum vertices per piece.
    resolution: V-HACD voxel count.
    convex_solidity: objects at least this solid skip the decomposition (their own hull).
  """

  max_hulls: int = 8
  max_vertices: int = 64
  resolution: int = 100_000
  convex_solidity: float = CONVEX_SOLIDITY

  def kwargs(self) -> dict:
    """The settings as keyword arguments of `collision_hulls` / `cached_collision_hulls`."""
    return dataclasses.asdict(self)


# Hulls with less volume than this fraction of the mesh's hull volume (slivers) are dropped.
_MIN_HULL_VOLUME_FRACTION = 1e-6


def collision_hulls(
    mesh: trimesh.Trimesh,
    *,
    max_hulls: int = 8,
    max_vertices: int = 64,
    resolution: int = 100_000,
    convex_solidity: float = CONVEX_SOLIDITY,
) -> tuple[np.ndarray, ...]:
  """Convex decomposition of a closed mesh into at most ``max_hulls`` convex pieces.

  Each piece is the vertex set of a convex hull: every returned point is a hull vertex (no interior
  points), at least 4 points not in one plane.

  Vertex cap: a hull with more than ``max_vertices`` vertices keeps the ``max_vertices`` chosen by
  farthest-point sampling over its vertices (started at the vertex farthest from their centroid; no
  randomness). The kept points are extreme points of the original hull, so the capped hull lies inside it
  and only loses volume: nothing when the hull already has at most ``max_vertices`` vertices (boxes, the
  pieces of polyhedral shapes), 0.6 % for a 128-sided cylinder at 64 vertices (2.5 % at 32, 10 % at 16),
  9 % for a finely tessellated sphere at 64 vertices (19 % at 32, 34 % at 16). V-HACD also limits its
  own hulls to ``max_vertices``, so decomposed pieces rarely need capping.

  Args:
    mesh: closed, outward-oriented triangle mesh in metres (e.g. from `dexjax.geometry.load_mesh`).
    max_hulls: maximum number of convex pieces (>= 1); 1 gives the mesh's (capped) convex hull.
    max_vertices: maximum vertices per piece (>= 4).
    resolution: V-HACD voxel count (>= 10,000); higher follows concave detail more closely, slower.
    convex_solidity: meshes with volume / hull volume at least this (in (0, 1]) skip the decomposition.

  Returns:
    A tuple of 1..max_hulls arrays, the i-th of shape (V_i, 3) float64, metres, 4 <= V_i <= max_vertices.

  Raises:
    ValueError: a parameter is out of range, or the mesh has no volume.
  """
  _check_params(max_hulls, max_vertices, resolution, convex_solidity)
  hull = mesh.convex_hull
  if not (np.isfinite(hull.volume) and hull.volume > 0):
    raise ValueError(f'collision_hulls: mesh: expected a solid with positive volume, got hull volume '
                     f'{hull.volume!r} m^3')
  solidity = float(mesh.volume) / float(hull.volume)
  if max_hulls == 1 or solidity >= convex_solidity:
    pieces = [np.asarray(hull.vertices, np.float64)]
  else:
    parts = trimesh.decomposition.convex_decomposition(
        mesh, maxConvexHulls=int(max_hulls), maxNumVerticesPerCH=int(max_vertices),
        resolution=int(resolution))
    pieces = [np.asarray(p['vertices'], np.float64) for p in parts]
  min_volume = _MIN_HULL_VOLUME_FRACTION * float(hull.volume)
  hulls = []
  for points in pieces:
    points = _hull_vertices(points)
    if points is None:
      continue
    points = _cap_vertices(points, max_vertices)
    if _hull_volume(points) > min_volume:
      hulls.append(points)
  if not hulls:  # Decomposition produced only slivers: fall back to the object's own hull.
    hulls = [_cap_vertices(np.asarray(hull.vertices, np.float64), max_vertices)]
  hulls = _merge_to(hulls, max_hulls, max_vertices)
  return tuple(hulls)


def hulls_cache_key(
    mesh: trimesh.Trimesh,
    *,
    max_hulls: int = 8,
    max_vertices: int = 64,
    resolution: int = 100_000,
    convex_solidity: float = CONVEX_SOLIDITY,
) -> str:
  """Hex SHA-256 identifying the hulls `collision_hulls(mesh, ...)` returns with these parameters."""
  header = {
      'kind': 'collision_hulls',
      'format': HULL_CACHE_FORMAT_VERSION,
      'vhacdx': _library_version('vhacdx'),
      'params': {'max_hulls': int(max_hulls), 'max_vertices': int(max_vertices),
                 'resolution': int(resolution), 'convex_solidity': float(convex_solidity)},
  }
  return mesh_content_key(header, mesh)


def cached_collision_hulls(
    mesh: trimesh.Trimesh,
    *,
    cache_dir: str | os.PathLike[str] | None = None,
    max_hulls: int = 8,
    max_vertices: int = 64,
    resolution: int = 100_000,
    convex_solidity: float = CONVEX_SOLIDITY,
) -> tuple[np.ndarray, ...]:
  """`collision_hulls(mesh, ...)`, read from ``<cache_dir>/hulls/<key>.npz`` when present.

  A missing entry is computed and written atomically; an unreadable or inconsistent entry is reported with
  a `RuntimeWarning` and recomputed; an unwritable directory only warns.

  Args:
    mesh: closed triangle mesh in metres.
    cache_dir: object cache directory; `dexjax.geometry.default_cache_dir()` when None.
    max_hulls, max_vertices, resolution, convex_solidity: see `collision_hulls`.

  Returns:
    The hulls, as `collision_hulls` returns them: a tuple of (V_i, 3) float64 arrays, metres.
  """
  _check_params(max_hulls, max_vertices, resolution, convex_solidity)
  params = dict(max_hulls=max_hulls, max_vertices=max_vertices, resolution=resolution,
                convex_solidity=convex_solidity)
  key = hulls_cache_key(mesh, **params)
  directory = os.fspath(cache_dir) if cache_dir is not None else default_cache_dir()
  path = os.path.join(directory, HULL_CACHE_SUBDIR, f'{key}.npz')
  if os.path.exists(path):
    try:
      return _read_hulls(path, key, max_hulls, max_vertices)
    except Exception as e:  # Any unreadable entry is recomputed; never crash on a bad cache file.
      warnings.warn(f"dexjax hull cache: '{path}' is corrupt or unreadable ({type(e).__name__}: {e}); "
                    'recomputing it', RuntimeWarning, stacklevel=2)
  hulls = collision_hulls(mesh, **params)
  counts = np.array([len(h) for h in hulls], np.int64)
  try:
    atomic_write_npz(path, {'cache_key': np.array(key), 'vertices': np.concatenate(hulls), 'counts': counts})
  except OSError as e:
    warnings.warn(f"dexjax hull cache: could not write '{path}' ({e}); continuing without caching",
                  RuntimeWarning, stacklevel=2)
  return hulls


def _check_params(max_hulls: int, max_vertices: int, resolution: int, convex_solidity: float) -> None:
  """Raises ValueError naming the parameter and its expected range."""
  if not (isinstance(max_hulls, (int, np.integer)) and max_hulls >= 1):
    raise ValueError(f'collision_hulls: max_hulls: expected an integer >= 1, got {max_hulls!r}')
  if not (isinstance(max_vertices, (int, np.integer)) and max_vertices >= 4):
    raise ValueError(f'collision_hulls: max_vertices: expected an integer >= 4, got {max_vertices!r}')
  if not (isinstance(resolution, (int, np.integer)) and resolution >= 10_000):
    raise ValueError(f'collision_hulls: resolution: expected an integer >= 10000, got {resolution!r}')
  if not (isinstance(convex_solidity, (int, float)) and 0.0 < convex_solidity <= 1.0):
    raise ValueError(
        f'collision_hulls: convex_solidity: expected a number in (0, 1], got {convex_solidity!r}')


def _library_version(name: str) -> str:
  try:
    return importlib.metadata.version(name)
  except importlib.metadata.PackageNotFoundError:
    return 'unknown'


def _hull_vertices(points: np.ndarray) -> np.ndarray | None:
  """The (H, 3) float64 vertices of the convex hull of (P, 3) points; None if the points are flat."""
  if len(points) < 4:
    return None
  try:
    hull = trimesh.convex.convex_hull(points)
  except Exception:  # qhull refuses coplanar / collinear input.
    return None
  vertices = np.asarray(hull.vertices, np.float64)
  return vertices if len(vertices) >= 4 else None


def _hull_volume(points: np.ndarray) -> float:
  """Volume (m^3) of the convex hull of (P, 3) points; 0 when they are flat."""
  try:
    return float(trimesh.convex.convex_hull(points).volume)
  except Exception:
    return 0.0


def _cap_vertices(points: np.ndarray, max_vertices: int) -> np.ndarray:
  """At most ``max_vertices`` of (P, 3) points by farthest-point sampling, in their original order."""
  if len(points) <= max_vertices:
    return points
  first = int(np.argmax(np.linalg.norm(points - points.mean(axis=0), axis=1)))
  chosen = [first]
  distance = np.linalg.norm(points - points[first], axis=1)
  for _ in range(max_vertices - 1):
    nxt = int(np.argmax(distance))
    chosen.append(nxt)
    distance = np.minimum(distance, np.linalg.norm(points - points[nxt], axis=1))
  return points[np.sort(chosen)]


def _merge_to(hulls: list[np.ndarray], max_hulls: int, max_vertices: int) -> list[np.ndarray]:
  """Greedily merges the pair of hulls whose joint hull adds the least volume until <= max_hulls remain.

  V-HACD already respects its hull limit; this only guards the contract.
  """
  hulls = list(hulls)
  volumes = [_hull_volume(h) for h in hulls]
  while len(hulls) > max_hulls:
    best = None
    for i in range(len(hulls)):
      for j in range(i + 1, len(hulls)):
        added = _hull_volume(np.concatenate([hulls[i], hulls[j]])) - volumes[i] - volumes[j]
        if best is None or added < best[0]:
          best = (added, i, j)
    _, i, j = best
    joint = np.concatenate([hulls[i], hulls[j]])
    vertices = _hull_vertices(joint)
    merged = _cap_vertices(joint if vertices is None else vertices, max_vertices)
    hulls[i], volumes[i] = merged, _hull_volume(merged)
    del hulls[j], volumes[j]
  return hulls


def _read_hulls(path: str, key: str, max_hulls: int, max_vertices: int) -> tuple[np.ndarray, ...]:
  """Loads and checks one hull cache file; raises ValueError if it is not a valid entry for ``key``."""
  with np.load(path, allow_pickle=False) as data:
    stored_key = str(data['cache_key']) if 'cache_key' in data.files else None
    if stored_key != key:
      raise ValueError(f'stored key {stored_key!r} does not match the file name')
    vertices, counts = np.array(data['vertices']), np.array(data['counts'])
  if vertices.ndim != 2 or vertices.shape[1] != 3 or vertices.dtype != np.float64:
    raise ValueError(f"field 'vertices' has shape {vertices.shape} {vertices.dtype}; expected (N, 3) float64")
  if not np.isfinite(vertices).all():
    raise ValueError("field 'vertices' contains NaN or inf")
  if counts.ndim != 1 or not 1 <= len(counts) <= max_hulls or counts.sum() != len(vertices) or (
      counts < 4).any() or (counts > max_vertices).any():
    raise ValueError(f"field 'counts' {counts.tolist()} is inconsistent with {len(vertices)} vertices, "
                     f'max_hulls={max_hulls} and max_vertices={max_vertices}')
  return tuple(np.split(vertices, np.cumsum(counts)[:-1]))
