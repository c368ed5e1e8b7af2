"""Rigid bodies for heap physics: collision hulls plus explicit mass properties (`HeapObject`).

Collision geometry is a tuple of convex hulls (vertex arrays in the object frame, metres), e.g. from
`dexjax.objects.collision.collision_hulls` (a cached convex decomposition) or a single ``mesh.convex_hull``.
MuJoCo takes the convex hull of each vertex array, so only vertices are needed.

Mass properties come from the full mesh, not the hulls: overlapping hulls of a decomposition would
double-count volume. Mass rule (`heap_object`), always with a uniform density for the inertia:

* an object that carries its own density, ``mesh.metadata['density']`` (kg/m^3; every procedural object does:
  drawn from its family's material, see ``docs/objects.md``): mass = that density x volume, not clipped (the
  generator keeps procedural masses within [0.01, 0.6] kg);
* any other object (built-ins, your meshes): density `DEFAULT_DENSITY` = 500 kg/m^3, a guess (a solid between
  softwood and water; a 5-10 cm object then weighs 0.05-0.5 kg, around the reward model's mean of 0.25 kg),
  with the mass clipped to `DEFAULT_MASS_RANGE` = [0.01, 2] kg so that tiny or huge meshes still give a stable
  simulation; when the mass is clipped the inertia is scaled by the same factor (same shape, other density).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Iterable
from typing import Protocol

import numpy as np
import trimesh

#: Density of heap objects that carry none of their own, kg/m^3 (a guess: see the module docstring).
DEFAULT_DENSITY = 500.0
#: (low, high) clip of the mass of objects that carry no density of their own, kg.
DEFAULT_MASS_RANGE = (0.01, 2.0)
#: Key of ``trimesh.Trimesh.metadata`` holding an object's own density, kg/m^3 (set by procedural objects).
DENSITY_KEY = 'density'


@dataclasses.dataclass(frozen=True, eq=False)
class HeapObject:
  """One object that can be dropped into a heap (plain data for model building; not traced).

  Attributes:
    name: a label (used in messages and MuJoCo names).
    hulls: tuple of (V_i, 3) float64 arrays, convex pieces' vertices in the object frame, metres.
    mass: kg.
    center_of_mass: (3,) float64, object frame, metres.
    inertia: (3, 3) float64 inertia tensor about the centre of mass in object-frame axes, kg m^2.
  """

  name: str
  hulls: tuple[np.ndarray, ...]
  mass: float
  center_of_mass: np.ndarray
  inertia: np.ndarray

  def __post_init__(self):
    hulls = tuple(validate_hull(h, f'HeapObject {self.name!r}: hulls[{i}]') for i, h in enumerate(self.hulls))
    if not hulls:
      raise ValueError(f'HeapObject {self.name!r}: hulls: expected at least one convex hull, got none')
    object.__setattr__(self, 'hulls', hulls)
    if not (np.isfinite(self.mass) and self.mass > 0):
      raise ValueError(f'HeapObject {self.name!r}: mass: expected a finite number > 0 (kg), got {self.mass!r}')
    com = np.asarray(self.center_of_mass, np.float64)
    if com.shape != (3,) or not np.all(np.isfinite(com)):
      raise ValueError(f'HeapObject {self.name!r}: center_of_mass: expected 3 finite numbers (metres), got {com!r}')
    inertia = np.asarray(self.inertia, np.float64)
    if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)):
      raise ValueError(f'HeapObject {self.name!r}: inertia: expected a finite (3, 3) array (kg m^2), got shape '
                       f'{inertia.shape}')
    inertia = 0.5 * (inertia + inertia.T)
    if np.linalg.eigvalsh(inertia).min() <= 0:
      raise ValueError(f'HeapObject {self.name!r}: inertia: expected a positive definite tensor, got eigenvalues '
                       f'{np.linalg.eigvalsh(inertia)}')
    object.__setattr__(self, 'center_of_mass', com)
    object.__setattr__(self, 'inertia', inertia)

  @functools.cached_property
  def vertices_about_com(self) -> np.ndarray:
    """(V, 3) float64: every hull's vertices, concatenated, relative to the centre of mass (object axes, metres);
    computed once per object (settling reads it for every heap the object is dropped into)."""
    return np.concatenate(self.hulls) - self.center_of_mass

  @property
  def radius(self) -> float:
    """Largest distance from the centre of mass to a hull vertex, metres."""
    return float(max(np.linalg.norm(h - self.center_of_mass, axis=1).max() for h in self.hulls))


def validate_hull(vertices: np.ndarray, where: str = 'hull') -> np.ndarray:
  """Checks one convex piece and returns it as a (V, 3) float64 array.

  Raises:
    ValueError (naming ``where``): not an (V, 3) array of finite numbers, or fewer than 4 non-coplanar points
    (MuJoCo cannot take the convex hull of a flat point set).
  """
  v = np.asarray(vertices, np.float64)
  if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
    raise ValueError(f'{where}: expected a (V, 3) array of finite vertex coordinates (metres), got shape '
                     f'{v.shape}')
  centred = v - v.mean(axis=0)
  scale = max(float(np.abs(centred).max()), 1e-12)
  if len(v) < 4 or np.linalg.matrix_rank(centred / scale, tol=1e-6) < 3:
    raise ValueError(f'{where}: expected at least 4 non-coplanar points (a convex hull with volume), got {len(v)} '
                     f'point(s) spanning {np.linalg.matrix_rank(centred / scale, tol=1e-6) if len(v) else 0} '
                     'dimension(s)')
  return v


def object_density(mesh: trimesh.Trimesh) -> float | None:
  """The object's own density, kg/m^3 (``mesh.metadata['density']``, set by procedural objects), or None."""
  density = mesh.metadata.get(DENSITY_KEY) if isinstance(mesh.metadata, dict) else None
  return None if density is None else float(density)


def mass_solid(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
  """The solid whose volume and inertia `heap_object` uses: the mesh when it is watertight with positive volume,
  else its convex hull."""
  return mesh if mesh.is_watertight and mesh.volume > 0 else mesh.convex_hull


def heap_object(mesh: trimesh.Trimesh, hulls: tuple[np.ndarray, ...] | list[np.ndarray] | None = None, *,
                density: float | None = None,
                mass_range: tuple[float, float] | None = None,
                name: str | None = None) -> HeapObject:
  """Builds a `HeapObject` from a mesh (for mass properties) and its convex pieces (for collisions).

  Args:
    mesh: the object's surface in metres, object frame. Mass properties use the mesh when it is watertight
      and its convex hull otherwise.
    hulls: convex pieces, each (V_i, 3) vertices in the same frame (e.g. ``collision_hulls(mesh)``); default:
      the mesh's convex hull as a single piece.
    density: kg/m^3; default: the object's own (`object_density`: every procedural object has one), else
      `DEFAULT_DENSITY` (500, a guess).
    mass_range: (low, high) clip of the resulting mass, kg; the inertia is scaled with the mass. Default: no
      clip for an object with its own density, `DEFAULT_MASS_RANGE` ([0.01, 2]) otherwise.
    name: label; default ``mesh.metadata['name']`` or ``'object'``.

  Raises:
    ValueError: a bad density or mass range, a mesh without volume, or a bad hull (see `validate_hull`).
  """
  name = name if name is not None else str(mesh.metadata.get('name', 'object'))
  own = object_density(mesh)
  if density is None:
    density = DEFAULT_DENSITY if own is None else own
  if mass_range is None and own is None:
    mass_range = DEFAULT_MASS_RANGE
  if not (np.isfinite(density) and density > 0):
    raise ValueError(f'heap_object({name!r}): density: expected a finite number > 0 (kg/m^3), got {density!r}')
  if mass_range is not None and not (0 < mass_range[0] <= mass_range[1] and np.isfinite(mass_range[1])):
    raise ValueError(f'heap_object({name!r}): mass_range: expected 0 < low <= high (kg), got {mass_range!r}')
  solid = mass_solid(mesh)
  volume = float(solid.volume)
  if not (np.isfinite(volume) and volume > 0):
    raise ValueError(f'heap_object({name!r}): mesh: expected a closed surface with positive volume, got volume '
                     f'{volume!r} m^3')
  mass = density * volume
  clipped = float(mass if mass_range is None else np.clip(mass, *mass_range))
  unit_inertia = np.asarray(solid.moment_inertia, np.float64) / float(getattr(solid, 'density', 1.0) or 1.0)
  inertia = unit_inertia * density * (clipped / mass)
  if hulls is None:
    hulls = (np.asarray(mesh.convex_hull.vertices, np.float64),)
  return HeapObject(name=name, hulls=tuple(hulls), mass=clipped,
                    center_of_mass=np.asarray(solid.center_mass, np.float64), inertia=inertia)


class _WithHulls(Protocol):
  """Anything with a name, a mesh and collision hulls, e.g. `dexjax.objects.PreparedObject`."""
  name: str
  mesh: trimesh.Trimesh
  hulls: tuple[np.ndarray, ...]


def heap_objects(prepared: Iterable[_WithHulls], *, density: float | None = None,
                 mass_range: tuple[float, float] | None = None) -> list[HeapObject]:
  """`heap_object` for each prepared object (e.g. from `dexjax.objects.prepare_object_set`), in order.

  Args:
    prepared: objects with ``name``, ``mesh`` (metres) and ``hulls`` (convex pieces).
    density, mass_range: see `heap_object` (defaults: each object's own density, unclipped, when it has one,
      e.g. procedural objects; 500 kg/m^3 clipped to [0.01, 2] kg otherwise).

  Returns:
    One `HeapObject` per item; ``HeapState.object_ids`` index into this list.
  """
  return [heap_object(p.mesh, p.hulls, density=density, mass_range=mass_range, name=p.name) for p in prepared]
