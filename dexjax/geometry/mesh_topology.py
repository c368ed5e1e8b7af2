"""Edge and face topology of triangle index arrays: directed and shared edges, face adjacency, consistent winding.

Shared by mesh repair (`dexjax.geometry.mesh_io`) and the reconstruction of imperfect meshes
(`dexjax.geometry.winding`). Faces are (F, 3) int64 vertex indices; nothing here looks at vertex positions.
Uses numpy / scipy only (no networkx).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph


def directed_edges(faces: np.ndarray) -> np.ndarray:
  """Returns the (3F, 2) directed edges (a, b), (b, c), (c, a) of (F, 3) faces, face-major."""
  return faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)


def undirected_edge_counts(faces: np.ndarray) -> np.ndarray:
  """Returns how many faces share each distinct undirected edge of (F, 3) faces."""
  edges = np.sort(directed_edges(faces), axis=1)
  _, counts = np.unique(edges, axis=0, return_counts=True)
  return counts


def is_winding_consistent(faces: np.ndarray) -> bool:
  """True if no directed edge occurs twice (adjacent faces traverse their shared edge in opposite senses)."""
  _, counts = np.unique(directed_edges(faces), axis=0, return_counts=True)
  return bool((counts == 1).all())


def face_adjacency(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
  """Pairs of faces sharing a manifold edge.

  Returns:
    pairs: (E, 2) int64 face indices.
    shared: (E, 2) int64 the shared edge as it appears (directed) in face ``pairs[:, 0]``.
  """
  directed = directed_edges(faces)
  undirected = np.sort(directed, axis=1)
  _, inverse, counts = np.unique(undirected, axis=0, return_inverse=True, return_counts=True)
  inverse = inverse.reshape(-1)
  keep = counts[inverse] == 2
  idx = np.nonzero(keep)[0]
  order = idx[np.argsort(inverse[idx], kind='stable')]
  first, second = order[0::2], order[1::2]
  pairs = np.stack([first // 3, second // 3], axis=1)
  return pairs, directed[first]


def consistent_winding(faces: np.ndarray) -> np.ndarray:
  """Flips faces so that every edge-connected patch is consistently wound (like trimesh's fix_winding).

  Which way a patch ends up facing is arbitrary; `dexjax.geometry.winding.orient_patches` also turns patches
  outward.

  Args:
    faces: (F, 3) int64, every edge shared by at most two faces.

  Returns:
    (F, 3) int64 faces; within each patch, faces adjacent to the patch's first face keep its orientation.
  """
  if is_winding_consistent(faces):
    return faces
  pairs, shared = face_adjacency(faces)
  num_faces = len(faces)
  # same[k] is True if the two faces of pair k traverse their shared edge in the same direction.
  second_edges = directed_edges(faces).reshape(num_faces, 3, 2)[pairs[:, 1]]
  same = (second_edges == shared[:, None, :]).all(axis=2).any(axis=1)
  adjacency = scipy.sparse.coo_matrix(
      (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(num_faces, num_faces))
  _, labels = scipy.sparse.csgraph.connected_components(adjacency, directed=False)
  _, roots = np.unique(labels, return_index=True)
  # One breadth-first traversal from a virtual node (index F) linked to the first face of every patch.
  rows = np.concatenate([pairs[:, 0], np.full(len(roots), num_faces)])
  cols = np.concatenate([pairs[:, 1], roots])
  graph = scipy.sparse.coo_matrix(
      (np.ones(len(rows)), (rows, cols)), shape=(num_faces + 1, num_faces + 1)).tocsr()
  order, pred = scipy.sparse.csgraph.breadth_first_order(graph, num_faces, directed=False)
  children = order[1:]
  parents = pred[children]
  pair_keys = np.minimum(pairs[:, 0], pairs[:, 1]) * num_faces + np.maximum(pairs[:, 0], pairs[:, 1])
  key_order = np.argsort(pair_keys)
  pair_keys, same = pair_keys[key_order], same[key_order]
  keys = np.minimum(parents, children) * num_faces + np.maximum(parents, children)
  found = np.clip(np.searchsorted(pair_keys, keys), 0, max(len(pair_keys) - 1, 0))
  relative = np.where(parents == num_faces, False, same[found] if len(same) else False).tolist()
  flip = [False] * (num_faces + 1)
  # Parents precede children in breadth-first order, so one sequential pass suffices.
  for child, parent, rel in zip(children.tolist(), parents.tolist(), relative):
    flip[child] = flip[parent] ^ rel
  flip = np.asarray(flip[:num_faces], bool)
  faces = faces.copy()
  faces[flip] = faces[flip][:, ::-1]
  return faces


__all__ = ['consistent_winding', 'directed_edges', 'face_adjacency', 'is_winding_consistent', 'undirected_edge_counts']
