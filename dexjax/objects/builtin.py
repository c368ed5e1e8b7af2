"""Built-in test objects and the object-spec resolver used by the command-line tools.

Every built-in mesh is closed (watertight), outward-oriented, in metres and centred so that its
bounding-box centre is at the origin:

* ``cube``: 4 cm cube.
* ``box``: 8 x 6 x 4 cm box (x by y by z).
* ``box_with_hole``: the ``box`` with a vertical (z) through-hole of 12 mm diameter at the centre of the
  top face (a 64-sided polygonal bore; the mesh is built directly, no boolean engine needed).
* ``cylinder``: radius 2.5 cm, height 8 cm, axis z (64 sides).
* ``sphere``: radius 3 cm (icosphere with 4 subdivisions, 5120 faces; vertices on the sphere).
* ``l_shape``: an L in the x-z plane, 4 cm deep in y: an 8 x 4 x 2 cm foot along x plus a 2 x 4 x 8 cm
  upright at its +x end (overall 8 x 4 x 8 cm; an extruded L profile), so the centre of mass is off the
  bounding-box centre in x and z.

An object spec is ``'builtin:NAME'``, ``'procedural:L{level}/{index}[@{seed}]'`` (see
`dexjax.objects.procedural`) or a mesh file path (see `dexjax.geometry.load_mesh`).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from typing import Any

import numpy as np
import trimesh

from dexjax.geometry.cache import cached_object_model
from dexjax.geometry.mesh_io import SUPPORTED_EXTENSIONS, MeshError, load_mesh
from dexjax.geometry.object_model import ObjectModel
from dexjax.objects.procedural import PROCEDURAL_PREFIX
from dexjax.objects.procedural import parse_procedural_spec
from dexjax.objects.procedural import procedural_spec_mesh

BUILTIN_PREFIX: str = 'builtin:'
"""Prefix of built-in object specs, e.g. ``'builtin:box'``."""

_CYLINDER_SECTIONS = 64

# Dimensions (metres) of the L-shape parts, in the frame before centring: the foot spans
# [0, 0.08] x [-0.02, 0.02] x [0, 0.02]; the upright spans [0.06, 0.08] x [-0.02, 0.02] x [0, 0.08].
# Only the foot's x, y, z and the upright's x and z are used (the depth is shared).
L_SHAPE_FOOT_EXTENTS = (0.08, 0.04, 0.02)
L_SHAPE_UPRIGHT_EXTENTS = (0.02, 0.04, 0.08)


def _centred(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
  """Translates ``mesh`` in place so that its bounding-box centre is at the origin; returns it."""
  mesh.apply_translation(-0.5 * (mesh.bounds[0] + mesh.bounds[1]))
  return mesh


def _extrude(points: np.ndarray, triangles: np.ndarray, loops: list[np.ndarray], w0: float, w1: float):
  """Extrudes a triangulated 2-D region along a third axis into a closed prism.

  Args:
    points: (N, 2) region vertices (u, v), metres.
    triangles: (T, 3) indices into ``points`` covering the region (any orientation; made counter-clockwise).
    loops: boundary loops as index arrays, each ordered with the region on its left (outer boundary
      counter-clockwise, holes clockwise).
    w0, w1: extent of the prism along the extrusion axis w, metres (w0 < w1).

  Returns:
    (vertices (2N, 3) as (u, v, w), faces (F, 3)) of a closed prism with outward counter-clockwise faces.
  """
  n = len(points)
  a, b, c = (points[triangles[:, k]] for k in range(3))
  cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
  triangles = np.where((cross < 0)[:, None], triangles[:, ::-1], triangles)
  faces = [triangles[:, ::-1], triangles + n]  # Bottom cap (w0) faces -w, top cap (w1) faces +w.
  for loop in loops:
    i, j = loop, np.roll(loop, -1)
    faces += [np.stack([i, j, j + n], axis=1), np.stack([i, j + n, i + n], axis=1)]
  vertices = np.concatenate([np.c_[points, np.full(n, w0)], np.c_[points, np.full(n, w1)]])
  return vertices, np.concatenate(faces).astype(np.int64)


def _stitch_rings(inner_angles: np.ndarray, outer_angles: np.ndarray) -> np.ndarray:
  """Triangulates the band between two star-shaped rings sorted by angle, both starting at angle 0.

  Returns:
    (len(inner) + len(outer), 3) triangles; inner vertices are indices 0..I-1, outer ones I..I+O-1.
  """
  n_in, n_out = len(inner_angles), len(outer_angles)
  next_angle = lambda angles, k: angles[k + 1] if k + 1 < len(angles) else 2 * np.pi + angles[0]
  triangles, i, j = [], 0, 0
  while i < n_in or j < n_out:
    if j == n_out or (i < n_in and next_angle(inner_angles, i) <= next_angle(outer_angles, j)):
      triangles.append([i, (i + 1) % n_in, n_in + j % n_out])
      i += 1
    else:
      triangles.append([i % n_in, n_in + j, n_in + (j + 1) % n_out])
      j += 1
  return np.asarray(triangles, np.int64)


def _cube() -> trimesh.Trimesh:
  return trimesh.creation.box(extents=(0.04, 0.04, 0.04))


def _box() -> trimesh.Trimesh:
  return trimesh.creation.box(extents=(0.08, 0.06, 0.04))


def _box_with_hole() -> trimesh.Trimesh:
  half_x, half_y, half_z, radius = 0.04, 0.03, 0.02, 0.006
  angles = 2 * np.pi * np.arange(_CYLINDER_SECTIONS) / _CYLINDER_SECTIONS
  inner = radius * np.c_[np.cos(angles), np.sin(angles)]
  # Outer ring: where the rays through the hole vertices meet the rectangle, plus its four corners.
  corners = np.array([[half_x, half_y], [-half_x, half_y], [-half_x, -half_y], [half_x, -half_y]])
  reach = np.minimum(half_x / np.maximum(np.abs(np.cos(angles)), 1e-300),
                     half_y / np.maximum(np.abs(np.sin(angles)), 1e-300))
  outer = np.concatenate([reach[:, None] * np.c_[np.cos(angles), np.sin(angles)], corners])
  outer_angles = np.mod(np.arctan2(outer[:, 1], outer[:, 0]), 2 * np.pi)
  order = np.argsort(outer_angles)
  outer, outer_angles = outer[order], outer_angles[order]
  triangles = _stitch_rings(angles, outer_angles)
  n_in = len(inner)
  loops = [n_in + np.arange(len(outer)), np.arange(n_in)[::-1]]  # Outer CCW, hole CW.
  vertices, faces = _extrude(np.concatenate([inner, outer]), triangles, loops, -half_z, half_z)
  return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)


def _cylinder() -> trimesh.Trimesh:
  return trimesh.creation.cylinder(radius=0.025, height=0.08, sections=_CYLINDER_SECTIONS)


def _sphere() -> trimesh.Trimesh:
  return trimesh.creation.icosphere(subdivisions=4, radius=0.03)


def _l_shape() -> trimesh.Trimesh:
  foot_x, depth, foot_z = L_SHAPE_FOOT_EXTENTS
  upright_x, _, height = L_SHAPE_UPRIGHT_EXTENTS
  # Profile in the x-z plane, counter-clockwise; vertex 4 is the concave corner and sees all the others.
  profile = np.array([[0.0, 0.0], [foot_x, 0.0], [foot_x, height], [foot_x - upright_x, height],
                      [foot_x - upright_x, foot_z], [0.0, foot_z]])
  triangles = np.array([[4, 5, 0], [4, 0, 1], [4, 1, 2], [4, 2, 3]])
  vertices, faces = _extrude(profile, triangles, [np.arange(6)], -depth / 2, depth / 2)
  # (u, v, w) -> (x, y, z) = (u, -w, v) is a proper rotation, so the faces stay outward.
  vertices = np.c_[vertices[:, 0], -vertices[:, 2], vertices[:, 1]]
  return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)


_BUILDERS: dict[str, Callable[[], trimesh.Trimesh]] = {
    'cube': _cube,
    'box': _box,
    'box_with_hole': _box_with_hole,
    'cylinder': _cylinder,
    'sphere': _sphere,
    'l_shape': _l_shape,
}

BUILTIN_OBJECTS: tuple[str, ...] = tuple(_BUILDERS)
"""Names accepted by `builtin_mesh` (and as ``'builtin:NAME'`` specs)."""


@functools.lru_cache(maxsize=None)
def _builtin_arrays(name: str) -> tuple[np.ndarray, np.ndarray]:
  mesh = _centred(_BUILDERS[name]())
  vertices = np.asarray(mesh.vertices, np.float64)
  faces = np.asarray(mesh.faces, np.int64)
  vertices.flags.writeable = False
  faces.flags.writeable = False
  return vertices, faces


def builtin_mesh(name: str) -> trimesh.Trimesh:
  """Returns a fresh copy of a built-in mesh (metres, bounding-box centre at the origin).

  Args:
    name: one of `BUILTIN_OBJECTS`.

  Raises:
    ValueError: unknown name; the message lists the available ones.
  """
  _check_builtin_name(name)
  vertices, faces = _builtin_arrays(name)
  return trimesh.Trimesh(vertices=vertices.copy(), faces=faces.copy(), process=False)


def _check_builtin_name(name: str) -> None:
  """Raises ValueError listing the valid ``builtin:NAME`` specs unless ``name`` is one of `BUILTIN_OBJECTS`."""
  if name not in _BUILDERS:
    shown = name if len(name) <= 100 else f'{name[:80]}...({len(name)} characters)'
    raise ValueError(f"unknown builtin object {shown!r}; expected one of "
                     f"{', '.join(BUILTIN_PREFIX + n for n in BUILTIN_OBJECTS)}")


def check_object_spec(spec: str | os.PathLike[str]) -> None:
  """Checks an object spec without building anything (for a command, before any computing): a known built-in
  name, a well-formed procedural spec, or a path that is a regular file (`mesh_path_problem`).

  Raises:
    ValueError: an unknown built-in name (listing the valid ones) or a malformed procedural spec.
    MeshError: the path does not exist, is a folder or is not a regular file.
  """
  spec = os.fspath(spec)
  if spec.startswith(BUILTIN_PREFIX):
    _check_builtin_name(spec[len(BUILTIN_PREFIX):])
  elif spec.startswith(PROCEDURAL_PREFIX):
    parse_procedural_spec(spec)
  else:
    problem = mesh_path_problem(spec)
    if problem is not None:
      raise MeshError(spec, problem)


def resolve_mesh(spec: str | os.PathLike[str], *, scale: float = 1.0) -> tuple[trimesh.Trimesh, str]:
  """Turns an object spec into a mesh in metres and a display name.

  Args:
    spec: ``'builtin:NAME'`` (see `BUILTIN_OBJECTS`), ``'procedural:L{level}/{index}[@{seed}]'`` (see
      `dexjax.objects.procedural_mesh`) or a mesh file path (see `load_mesh`).
    scale: factor applied to the coordinates (e.g. 0.001 for a file in millimetres); also applies to
      built-in and procedural objects.

  Returns:
    (mesh, name): the repaired mesh and the spec as a string (used in messages).

  Raises:
    ValueError: unknown builtin name, malformed procedural spec or a bad scale.
    MeshError: the path does not exist, is a folder or not a regular file (`mesh_path_problem`), or the file
      cannot be loaded or repaired.
  """
  spec = os.fspath(spec)
  if isinstance(spec, str) and spec.startswith((BUILTIN_PREFIX, PROCEDURAL_PREFIX)):
    if spec.startswith(PROCEDURAL_PREFIX):
      mesh = procedural_spec_mesh(spec)
    else:
      mesh = builtin_mesh(spec[len(BUILTIN_PREFIX):])
    if not (np.isfinite(scale) and scale > 0):
      raise ValueError(f"resolve_mesh('{spec}'): scale must be a finite positive number, got {scale!r}")
    if scale != 1.0:
      mesh.apply_scale(scale)
    return mesh, spec
  check_object_spec(spec)
  return load_mesh(spec, scale=scale), str(spec)


def mesh_path_problem(path: str | os.PathLike[str], *, folder_ok: bool = False) -> str | None:
  """What is wrong with ``path`` as a mesh source, in words without the path (None: nothing found wrong).

  Checked before the file's extension, so that a missing path or a folder is not reported as an unsupported
  extension: the path must exist (a dangling link does not), be a regular file (not a device such as
  ``/dev/null``, a pipe or a socket) or, with ``folder_ok``, a folder.
  """
  path = os.fspath(path)
  expected = f"expected a mesh file ({', '.join(SUPPORTED_EXTENSIONS)})"
  expected += ' or a folder of them' if folder_ok else ''
  if not os.path.exists(path):
    return f'file not found: the path does not exist; {expected}'
  if os.path.isdir(path):
    return None if folder_ok else f'is a folder, {expected} (or builtin:NAME)'
  if not os.path.isfile(path):
    return f'is not a regular file (a device, pipe or socket); {expected}'
  return None


def load_object_model(
    spec: str | os.PathLike[str],
    *,
    cache_dir: str | os.PathLike[str] | None = None,
    scale: float = 1.0,
    **build_kwargs: Any,
) -> ObjectModel:
  """Resolves an object spec and returns its (cached) `ObjectModel`; what the command-line tools call.

  Args:
    spec: ``'builtin:NAME'``, ``'procedural:L{level}/{index}[@{seed}]'`` or a mesh file path.
    cache_dir: model cache directory (default: ``$DEXJAX_CACHE`` or ``~/.cache/dexjax/objects``).
    scale: coordinate scale applied when loading (see `resolve_mesh`).
    **build_kwargs: `dexjax.geometry.build_object_model` arguments (grid_size, padding,
      num_surface_samples, seed); ``name`` defaults to the spec.

  Returns:
    The object's `ObjectModel`.
  """
  mesh, name = resolve_mesh(spec, scale=scale)
  build_kwargs.setdefault('name', name)
  return cached_object_model(mesh, cache_dir=cache_dir, **build_kwargs)
