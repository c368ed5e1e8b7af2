"""Mesh loading, validation and repair for building signed distance grids.

A *signed* distance grid (see `dexjax.geometry.object_model`) needs a closed, consistently oriented surface:
the sign at a query point comes from the angle-weighted pseudonormal of the nearest feature, which flips
wherever the winding or the closure is broken. This module turns whatever a file contains into such a solid,
or refuses it with a `MeshError` that names the file and the problem when it is unusable.

Repair steps (`validate_and_repair`), in order:

1. reject empty meshes, NaN / inf coordinates and flat meshes (all vertices in one plane);
2. merge coincident vertices (trimesh's default 1e-8 tolerance), drop collapsed faces (a vertex index
   repeated) and duplicate faces, drop unreferenced vertices;
3. orient the faces of every connected patch consistently (breadth-first traversal over shared edges);
4. close small holes (boundary loops of at most `MAX_HOLE_EDGES` edges) with a fan of triangles;
5. orient every closed component outward (a component nested inside an odd number of others is a cavity
   and is oriented inward); components that overlap or touch are merged with a boolean union (manifold3d),
   since overlapping shells give wrong signed distances;
6. **imperfect meshes** -- non-manifold edges (shared by more than two faces), holes still open after step 4,
   a surface that cannot be oriented, or overlapping parts that also enclose cavities -- are not rejected:
   they become the closed solid their generalized winding number encloses (`dexjax.geometry.winding`:
   patches turned outward by visibility, inside where the winding number exceeds 0.5, the surface rebuilt
   by marching cubes at 1/128 of the largest extent and decimated to at most 20,000 faces; cached on disk),
   with an `ImperfectMeshWarning` naming the file and what was wrong;
7. reject zero-volume results (including soups whose winding number encloses nothing, e.g. an open sheet).

Faces with zero area but three distinct vertices (slivers) are kept: removing one opens a slit in an
otherwise closed surface. Self-intersections within one closed component are not detected.

The repair code uses numpy / scipy / libigl only (no networkx), so it behaves the same whether or not
trimesh's optional graph dependencies are installed.
"""

from __future__ import annotations

import os
import re
import warnings

import igl
import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import trimesh

from dexjax.geometry.mesh_topology import (consistent_winding, directed_edges, face_adjacency, is_winding_consistent,
                                           undirected_edge_counts)
from dexjax.geometry.winding import cached_solidify

SUPPORTED_EXTENSIONS: tuple[str, ...] = ('.obj', '.stl', '.ply', '.glb', '.off')
"""File extensions `load_mesh` accepts (case-insensitive)."""

MAX_HOLE_EDGES: int = 8
"""Boundary loops with at most this many edges are closed by `validate_and_repair`; larger ones are errors."""

PLAUSIBLE_EXTENT: tuple[float, float] = (0.005, 1.0)
"""Largest extent (metres, after ``scale``) of a graspable object; `load_mesh` warns (`ScaleWarning`) outside it."""

# A mesh is "flat" when the smallest principal extent of its vertices is below this fraction of the largest.
_FLAT_RELATIVE_TOL = 1e-7
# A closed mesh is degenerate when |volume| is below this fraction of (largest extent)^3.
_VOLUME_RELATIVE_TOL = 1e-9
# Nested-component test: at most this many vertices of a component are tested against the others.
_NESTING_SAMPLES = 64


class ScaleWarning(UserWarning):
  """A mesh file's size in metres is implausible for a graspable object (most likely a unit mistake)."""


class ImperfectMeshWarning(UserWarning):
  """A mesh is open, non-manifold or cannot be oriented: it was loaded as the solid its generalized winding
  number encloses (`dexjax.geometry.winding`), not rejected. The message names the file and what was wrong."""


class _Overlap(Exception):
  """Closed components overlap and enclose cavities: no boolean union applies; the soup path takes over."""


class MeshError(ValueError):
  """A mesh file or mesh cannot be turned into a closed solid.

  Attributes:
    file: the file name (or a display name such as ``'builtin:cube'`` / ``'<mesh>'``) of the offending mesh.
    reason: what is wrong, in words (no file name).
  """

  def __init__(self, file: str | os.PathLike[str], reason: str):
    self.file = os.fspath(file)
    self.reason = reason
    super().__init__(f"mesh '{self.file}': {reason}")

  def __reduce__(self):
    return (type(self), (self.file, self.reason))


def load_mesh(path: str | os.PathLike[str], *, scale: float = 1.0) -> trimesh.Trimesh:
  """Reads a mesh file, scales it to metres and returns a repaired, closed, outward-oriented copy.

  Scenes (GLB, multi-object OBJ) are flattened into one mesh with their node transforms applied.

  Args:
    path: an ``.obj``, ``.stl``, ``.ply``, ``.glb`` or ``.off`` file.
    scale: factor applied to the vertex coordinates, e.g. 0.001 for a file in millimetres.

  Returns:
    A `trimesh.Trimesh` in metres that is watertight, consistently wound and has positive volume.

  Raises:
    MeshError: the extension is unsupported, the file is missing, empty, unreadable or (OBJ, OFF) not text, or
      the mesh is unusable (see `validate_and_repair`).
    ValueError: ``scale`` is not a finite positive number.

  Warns:
    ImperfectMeshWarning: the mesh was open or non-manifold and was loaded as the solid its generalized
      winding number encloses (see `validate_and_repair`).
    ScaleWarning: the largest extent after scaling is outside `PLAUSIBLE_EXTENT` (5 mm - 1 m), with the
      ``--scale`` that would fix the likely unit mistake (e.g. 0.001 for a file in millimetres).
  """
  file = os.fspath(path)
  ext = os.path.splitext(file)[1].lower()
  supported = ', '.join(SUPPORTED_EXTENSIONS)
  if ext not in SUPPORTED_EXTENSIONS:
    shown = f"'{ext}'" if ext else '(none)'
    raise MeshError(file, f'unsupported file extension {shown}; supported extensions are {supported}')
  if not (np.isfinite(scale) and scale > 0):
    raise ValueError(f"load_mesh('{file}'): scale must be a finite positive number, got {scale!r}")
  if not os.path.isfile(file):
    raise MeshError(file, 'file not found')
  if os.path.getsize(file) == 0:
    raise MeshError(file, 'empty file (0 bytes); expected a triangle mesh')
  if ext in TEXT_FORMATS:
    _check_text(file, ext)
  try:
    scene = trimesh.load_scene(file, file_type=ext[1:], process=False)
  except Exception as e:  # trimesh raises many exception types for malformed files.
    raise MeshError(file, f'could not be read as {ext[1:].upper()} ({type(e).__name__}: {e})') from e
  meshes = [g for g in scene.geometry.values() if isinstance(g, trimesh.Trimesh) and len(g.faces) > 0]
  if not meshes:
    raise MeshError(file, 'contains no triangle faces; expected a triangle mesh')
  try:
    mesh = scene.to_mesh()  # Applies the scene graph's node transforms.
  except Exception as e:
    raise MeshError(file, f'could not flatten the scene into one mesh ({type(e).__name__}: {e})') from e
  mesh = trimesh.Trimesh(
      vertices=np.asarray(mesh.vertices, np.float64) * float(scale),
      faces=np.asarray(mesh.faces, np.int64),
      process=False,
  )
  mesh = validate_and_repair(mesh, file)
  check_scale(mesh, file, scale)
  return mesh


TEXT_FORMATS: dict[str, str] = {'.obj': "a Wavefront OBJ, which is text ('v' and 'f' lines)",
                                 '.off': "an OFF file, which is text ('OFF', then vertex and face lines)"}
"""Mesh formats that are always text, and what such a file holds: `load_mesh` refuses binary data in them."""

# Control characters (but tab, line and page breaks and the old end-of-file mark Ctrl-Z) never occur in text.
_BINARY_BYTE = re.compile(rb'[\x00-\x08\x0e-\x19\x1b-\x1f\x7f]')


def _check_text(file: str, ext: str) -> None:
  """`MeshError` if the first 64 kB of a text-format file hold binary data (which its parser reports as no faces)."""
  with open(file, 'rb') as f:
    found = _BINARY_BYTE.search(f.read(1 << 16))
  if found:
    raise MeshError(file, f'not a text {ext[1:].upper()} file (byte {found.start()} is 0x{found.group()[0]:02x}: '
                          f'binary data); expected {TEXT_FORMATS[ext]}')


def check_scale(mesh: trimesh.Trimesh, name: str, scale: float = 1.0) -> float:
  """Warns (`ScaleWarning`) when the mesh's largest extent (metres) is outside `PLAUSIBLE_EXTENT`; returns it.

  The message names the mesh, its extent and the ``--scale`` that brings it into range (0.001 for millimetres,
  0.01 for centimetres, 0.0254 for inches; or the power of ten that undoes a wrong ``--scale``).
  """
  extent = float(np.max(mesh.extents))
  low, high = PLAUSIBLE_EXTENT
  if low <= extent <= high:
    return extent
  original = extent / scale
  hints = []
  for factor, unit in ((0.001, 'millimetres'), (0.01, 'centimetres'), (0.0254, 'inches'), (1.0, 'metres')):
    if factor != scale and low <= original * factor <= high:
      hints.append(f'--scale {factor:g} if the file is in {unit}')
  hint = '; '.join(hints[:2]) if hints else f'a --scale that brings it to {low * 1000:g} mm - {high:g} m'
  size = f'{extent:.3g} m' if extent >= 0.01 else f'{extent * 1000:.3g} mm'
  warnings.warn(ScaleWarning(
      f"mesh '{name}': largest extent {size} (with --scale {scale:g}) is implausible for a graspable object "
      f"(expected {low * 1000:g} mm to {high:g} m); use {hint}"), stacklevel=3)
  return extent


def validate_and_repair(mesh: trimesh.Trimesh, name: str = '<mesh>') -> trimesh.Trimesh:
  """Validates a triangle mesh and returns a repaired copy that is a closed, outward-oriented solid.

  See the module docstring for the repair steps. Visual attributes (colours, UVs) are dropped.

  Args:
    mesh: the input mesh (not modified), vertices in metres.
    name: file or display name used in error messages and warnings.

  Returns:
    A new `trimesh.Trimesh`: watertight, consistently wound, positive volume.

  Raises:
    MeshError: the mesh is unusable: empty, NaN / inf coordinates, out-of-range face indices, flat, or
      without enclosed volume.

  Warns:
    ImperfectMeshWarning: the mesh was open, non-manifold, non-orientable or overlapping with cavities and was
      rebuilt as the solid its generalized winding number encloses.
  """
  if not isinstance(mesh, trimesh.Trimesh):
    raise TypeError(f"validate_and_repair('{name}'): expected a trimesh.Trimesh, got {type(mesh).__name__}")
  vertices = np.array(mesh.vertices, dtype=np.float64).reshape(-1, 3)
  faces = np.asarray(mesh.faces)
  if len(vertices) == 0 or faces.size == 0:
    raise MeshError(name, 'mesh has no faces (empty); expected a triangle mesh')
  if faces.ndim != 2 or faces.shape[1] != 3:
    raise MeshError(name, f'faces have shape {faces.shape}; expected (F, 3) triangles')
  faces = faces.astype(np.int64)
  if faces.min() < 0 or faces.max() >= len(vertices):
    raise MeshError(name, f'face indices out of range [0, {len(vertices)}); the file is corrupt')
  bad = ~np.isfinite(vertices).all(axis=1)
  if bad.any():
    raise MeshError(name, f'{int(bad.sum())} vertices have NaN or infinite coordinates')
  _check_not_flat(vertices[np.unique(faces)], name)

  out = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
  out.merge_vertices(merge_tex=True, merge_norm=True)
  faces = np.asarray(out.faces, np.int64)
  collapsed = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 2] == faces[:, 0])
  faces = faces[~collapsed]
  if len(faces) == 0:
    raise MeshError(name, 'every face is degenerate after merging coincident vertices')
  _, first = np.unique(np.sort(faces, axis=1), axis=0, return_index=True)
  faces = faces[np.sort(first)]
  vertices = np.asarray(out.vertices, np.float64)

  non_manifold = int((undirected_edge_counts(faces) > 2).sum())
  imperfection = None
  if non_manifold:
    imperfection = f'{non_manifold} non-manifold edges (shared by more than two faces)'
  else:
    faces = consistent_winding(faces)
    vertices, faces = _fill_small_holes(vertices, faces)
    open_edges = int((undirected_edge_counts(faces) == 1).sum())
    if open_edges:
      imperfection = f'not watertight after repair ({open_edges} open edges)'
    elif not is_winding_consistent(faces):
      imperfection = 'faces cannot be oriented consistently (non-orientable surface)'
  if imperfection is None:
    try:
      vertices, faces = _orient_components(vertices, faces, name)
    except _Overlap as e:
      imperfection = str(e)
  if imperfection is not None:
    vertices, faces = _solid_from_soup(vertices, faces, name, imperfection)
  out = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
  out.remove_unreferenced_vertices()
  extent = float(np.max(out.extents))
  if not out.volume > _VOLUME_RELATIVE_TOL * extent**3:
    raise MeshError(name, f'degenerate mesh: enclosed volume {out.volume:.3g} m^3 is zero or negative')
  return out


def _solid_from_soup(vertices: np.ndarray, faces: np.ndarray, name: str,
                     imperfection: str) -> tuple[np.ndarray, np.ndarray]:
  """The closed solid an imperfect soup's winding number encloses (cached), with an `ImperfectMeshWarning`.

  Raises:
    MeshError: nothing is inside (an open sheet, a single patch without volume).
  """
  solid_vertices, solid_faces = cached_solidify(vertices, faces)
  if len(solid_faces) == 0:
    raise MeshError(name, f'{imperfection}, and no volume is inside it (its generalized winding number stays '
                          'below 0.75 everywhere: an open sheet?); expected a solid')
  warnings.warn(ImperfectMeshWarning(
      f"mesh '{name}': {imperfection}; loaded as the solid its generalized winding number encloses "
      '(surface rebuilt)'), stacklevel=4)
  return solid_vertices, solid_faces


def _check_not_flat(points: np.ndarray, name: str) -> None:
  """Raises MeshError if (P, 3) points lie in a plane, a line or a point (zero-volume bounding shape)."""
  centred = points - points.mean(axis=0)
  singular = np.linalg.svd(centred, compute_uv=False) if len(points) >= 3 else np.zeros(3)
  singular = np.pad(singular, (0, 3 - len(singular)))
  if singular[0] == 0 or singular[2] <= _FLAT_RELATIVE_TOL * singular[0]:
    raise MeshError(name, 'degenerate mesh: zero volume (all vertices lie in one plane); expected a solid')


def _fill_small_holes(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
  """Closes boundary loops of at most `MAX_HOLE_EDGES` edges with triangles wound like their neighbours.

  Triangular holes get one face; larger ones a fan around a new vertex at the loop's centroid (works for
  non-planar and mildly non-convex loops). Loops through a vertex with several boundary edges are left
  open.

  Args:
    vertices: (V, 3) float64.
    faces: (F, 3) int64, consistently wound patches.

  Returns:
    (vertices, faces) with the new vertices / faces appended.
  """
  directed = directed_edges(faces)
  undirected = np.sort(directed, axis=1)
  _, inverse, counts = np.unique(undirected, axis=0, return_inverse=True, return_counts=True)
  boundary = directed[counts[inverse.reshape(-1)] == 1]
  if len(boundary) == 0:
    return vertices, faces
  starts, num_out = np.unique(boundary[:, 0], return_counts=True)
  pinched = set(starts[num_out > 1].tolist())
  next_vertex = {int(a): int(b) for a, b in boundary if int(a) not in pinched}
  new_vertices, new_faces = [], []
  seen: set[int] = set()
  for start in list(next_vertex):
    if start in seen:
      continue
    loop, v = [], start
    while v in next_vertex and v not in seen and len(loop) <= MAX_HOLE_EDGES:
      seen.add(v)
      loop.append(v)
      v = next_vertex[v]
    if v != start or len(loop) > MAX_HOLE_EDGES or len(loop) < 3:
      continue
    # The mesh traverses each boundary edge a -> b, so the filling faces must contain b -> a.
    if len(loop) == 3:
      new_faces.append([loop[2], loop[1], loop[0]])
      continue
    centre = len(vertices) + len(new_vertices)
    new_vertices.append(vertices[loop].mean(axis=0))
    new_faces.extend([loop[(i + 1) % len(loop)], loop[i], centre] for i in range(len(loop)))
  if not new_faces:
    return vertices, faces
  if new_vertices:
    vertices = np.concatenate([vertices, np.asarray(new_vertices)], axis=0)
  return vertices, np.concatenate([faces, np.asarray(new_faces, np.int64)], axis=0)


def _signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
  """Signed volume (m^3) enclosed by closed (F, 3) faces; positive when wound counter-clockwise outward."""
  tri = vertices[faces] - vertices[faces].reshape(-1, 3).mean(axis=0)
  return float(np.einsum('ij,ij->i', tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)


def _orient_components(vertices: np.ndarray, faces: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
  """Orients each closed component outward (cavities inward); unions overlapping components.

  Args:
    vertices: (V, 3) float64.
    faces: (F, 3) int64, closed and consistently wound.
    name: display name for errors.

  Returns:
    (vertices, faces) of a solid whose total signed volume is positive.
  """
  pairs, _ = face_adjacency(faces)
  adjacency = scipy.sparse.coo_matrix(
      (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(faces), len(faces)))
  num_comp, labels = scipy.sparse.csgraph.connected_components(adjacency, directed=False)
  faces = faces.copy()
  by_label = np.argsort(labels, kind='stable')
  comps = np.split(by_label, np.cumsum(np.bincount(labels, minlength=num_comp))[:-1])
  for idx in comps:
    if _signed_volume(vertices, faces[idx]) < 0:
      faces[idx] = faces[idx][:, ::-1]
  if num_comp == 1:
    return vertices, faces

  # Depth of each component = number of other components that contain it. Tested on a few vertices and
  # face centroids per component: |winding number| ~ 1 inside, ~ 0 outside, in between on the surface.
  rng = np.random.default_rng(0)
  samples, owner = [], []
  for c, idx in enumerate(comps):
    verts = vertices[np.unique(faces[idx])]
    centroids = vertices[faces[idx]].mean(axis=1)
    for points in (verts, centroids):
      samples.append(points[rng.choice(len(points), size=min(len(points), _NESTING_SAMPLES), replace=False)])
      owner.append(np.full(len(samples[-1]), c))
  samples, owner = np.concatenate(samples), np.concatenate(owner)
  sample_count = np.bincount(owner, minlength=num_comp)
  depth = np.zeros(num_comp, np.int64)
  overlap = False
  for c, idx in enumerate(comps):
    winding = np.abs(igl.winding_number(vertices, faces[idx], samples))
    other = owner != c
    inside_count = np.bincount(owner[other & (winding > 0.75)], minlength=num_comp)
    unclear_count = np.bincount(owner[other & (winding >= 0.25) & (winding <= 0.75)], minlength=num_comp)
    depth += (inside_count == sample_count)
    overlap |= bool(((unclear_count > 0) | ((inside_count > 0) & (inside_count < sample_count))).any())
  if overlap and (depth % 2 == 1).any():
    raise _Overlap(f'{num_comp} closed parts overlap or touch and some enclose cavities')
  if overlap:  # Overlapping or touching shells: replace them by their boolean union.
    parts = [trimesh.Trimesh(vertices, faces[idx], process=False) for idx in comps]
    for part in parts:
      part.remove_unreferenced_vertices()
    try:
      import manifold3d  # noqa: F401  pylint: disable=g-import-not-at-top,unused-import
    except ImportError as e:
      raise MeshError(
          name, f'{num_comp} parts overlap or touch; merging them needs the manifold3d package '
          '(pip install manifold3d)') from e
    try:
      merged = trimesh.boolean.union(parts, engine='manifold')
    except Exception as e:  # manifold3d raises several exception types.
      raise MeshError(name, f'{num_comp} parts overlap and their boolean union failed ({e})') from e
    if not (merged.is_watertight and merged.volume > 0):
      raise MeshError(name, f'{num_comp} parts overlap and their boolean union is not a closed solid')
    return np.asarray(merged.vertices, np.float64), np.asarray(merged.faces, np.int64)
  for c, idx in enumerate(comps):
    if depth[c] % 2 == 1:  # A cavity: its surface faces into the cavity, i.e. negative volume.
      faces[idx] = faces[idx][:, ::-1]
  return vertices, faces

