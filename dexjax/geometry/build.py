"""Builds an `ObjectModel` (signed distance grid, surface samples, mass properties) from a triangle mesh.

The grid follows Dex-Net's SDFGen (spec section 1.2): a cube of ``grid_size**3`` isotropic voxels centred
on the bounding-box centre, with voxel size ``largest extent / (grid_size - 2 * padding)``, so the mesh
leaves about ``padding`` voxels of free space on each side along its longest axis. Unlike Dex-Net the grid
is *signed* (negative inside), computed exactly at voxel centres with libigl's pseudonormal test.

Grid indexing: ``sdf[i, j, k]`` is the signed distance at ``origin + voxel_size * (i, j, k)``, i.e. the
array axes are x, y, z.
"""

from __future__ import annotations

import igl
import jax.numpy as jnp
import numpy as np
import trimesh

from dexjax.config_rules import MAX_GRID_SIZE
from dexjax.geometry.mesh_io import validate_and_repair
from dexjax.geometry.object_model import ObjectModel


def build_object_model(
    mesh: trimesh.Trimesh,
    *,
    grid_size: int = 100,
    padding: int = 5,
    num_surface_samples: int = 2048,
    seed: int = 0,
    name: str = '<mesh>',
) -> ObjectModel:
  """Builds the analytic-quality description of a rigid object from its mesh (metres).

  The mesh is first passed through `validate_and_repair` (a no-op copy for clean closed meshes).

  Args:
    mesh: closed triangle mesh in the object frame, metres.
    grid_size: voxels D along each axis of the cubic grid; must exceed ``2 * padding + 1`` and be at most
      `dexjax.config_rules.MAX_GRID_SIZE` (512).
    padding: voxels of free space between the bounding box and the grid border along the longest axis
      (Dex-Net: 5); at least 1.
    num_surface_samples: number S of area-uniform surface samples; at least 1.
    seed: seed of the surface sampler; the same mesh and seed give the same samples.
    name: file or display name used in error messages.

  Returns:
    An `ObjectModel` of float32 jax arrays: sdf (D, D, D) m, sdf_grad (D, D, D, 3), origin (3,) m,
    voxel_size () m, surface_points (S, 3) m, surface_normals (S, 3), center_of_mass (3,) m,
    volume () m^3, inertia (3, 3) m^2 per kg, bounds (2, 3) m.

  Raises:
    ValueError: a build parameter is out of range.
    MeshError: the mesh cannot be repaired into a closed solid.
  """
  _check_int('grid_size', grid_size, 2 * _as_int('padding', padding) + 2)
  if grid_size > MAX_GRID_SIZE:
    raise ValueError(f'build_object_model: grid_size: expected at most {MAX_GRID_SIZE} voxels per axis (MAX_GRID_SIZE; '
                     f'a {MAX_GRID_SIZE}^3 grid is 0.5 GB), got {grid_size}')
  _check_int('padding', padding, 1)
  _check_int('num_surface_samples', num_surface_samples, 1)
  _check_int('seed', seed, 0)
  mesh = validate_and_repair(mesh, name)
  vertices = np.asarray(mesh.vertices, np.float64)
  faces = np.asarray(mesh.faces, np.int64)

  origin, voxel_size = grid_frame(mesh.bounds, grid_size, padding)
  sdf = _signed_distance_grid(vertices, faces, origin, voxel_size, grid_size)
  grad = np.stack(np.gradient(sdf, voxel_size, edge_order=1), axis=-1)
  points, normals = sample_surface(mesh, num_surface_samples, seed)

  props = mesh.mass_properties  # Uniform density 1 kg/m^3, so mass == volume.
  volume = float(props.volume)
  inertia = np.asarray(props.inertia, np.float64) / volume
  inertia = 0.5 * (inertia + inertia.T)

  f32 = lambda x: jnp.asarray(np.asarray(x, np.float32))
  return ObjectModel(
      sdf=f32(sdf),
      sdf_grad=f32(grad),
      origin=f32(origin),
      voxel_size=f32(voxel_size),
      surface_points=f32(points),
      surface_normals=f32(normals),
      center_of_mass=f32(props.center_mass),
      volume=f32(volume),
      inertia=f32(inertia),
      bounds=f32(mesh.bounds),
  )


def grid_frame(bounds: np.ndarray, grid_size: int, padding: int) -> tuple[np.ndarray, float]:
  """Origin and voxel size of the SDFGen-style cubic grid around an axis-aligned bounding box.

  Args:
    bounds: (2, 3) [min, max] corners, metres.
    grid_size: voxels D per axis.
    padding: free voxels beyond the bounding box along its longest axis.

  Returns:
    origin: (3,) float64 centre of voxel (0, 0, 0), metres.
    voxel_size: edge length of a voxel, metres.
  """
  bounds = np.asarray(bounds, np.float64)
  voxel_size = float(np.max(bounds[1] - bounds[0])) / (grid_size - 2 * padding)
  centre = 0.5 * (bounds[0] + bounds[1])
  origin = centre - 0.5 * (grid_size - 1) * voxel_size
  return origin, voxel_size


def sample_surface(mesh: trimesh.Trimesh, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
  """Area-uniform random points on a mesh surface with the (outward) normals of their faces.

  Uses its own numpy generator (not trimesh's sampler) so the samples for a seed do not change with the
  trimesh version.

  Args:
    mesh: triangle mesh, metres.
    count: number of samples S.
    seed: seed of `numpy.random.default_rng`.

  Returns:
    points: (S, 3) float64, metres.
    normals: (S, 3) float64 unit face normals.
  """
  rng = np.random.default_rng(seed)
  areas = np.asarray(mesh.area_faces, np.float64)
  cdf = np.cumsum(areas)
  face = np.searchsorted(cdf, rng.random(count) * cdf[-1], side='right')
  face = np.minimum(face, len(areas) - 1)
  r1, r2 = rng.random((2, count))
  s = np.sqrt(r1)
  tri = np.asarray(mesh.triangles, np.float64)[face]
  points = (1.0 - s)[:, None] * tri[:, 0] + (s * (1.0 - r2))[:, None] * tri[:, 1] + (s * r2)[:, None] * tri[:, 2]
  normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
  normals /= np.linalg.norm(normals, axis=1, keepdims=True)
  return points, normals


def _signed_distance_grid(
    vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray, voxel_size: float, grid_size: int
) -> np.ndarray:
  """(D, D, D) float64 signed distance (m, negative inside) at the voxel centres, via libigl."""
  axis = np.arange(grid_size, dtype=np.float64) * voxel_size
  gx, gy, gz = np.meshgrid(origin[0] + axis, origin[1] + axis, origin[2] + axis, indexing='ij')
  queries = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
  dist, *_ = igl.signed_distance(
      queries, np.ascontiguousarray(vertices), np.ascontiguousarray(faces),
      sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)
  return np.asarray(dist, np.float64).reshape(grid_size, grid_size, grid_size)


def _as_int(field: str, value: object) -> int:
  if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
    raise ValueError(f'build_object_model (dexjax/geometry/build.py): {field} must be an int, got {value!r}')
  return int(value)


def _check_int(field: str, value: object, minimum: int) -> None:
  if _as_int(field, value) < minimum:
    raise ValueError(
        f'build_object_model (dexjax/geometry/build.py): {field} must be >= {minimum}, got {value!r}')
