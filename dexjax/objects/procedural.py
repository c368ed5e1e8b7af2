"""Procedural object sets at the three difficulty levels of Dex-Net 4.0's object range.

The seed's benchmark objects come in three difficulty levels: (1) prismatic and circular solids, (2)
household objects with complex geometry (toys, tools, "blisterpack" objects) and (3) adversarial geometry
(detailed 3D-printed industrial parts). `procedural_mesh(level, index, seed)` generates an unbounded,
deterministic stream of watertight, household-sized meshes for each level, each with a material and a
density; see ``docs/objects.md`` for the families, their parameter ranges and their materials.

* Object ``index`` of a level belongs to family ``index % len(families)`` (`procedural_families`); its
  parameters, including its density, are drawn from ``numpy.random.default_rng([seed, level, index,
  attempt])``, so a mesh is a pure function of (level, index, seed): the same arguments give byte-identical
  vertices and faces and the same density.
* Sizes: level-1 families draw absolute dimensions (largest extent 0.06-0.14 m, every extent >= 0.03 m, four in
  five at most 0.045 m wide for the jaws; see `procedural_solids`); levels 2 and 3 draw the largest extent
  log-uniformly in [0.06, 0.15] m (`SIZE_RANGE`), some families in a narrower range with absolute thicknesses
  for the parts a gripper holds.
* Mass: density (drawn uniformly in the family's `Material` range) x volume, at most `MAX_MASS` = 0.6 kg (the
  seed's 0.9 kg suction payload over a safety factor of 1.5) and at least `MIN_MASS`; ``mesh.metadata`` carries
  ``density`` and ``material``, and `dexjax.sim.heap_object` uses that density.
* Every returned mesh is watertight, consistently wound with outward normals, one connected body with
  positive volume and a positive-definite inertia, has at most `MAX_FACES` faces, a largest extent in
  [`MIN_EXTENT`, `MAX_EXTENT`] metres and its bounding-box centre at the origin (the built-in objects'
  convention). A draw that fails these checks (or the mass bounds, or level 1's sizes) is redrawn with the
  next ``attempt`` (deterministic).
* Object specs: ``'procedural:L{level}/{index}'`` or ``'procedural:L{level}/{index}@{seed}'`` (e.g.
  ``'procedural:L2/17@3'``), accepted by `dexjax.objects.resolve_mesh` / `load_object_model`.
"""

from __future__ import annotations

import functools
import re

import manifold3d
import numpy as np
import trimesh

from dexjax.grippers import SUCTION_RATED_MASS_KG
from dexjax.objects.procedural_adversarial import LEVEL3_FAMILIES
from dexjax.objects.procedural_household import LEVEL2_FAMILIES
from dexjax.objects.procedural_materials import Material
from dexjax.objects.procedural_shapes import SIZE_RANGE
from dexjax.objects.procedural_shapes import Manifold
from dexjax.objects.procedural_shapes import Params
from dexjax.objects.procedural_shapes import ShapeFamily
from dexjax.objects.procedural_shapes import draw_extent
from dexjax.objects.procedural_solids import LEVEL1_EXTENT_RANGE
from dexjax.objects.procedural_solids import LEVEL1_FAMILIES
from dexjax.objects.procedural_solids import LEVEL1_MIN_THICKNESS

__all__ = [
    'PROCEDURAL_PREFIX', 'PROCEDURAL_LEVELS', 'PROCEDURAL_VERSION', 'MAX_RANGE_COUNT', 'MIN_EXTENT', 'MAX_EXTENT',
    'MAX_FACES', 'MAX_MASS', 'MIN_MASS',
    'procedural_families', 'procedural_material', 'procedural_params', 'procedural_mesh', 'procedural_spec',
    'procedural_specs', 'parse_procedural_spec', 'procedural_spec_mesh', 'procedural_mesh_problems',
]

PROCEDURAL_PREFIX: str = 'procedural:'
"""Prefix of procedural object specs, e.g. ``'procedural:L2/17@3'``."""

PROCEDURAL_LEVELS: tuple[int, ...] = (1, 2, 3)
"""The difficulty levels."""

PROCEDURAL_VERSION: int = 6
"""Version of the procedural object sets: a spec names another object when this changes, so a dataset's
fingerprint (`dexjax.generate.fingerprint`) includes it and no run resumes with other objects. 2: level 1 of
household size with masses from materials (2026-12-05); 3: level-1 round solids >= 4 cm across (2026-12-06);
4: level-1 flat faces >= the cup (rounded boxes' flats, prisms of 4 or 6 faces; 2026-12-06); 5: level-2 vessels of
plastic or melamine instead of porcelain (2026-12-07); 6: level-1 flat faces >= 3 cm, 1.5 x the cup (2026-12-07)."""

MAX_RANGE_COUNT: int = 100_000
"""Most objects one procedural range (``'procedural:L1/0:100000'``) or `procedural_specs` call may name: a larger
count is refused before any work (preparing 100,000 objects already takes days; a typo such as
``'procedural:L1/0:99999999999'`` would otherwise fill the memory with spec strings)."""

MIN_EXTENT: float = SIZE_RANGE[0]
"""Smallest allowed largest extent of a procedural object, metres (0.06)."""

MAX_EXTENT: float = SIZE_RANGE[1]
"""Largest allowed largest extent of a procedural object, metres (0.15)."""

MAX_FACES: int = 5000
"""Face-count cap of a procedural mesh (keeps the signed distance build fast)."""

MAX_MASS: float = SUCTION_RATED_MASS_KG
"""Heaviest procedural object, kg (0.6): the seed's suction payload (about 0.9 kg) over the safety factor 1.5 that
Schmalz quotes from the German accident-prevention regulation (UVV) for vacuum grippers
(`dexjax.grippers.SUCTION_RATED_MASS_KG`), so that the cup can lift every object by construction."""

MIN_MASS: float = 0.01
"""Lightest procedural object, kg (the lower clip of the default mass rule, `dexjax.sim.DEFAULT_MASS_RANGE`)."""

_MAX_ATTEMPTS = 40
_EXTENT_TOLERANCE = 1e-9  # metres: rounding of the rescaled vertices.
_MIN_RELATIVE_VOLUME = 1e-3  # volume >= this * extent^3.
_MIN_RELATIVE_INERTIA = 1e-6  # unit-mass principal moments >= this * extent^2.
_SPEC_PATTERN = re.compile(r'L([0-9])/(0|[1-9][0-9]*)(?:@(0|[1-9][0-9]*))?')  # No signs, no leading zeros.
_SPEC_FORM = "'procedural:L{level}/{index}' or 'procedural:L{level}/{index}@{seed}'"

_FAMILIES: dict[int, tuple[ShapeFamily, ...]] = {1: LEVEL1_FAMILIES, 2: LEVEL2_FAMILIES, 3: LEVEL3_FAMILIES}


def procedural_families(level: int) -> tuple[str, ...]:
  """Names of the shape families of ``level``; object ``index`` belongs to family ``index % len(...)``."""
  return tuple(family.name for family in _families(level))


def procedural_material(level: int, index: int, seed: int = 0) -> Material:
  """The `Material` (name, density range in kg/m^3, source) of procedural object ``index`` of ``level``."""
  return _family(level, index, seed).material


def procedural_params(level: int, index: int, seed: int = 0, attempt: int = 0) -> tuple[str, Params]:
  """Draws the parameters of one procedural object without building it (cheap).

  Args:
    level: difficulty level, 1, 2 or 3.
    index: object index, >= 0.
    seed: object-set seed, >= 0.
    attempt: redraw counter (0 for the first draw; `procedural_mesh` uses the first draw that validates).

  Returns:
    (family name, parameters): ``parameters['extent']`` is the largest extent in metres (drawn by the family
    when it returns one, else log-uniformly in `SIZE_RANGE`), ``parameters['density']`` the density in
    kg/m^3 (uniform in the family's material range, drawn last); the rest are the family's parameters in
    model units (largest dimension ~1) and degrees.
  """
  family = _family(level, index, seed)
  rng = np.random.default_rng([seed, level, index, attempt])
  params = dict(family.draw(rng))
  if 'extent' not in params:
    params['extent'] = draw_extent(rng)
  params['density'] = float(rng.uniform(*family.material.density))
  return family.name, params


def procedural_mesh(level: int, index: int, seed: int = 0) -> trimesh.Trimesh:
  """Generates procedural object ``index`` of difficulty ``level`` (a pure function of its arguments).

  Args:
    level: difficulty level, 1 (prismatic / circular solids), 2 (household-like) or 3 (adversarial).
    index: object index, >= 0 (unbounded; parameters are drawn per index).
    seed: object-set seed, >= 0.

  Returns:
    A fresh watertight, outward-wound `trimesh.Trimesh` in metres with its bounding-box centre at the
    origin; ``mesh.metadata`` holds ``name`` (the spec), ``family``, ``attempt``, ``material`` (its name) and
    ``density`` (kg/m^3; the mass is ``density * mesh.volume``, within [`MIN_MASS`, `MAX_MASS`]).

  Raises:
    ValueError: a level outside 1-3 or a negative index / seed.
    RuntimeError: no valid draw in 40 attempts (not seen in 15,000 objects; the message names the spec).
  """
  vertices, faces, family, attempt, density = _procedural_arrays(*_checked(level, index, seed))
  mesh = trimesh.Trimesh(vertices=vertices.copy(), faces=faces.copy(), process=False)
  mesh.metadata.update(name=procedural_spec(level, index, seed), family=family, attempt=attempt,
                       material=procedural_material(level, index, seed).name, density=density)
  return mesh


def procedural_spec(level: int, index: int, seed: int = 0) -> str:
  """The object spec of a procedural object: ``'procedural:L{level}/{index}'`` plus ``'@{seed}'`` if seed != 0."""
  level, index, seed = _checked(level, index, seed)
  suffix = f'@{seed}' if seed else ''
  return f'{PROCEDURAL_PREFIX}L{level}/{index}{suffix}'


def procedural_specs(level: int, count: int, seed: int = 0) -> list[str]:
  """Specs of objects 0 .. count-1 of ``level`` (a set covering every family of the level in turn); ``count`` is at
  most `MAX_RANGE_COUNT`."""
  if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 0:
    raise ValueError(f'procedural_specs: count must be an integer >= 0, got {count!r}')
  if count > MAX_RANGE_COUNT:
    raise ValueError(f'procedural_specs: count must be at most MAX_RANGE_COUNT = {MAX_RANGE_COUNT}, got {count}')
  return [procedural_spec(level, index, seed) for index in range(int(count))]


def parse_procedural_spec(spec: str) -> tuple[int, int, int]:
  """Parses ``'procedural:L{level}/{index}[@{seed}]'`` into (level, index, seed); seed defaults to 0.

  Raises:
    ValueError: the spec is malformed or the level is not 1, 2 or 3; the message names the spec and the
      expected form.
  """
  body = spec[len(PROCEDURAL_PREFIX):] if isinstance(spec, str) and spec.startswith(PROCEDURAL_PREFIX) else None
  match = _SPEC_PATTERN.fullmatch(body) if body is not None else None
  numbers = spec_integers(match.groups()) if match is not None else None
  if numbers is None or numbers[0] not in PROCEDURAL_LEVELS:
    shown = spec if not isinstance(spec, str) or len(spec) <= 80 else f'{spec[:60]}...({len(spec)} characters)'
    raise ValueError(
        f'object spec {shown!r}: expected {_SPEC_FORM} with level 1, 2 or 3 and integers index >= 0 and '
        "seed >= 0 (e.g. 'procedural:L2/17@3')")
  level, index, seed = numbers
  return level, index, seed or 0


def spec_integers(groups: tuple[str | None, ...]) -> tuple[int | None, ...] | None:
  """The integers of a spec's matched digit groups (None for an absent group), or None when one is too long for
  Python to convert (over 4,300 digits: `sys.get_int_max_str_digits`), so that the caller reports the spec."""
  try:
    return tuple(None if g is None else int(g) for g in groups)
  except ValueError:
    return None


def procedural_spec_mesh(spec: str) -> trimesh.Trimesh:
  """The mesh of a procedural object spec (see `parse_procedural_spec`)."""
  return procedural_mesh(*parse_procedural_spec(spec))


def procedural_mesh_problems(mesh: trimesh.Trimesh, *, level: int | None = None,
                             density: float | None = None) -> list[str]:
  """Checks the guarantees of a procedural mesh; returns the violated ones in words (empty if valid).

  Args:
    mesh: the mesh, metres.
    level: with 1, also checks level 1's sizes (largest extent in `LEVEL1_EXTENT_RANGE`, every extent >=
      `LEVEL1_MIN_THICKNESS`).
    density: kg/m^3; default ``mesh.metadata['density']`` when present. With a density, also checks that the
      mass (density x volume) lies in [`MIN_MASS`, `MAX_MASS`].
  """
  problems = []
  if len(mesh.faces) > MAX_FACES:
    problems.append(f'{len(mesh.faces)} faces, expected <= {MAX_FACES}')
  if not mesh.is_watertight:
    problems.append('not watertight')
  if not mesh.is_winding_consistent:
    problems.append('inconsistent winding')
  extents = np.asarray(mesh.extents, np.float64)
  extent = float(np.max(extents))
  low, high = LEVEL1_EXTENT_RANGE if level == 1 else (MIN_EXTENT, MAX_EXTENT)
  if not low - _EXTENT_TOLERANCE <= extent <= high + _EXTENT_TOLERANCE:
    problems.append(f'largest extent {extent:.4g} m, expected within [{low}, {high}] m')
  if level == 1 and float(np.min(extents)) < LEVEL1_MIN_THICKNESS - _EXTENT_TOLERANCE:
    problems.append(f'smallest extent {float(np.min(extents)):.4g} m, expected >= {LEVEL1_MIN_THICKNESS} m')
  centre = 0.5 * (mesh.bounds[0] + mesh.bounds[1])
  if np.abs(centre).max() > 1e-9:
    problems.append(f'bounding-box centre {centre.tolist()}, expected the origin')
  if problems:  # The remaining checks need a closed, oriented surface.
    return problems
  volume = float(mesh.volume)
  if not volume > _MIN_RELATIVE_VOLUME * extent**3:
    problems.append(f'volume {volume:.3g} m^3, expected > {_MIN_RELATIVE_VOLUME} * extent^3 (outward faces)')
    return problems
  if mesh.body_count != 1:
    problems.append(f'{mesh.body_count} separate bodies, expected one')
  moments = np.linalg.eigvalsh(np.asarray(mesh.moment_inertia) / mesh.mass)
  if not moments.min() > _MIN_RELATIVE_INERTIA * extent**2:
    problems.append(f'unit-mass principal moments {moments.tolist()} m^2 are not positive')
  density = mesh.metadata.get('density') if density is None else density
  if density is not None and not MIN_MASS <= density * volume <= MAX_MASS:
    problems.append(f'mass {density * volume:.4g} kg (density {density:.4g} kg/m^3 x volume {volume:.4g} m^3), '
                    f'expected within [{MIN_MASS}, {MAX_MASS}] kg')
  return problems


def _families(level: int) -> tuple[ShapeFamily, ...]:
  if isinstance(level, bool) or not isinstance(level, (int, np.integer)) or int(level) not in _FAMILIES:
    raise ValueError(f'procedural object level must be 1, 2 or 3, got {level!r}')
  return _FAMILIES[int(level)]


def _family(level: int, index: int, seed: int) -> ShapeFamily:
  families = _families(level)
  return families[_checked(level, index, seed)[1] % len(families)]


def _checked(level: int, index: int, seed: int) -> tuple[int, int, int]:
  """Validates (level, index, seed) and returns them as plain ints."""
  _families(level)
  for field, value in (('index', index), ('seed', seed)):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
      raise ValueError(f'procedural object {field} must be an integer >= 0, got {value!r}')
  return int(level), int(index), int(seed)


def _scaled_mesh(solid: Manifold, extent: float) -> trimesh.Trimesh:
  """Converts a manifold to a mesh scaled to largest extent ``extent`` (m) with its box centre at the origin."""
  mesh64 = solid.to_mesh64()
  vertices = np.asarray(mesh64.vert_properties, np.float64)[:, :3]
  faces = np.asarray(mesh64.tri_verts, np.int64)
  used, faces = np.unique(faces, return_inverse=True)  # Drops vertices no face uses (e.g. on a revolve axis).
  vertices, faces = vertices[used], faces.reshape(-1, 3)
  low, high = vertices.min(axis=0), vertices.max(axis=0)
  vertices = (vertices - 0.5 * (low + high)) * (extent / float(np.max(high - low)))
  vertices -= 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))  # Exact centring after rounding.
  return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)


def _attempt(level: int, index: int, seed: int, attempt: int) -> tuple[trimesh.Trimesh | None, str]:
  """Builds one draw; returns (mesh with ``metadata['density']``, '') or (None, reason)."""
  family = _family(level, index, seed)
  _, params = procedural_params(level, index, seed, attempt)
  try:
    solid = family.build(params)
  except (ValueError, RuntimeError) as e:  # manifold3d rejects some degenerate inputs.
    return None, f'{family.name} build failed ({e})'
  if solid.status() != manifold3d.Error.NoError or solid.is_empty():
    return None, f'{family.name} build gave an invalid solid ({solid.status()})'
  pieces = len(solid.decompose())
  if pieces != 1:
    return None, f'{family.name} build gave {pieces} separate bodies'
  mesh = _scaled_mesh(solid, params['extent'])
  mesh.metadata['density'] = params['density']
  problems = procedural_mesh_problems(mesh, level=level)
  return (None, f"{family.name}: {'; '.join(problems)}") if problems else (mesh, '')


@functools.lru_cache(maxsize=64)
def _procedural_arrays(level: int, index: int, seed: int) -> tuple[np.ndarray, np.ndarray, str, int, float]:
  """(vertices (V, 3) float64 m, faces (F, 3) int64, family name, attempt, density kg/m^3) of the first valid
  draw."""
  reason = ''
  for attempt in range(_MAX_ATTEMPTS):
    mesh, reason = _attempt(level, index, seed, attempt)
    if mesh is not None:
      vertices, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
      vertices.flags.writeable = False
      faces.flags.writeable = False
      return vertices, faces, _family(level, index, seed).name, attempt, float(mesh.metadata['density'])
  raise RuntimeError(
      f'{procedural_spec(level, index, seed)}: no valid mesh after {_MAX_ATTEMPTS} draws (last: {reason})')
