"""Imperfect copies of a closed mesh, the way downloaded assets come: to test a pipeline on meshes like users have.

Scanned objects, CAD exports and simulator asset libraries are rarely closed 2-manifolds. Each function here
takes a closed triangle mesh (metres) and returns a new `trimesh.Trimesh` (``process=False``) with one kind of
defect, deterministically from its ``seed``; `dexjax.geometry.load_mesh` must still load the result (as the
solid its generalized winding number encloses, with an `ImperfectMeshWarning`):

* `open_holes`: large holes, the faces around random surface points removed;
* `remove_facing`: a missing side or cap (every face whose normal is within an angle of a direction);
* `split_seam`: a seam that does not close, the vertices on one side of a plane moved apart by a tiny gap
  (what unit conversion or UV splitting does to an exported mesh);
* `add_fins`: non-manifold edges, thin internal fins attached to existing edges (a third face per edge);
* `duplicate_faces`: a double wall, copies of some faces just inside the surface with their own vertices;
* `flip_faces`: random faces wound the wrong way.
"""

from __future__ import annotations

import numpy as np
import trimesh


def _copy(vertices: np.ndarray, faces: np.ndarray) -> trimesh.Trimesh:
  return trimesh.Trimesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64), process=False)


def open_holes(mesh: trimesh.Trimesh, num_holes: int = 2, radius: float = 0.2, seed: int = 0) -> trimesh.Trimesh:
  """Removes the faces whose centroid lies within ``radius`` x (largest extent) of ``num_holes`` random
  (area-uniform) surface points; at least one face per hole."""
  rng = np.random.default_rng(seed)
  centres = np.asarray(mesh.triangles_center)
  areas = np.asarray(mesh.area_faces)
  picks = rng.choice(len(centres), size=num_holes, p=areas / areas.sum())
  reach = radius * float(np.max(mesh.extents))
  distance = np.linalg.norm(centres[:, None, :] - centres[picks][None], axis=-1).min(axis=1)
  remove = distance <= reach
  remove[picks] = True
  return _copy(mesh.vertices, np.asarray(mesh.faces)[~remove])


def remove_facing(mesh: trimesh.Trimesh, direction=(0.0, 0.0, 1.0), max_angle_deg: float = 30.0) -> trimesh.Trimesh:
  """Removes every face whose outward normal is within ``max_angle_deg`` of ``direction`` (a missing cap)."""
  d = np.asarray(direction, np.float64)
  d = d / np.linalg.norm(d)
  keep = np.asarray(mesh.face_normals) @ d < np.cos(np.radians(max_angle_deg))
  return _copy(mesh.vertices, np.asarray(mesh.faces)[keep])


def split_seam(mesh: trimesh.Trimesh, axis: int = 0, gap: float = 1e-5) -> trimesh.Trimesh:
  """Duplicates the vertices of the faces on the positive side of the plane through the centre normal to
  ``axis`` and moves them by ``gap`` x (largest extent) along it: the surface opens along the plane."""
  vertices = np.asarray(mesh.vertices, np.float64)
  faces = np.asarray(mesh.faces, np.int64).copy()
  centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
  side = np.asarray(mesh.triangles_center)[:, axis] > centre[axis]
  moved = np.unique(faces[side])
  new_index = np.full(len(vertices), -1)
  new_index[moved] = len(vertices) + np.arange(len(moved))
  shifted = vertices[moved].copy()
  shifted[:, axis] += gap * float(np.max(mesh.extents))
  faces[side] = new_index[faces[side]]
  return _copy(np.concatenate([vertices, shifted]), faces)


def add_fins(mesh: trimesh.Trimesh, num_fins: int = 6, depth: float = 0.1, seed: int = 0) -> trimesh.Trimesh:
  """Adds ``num_fins`` triangles, each on an existing edge (which then has three faces) with its third vertex
  ``depth`` x (largest extent) inside the solid along the inward normal at the edge's midpoint."""
  rng = np.random.default_rng(seed)
  edges = np.asarray(mesh.edges_unique)
  chosen = edges[rng.choice(len(edges), size=min(num_fins, len(edges)), replace=False)]
  vertices = np.asarray(mesh.vertices, np.float64)
  normals = np.asarray(mesh.vertex_normals, np.float64)
  mid = 0.5 * (vertices[chosen[:, 0]] + vertices[chosen[:, 1]])
  inward = -(normals[chosen[:, 0]] + normals[chosen[:, 1]])
  inward /= np.maximum(np.linalg.norm(inward, axis=1, keepdims=True), 1e-12)
  tips = mid + depth * float(np.max(mesh.extents)) * inward
  tip_index = len(vertices) + np.arange(len(tips))
  fins = np.stack([chosen[:, 0], chosen[:, 1], tip_index], axis=1)
  return _copy(np.concatenate([vertices, tips]), np.concatenate([np.asarray(mesh.faces), fins]))


def duplicate_faces(mesh: trimesh.Trimesh, fraction: float = 0.2, offset: float = 1e-4,
                    seed: int = 0) -> trimesh.Trimesh:
  """Adds a copy of a random ``fraction`` of the faces, with vertices of their own moved ``offset`` x (largest
  extent) inward along the vertex normals, wound the other way round (a double wall, as CAD exports with
  duplicated bodies have); the copies leave open boundaries and a second sheet inside the solid."""
  rng = np.random.default_rng(seed)
  faces = np.asarray(mesh.faces, np.int64)
  chosen = faces[rng.random(len(faces)) < fraction]
  used, inverse = np.unique(chosen, return_inverse=True)
  vertices = np.asarray(mesh.vertices, np.float64)
  moved = vertices[used] - offset * float(np.max(mesh.extents)) * np.asarray(mesh.vertex_normals)[used]
  copies = (len(vertices) + inverse.reshape(-1, 3))[:, ::-1]
  return _copy(np.concatenate([vertices, moved]), np.concatenate([faces, copies]))


def flip_faces(mesh: trimesh.Trimesh, fraction: float = 0.3, seed: int = 0) -> trimesh.Trimesh:
  """Reverses the winding of a random ``fraction`` of the faces."""
  rng = np.random.default_rng(seed)
  faces = np.asarray(mesh.faces, np.int64).copy()
  flip = rng.random(len(faces)) < fraction
  faces[flip] = faces[flip][:, ::-1]
  return _copy(mesh.vertices, faces)


__all__ = ['add_fins', 'duplicate_faces', 'flip_faces', 'open_holes', 'remove_facing', 'split_seam']
