"""Tests of the procedural object generator (dexjax.objects.procedural), its materials and its contact sheet."""

import dataclasses
import hashlib
import subprocess
import sys

from pathlib import Path

import igl
import matplotlib.image
import numpy as np
import pytest
import scipy.ndimage
import trimesh

from dexjax.geometry import validate_and_repair
from dexjax.objects import MAX_EXTENT
from dexjax.objects import MAX_FACES
from dexjax.objects import MAX_MASS
from dexjax.objects import MIN_EXTENT
from dexjax.objects import MIN_MASS
from dexjax.objects import builtin_mesh
from dexjax.objects import load_object_model
from dexjax.objects import parse_procedural_spec
from dexjax.objects import procedural_families
from dexjax.objects import procedural_material
from dexjax.objects import procedural_mesh
from dexjax.objects import procedural_mesh_problems
from dexjax.objects import procedural_params
from dexjax.objects import procedural_spec
from dexjax.objects import procedural_specs
from dexjax.objects import resolve_mesh
from dexjax.objects import save_contact_sheet
from dexjax.objects import procedural
from dexjax.objects.procedural_shapes import SIZE_RANGE
from dexjax.objects.procedural_shapes import box
from dexjax.objects.procedural_solids import LEVEL1_EXTENT_RANGE
from dexjax.objects.procedural_solids import LEVEL1_JAW_WIDTH
from dexjax.objects.procedural_solids import LEVEL1_MIN_FACE
from dexjax.objects.procedural_solids import LEVEL1_MIN_ROUND_DIAMETER
from dexjax.objects.procedural_solids import LEVEL1_MIN_THICKNESS
from dexjax.sim import heap_object

LEVELS = (1, 2, 3)
DISTINCT_COUNT = 1000


@pytest.fixture
def clean_cache():
  """Empties the in-process mesh cache before and after a test that patches the families."""
  procedural._procedural_arrays.cache_clear()
  yield
  procedural._procedural_arrays.cache_clear()


def _fresh_mesh(level, index, seed=0):
  """Generates a mesh bypassing the in-process cache."""
  procedural._procedural_arrays.cache_clear()
  return procedural_mesh(level, index, seed)


def _solidity(mesh):
  return mesh.volume / mesh.convex_hull.volume


def _mesh_digest(mesh):
  return (np.asarray(mesh.vertices).tobytes(), np.asarray(mesh.faces).tobytes(), repr(mesh.metadata['density']))


# ---------------------------------------------------------------------------------------------------------
# Determinism.


@pytest.mark.parametrize('level', LEVELS)
def test_same_arguments_give_identical_mesh(level):
  for index in (0, 5, 13):
    a, b = _fresh_mesh(level, index, 4), _fresh_mesh(level, index, 4)
    assert a.vertices.dtype == np.float64 and a.faces.dtype == np.int64
    assert _mesh_digest(a) == _mesh_digest(b)


def test_identical_mesh_in_a_fresh_process():
  code = ('import hashlib, numpy as np; from dexjax.objects import procedural_mesh as p; h = hashlib.sha256()\n'
          'for level, index in ((1, 3), (2, 4), (3, 6), (3, 7)):\n'
          '  m = p(level, index, 2)\n'
          '  h.update(np.asarray(m.vertices).tobytes()); h.update(np.asarray(m.faces).tobytes())\n'
          '  h.update(repr(m.metadata["density"]).encode())\n'
          'print(h.hexdigest())')
  digest = hashlib.sha256()
  for level, index in ((1, 3), (2, 4), (3, 6), (3, 7)):
    for part in _mesh_digest(_fresh_mesh(level, index, 2)):
      digest.update(part if isinstance(part, bytes) else part.encode())
  out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True, timeout=120)
  assert out.stdout.strip() == digest.hexdigest()


@pytest.mark.parametrize('level', LEVELS)
def test_different_index_or_seed_gives_different_mesh(level):
  meshes = [procedural_mesh(level, 0), procedural_mesh(level, 1), procedural_mesh(level, 0, seed=1)]
  digests = {_mesh_digest(m) for m in meshes}
  assert len(digests) == 3
  n = len(procedural_families(level))  # Same family, next cycle: still a different object.
  assert _mesh_digest(procedural_mesh(level, n)) != _mesh_digest(meshes[0])


def test_returned_mesh_is_a_fresh_copy():
  a = procedural_mesh(2, 3)
  a.apply_translation((1.0, 0.0, 0.0))
  assert np.abs(0.5 * (procedural_mesh(2, 3).bounds.sum(axis=0))).max() < 1e-9


# ---------------------------------------------------------------------------------------------------------
# Guarantees of every object.


@pytest.mark.parametrize('level', LEVELS)
def test_twenty_objects_per_level_are_valid_solids(level):
  families = set()
  for index in range(20):
    mesh = procedural_mesh(level, index, seed=11)
    families.add(mesh.metadata['family'])
    assert mesh.is_watertight, index
    assert mesh.is_winding_consistent, index
    assert mesh.volume > 0, index
    assert mesh.body_count == 1, index
    assert len(mesh.faces) <= MAX_FACES, index
    assert MIN_EXTENT - 1e-9 <= mesh.extents.max() <= MAX_EXTENT + 1e-9, index
    assert MIN_MASS <= mesh.metadata['density'] * mesh.volume <= MAX_MASS, index
    np.testing.assert_allclose(mesh.bounds.sum(axis=0), 0.0, atol=1e-12)
    inertia = np.linalg.eigvalsh(mesh.moment_inertia)
    assert inertia.min() > 0, index
    assert procedural_mesh_problems(mesh) == []
  assert families == set(procedural_families(level))


@pytest.mark.parametrize('level', LEVELS)
def test_winding_numbers_are_zero_outside_and_one_inside(level):
  # Outward orientation and no self-overlap: the generalised winding number is 0 or 1 everywhere.
  rng = np.random.default_rng(level)
  for index in range(len(procedural_families(level))):
    mesh = procedural_mesh(level, index, seed=5)
    points = rng.uniform(mesh.bounds[0], mesh.bounds[1], (2000, 3))
    winding = igl.winding_number(np.asarray(mesh.vertices), np.asarray(mesh.faces), points)
    near_integer = np.abs(winding - np.round(winding)) < 0.05
    assert near_integer.mean() > 0.95, index
    assert set(np.round(winding[near_integer]).astype(int).tolist()) <= {0, 1}, index
    assert (np.round(winding) == 1).any(), index


@pytest.mark.parametrize('level', LEVELS)
def test_meshes_pass_mesh_repair_unchanged(level):
  for index in range(len(procedural_families(level))):
    mesh = procedural_mesh(level, index)
    repaired = validate_and_repair(mesh, procedural_spec(level, index))
    assert len(repaired.faces) == len(mesh.faces)
    np.testing.assert_allclose(repaired.volume, mesh.volume, rtol=1e-9)


def test_problems_detects_bad_meshes():
  assert procedural_mesh_problems(builtin_mesh('box')) == []  # 8 cm: within the extent range.
  too_big = builtin_mesh('box')
  too_big.apply_scale(3.0)
  assert any('largest extent' in p for p in procedural_mesh_problems(too_big))
  too_small = builtin_mesh('box')
  too_small.apply_scale(0.5)
  assert any('largest extent' in p for p in procedural_mesh_problems(too_small))
  # Level 1: every extent >= 3 cm (the built-in box is 4 x 6 x 8 cm; a 2 cm slab is not).
  assert procedural_mesh_problems(builtin_mesh('box'), level=1) == []
  slab = trimesh.creation.box((0.08, 0.06, 0.02))
  assert any('smallest extent' in p for p in procedural_mesh_problems(slab, level=1))
  assert procedural_mesh_problems(slab) == []
  # Mass bounds with a density (argument or metadata): 192 cm^3 at 500 kg/m^3 is 0.096 kg.
  heavy = builtin_mesh('box')
  assert procedural_mesh_problems(heavy, density=500.0) == []
  assert any('mass' in p for p in procedural_mesh_problems(heavy, density=4000.0))  # 0.77 kg > MAX_MASS.
  assert any('mass' in p for p in procedural_mesh_problems(heavy, density=20.0))  # 3.8 g < MIN_MASS.
  heavy.metadata['density'] = 4000.0
  assert any('mass' in p for p in procedural_mesh_problems(heavy))
  open_box = builtin_mesh('box')
  open_box = trimesh.Trimesh(open_box.vertices, open_box.faces[1:], process=False)
  assert 'not watertight' in procedural_mesh_problems(open_box)
  inverted = builtin_mesh('box')
  inverted.invert()
  assert any('volume' in p for p in procedural_mesh_problems(inverted))
  two = trimesh.util.concatenate([trimesh.creation.box((0.02,) * 3), trimesh.creation.box((0.02,) * 3)])
  two.apply_translation((-0.01, 0.0, 0.0))
  two.vertices[len(two.vertices) // 2:] += (0.05, 0.0, 0.0)
  two.apply_translation(-0.5 * two.bounds.sum(axis=0))
  assert any('bodies' in p for p in procedural_mesh_problems(two))
  shifted = builtin_mesh('cube')
  shifted.apply_translation((0.01, 0.0, 0.0))
  assert any('centre' in p for p in procedural_mesh_problems(shifted))


def test_failed_draw_is_redrawn_deterministically(monkeypatch, clean_cache):
  real = procedural._FAMILIES[1][0]
  calls = []

  def flaky_build(params):
    calls.append(params['size'].tolist())
    return box((1.0, 1.0, 1e-9)) if len(calls) == 1 else real.build(params)  # First draw is flat.

  monkeypatch.setitem(procedural._FAMILIES, 1, (dataclasses.replace(real, build=flaky_build),))
  mesh = _fresh_mesh(1, 0)
  assert mesh.metadata['attempt'] == 1
  assert calls[0] != calls[1]  # The redraw used new parameters.
  assert procedural_mesh_problems(mesh, level=1) == []
  monkeypatch.setitem(procedural._FAMILIES, 1, (dataclasses.replace(real, build=lambda p: box((1.0, 1.0, 1e-9))),))
  with pytest.raises(RuntimeError, match=r'procedural:L1/0@2: no valid mesh'):
    _fresh_mesh(1, 0, 2)


def test_heavy_draw_is_redrawn(monkeypatch, clean_cache):
  # A material dense enough that a large box exceeds MAX_MASS: those draws are redrawn, lighter ones kept.
  real = procedural._FAMILIES[1][0]
  dense = dataclasses.replace(real.material, density=(3000.0, 3000.0))
  monkeypatch.setitem(procedural._FAMILIES, 1, (dataclasses.replace(real, material=dense),))
  attempts = []
  for index in range(12):
    mesh = _fresh_mesh(1, index)
    attempts.append(mesh.metadata['attempt'])
    assert mesh.metadata['density'] == 3000.0
    assert 3000.0 * mesh.volume <= MAX_MASS
    for attempt in range(mesh.metadata['attempt']):  # Every rejected draw was too heavy.
      _, params = procedural_params(1, index, 0, attempt)
      assert 3000.0 * np.prod(params['size'] * params['extent']) > MAX_MASS
  assert max(attempts) > 0


# ---------------------------------------------------------------------------------------------------------
# Household sizes, materials and masses.

SIZE_COUNT = 300


def test_level1_objects_are_household_boxes_and_cylinders():
  assert procedural_families(1) == ('box', 'cylinder', 'rounded_box', 'prism', 'frustum', 'ball')
  widths = []
  for seed in (0, 1):
    for index in range(SIZE_COUNT):
      mesh = procedural_mesh(1, index, seed)
      extents = np.sort(mesh.extents)
      assert extents[0] >= LEVEL1_MIN_THICKNESS - 1e-9, (index, seed, extents)
      family = procedural_families(1)[index % 6]
      if family in ('cylinder', 'frustum'):  # round: the base is >= 4 cm across
        assert extents[1] >= LEVEL1_MIN_ROUND_DIAMETER - 1e-9, (index, seed, extents)
      if family == 'frustum':  # and so is the top: the cup seals along a lying frustum's whole side
        _, params = procedural_params(1, index, seed, mesh.metadata['attempt'])
        top = params['diameter'] * params['top_over_bottom'] * params['extent']
        assert LEVEL1_MIN_ROUND_DIAMETER - 1e-9 <= top <= params['diameter'] * params['extent'] + 1e-9, (index, seed)
      assert LEVEL1_EXTENT_RANGE[0] - 1e-9 <= extents[2] <= LEVEL1_EXTENT_RANGE[1] + 1e-9, (index, seed, extents)
      widths.append(extents[1])
  assert (LEVEL1_MIN_THICKNESS, LEVEL1_EXTENT_RANGE, LEVEL1_JAW_WIDTH) == (0.03, (0.06, 0.14), 0.045)
  # Most fit between the 5 cm jaws across their width (the second-largest extent); balls and a fifth of the
  # others (flat boxes, tuna cans) do not.
  assert 0.65 < np.mean(np.asarray(widths) <= LEVEL1_JAW_WIDTH + 1e-9) < 0.85


def _facet_widths(mesh, min_area=2e-5):
  """Narrower in-plane side (metres) of the largest planar facet of ``mesh`` facing each distinct direction, over
  the facets above ``min_area`` m^2 (the bevels of a rounded box's edges are many strips facing other ways)."""
  best = {}
  for facet, normal, area in zip(mesh.facets, mesh.facets_normal, mesh.facets_area):
    if area < min_area:
      continue
    points = mesh.vertices[np.unique(mesh.faces[facet])]
    points = points - points.mean(axis=0)
    in_plane = points - np.outer(points @ normal, normal)
    axes = np.linalg.svd(in_plane, full_matrices=False)[2][:2]  # the facet's in-plane principal axes
    key = tuple(np.round(normal, 2))
    if area > best.get(key, (0.0, 0.0))[0]:
      best[key] = (area, float(np.min(np.ptp(in_plane @ axes.T, axis=0))))
  return [width for _, width in best.values()]


def test_level1_flat_faces_are_wider_than_the_cup():
  """Rounded boxes keep a flat of >= 3 cm on every face; prisms have 4 or 6 faces around, each >= 3 cm wide (an
  odd prism lying on a face shows the cup a ridge)."""
  families = procedural_families(1)
  for index in range(120):
    name = families[index % 6]
    if name not in ('rounded_box', 'prism'):
      continue
    mesh = procedural_mesh(1, index)
    widths = _facet_widths(mesh)
    if name == 'prism':
      assert len(widths) in (6, 8), (index, len(widths))  # two caps and 4 or 6 sides
    flats = sorted(widths)[-6:] if name == 'rounded_box' else widths  # the six flats, wider than the bevels
    assert min(flats) >= LEVEL1_MIN_FACE - 1e-4, (index, name, widths)
  assert LEVEL1_MIN_FACE == 0.03


@pytest.mark.parametrize('level', LEVELS)
def test_masses_come_from_the_family_material_and_stay_liftable(level):
  masses, extents = [], []
  for index in range(SIZE_COUNT if level == 1 else 150):
    mesh = procedural_mesh(level, index)
    material = procedural_material(level, index)
    density = mesh.metadata['density']
    assert mesh.metadata['material'] == material.name
    assert material.density[0] <= density <= material.density[1], (index, material, density)
    _, params = procedural_params(level, index, 0, mesh.metadata['attempt'])
    assert params['density'] == density  # Drawn with the object's parameters.
    mass = heap_object(mesh).mass  # What the physics gets: the object's own density, not clipped.
    assert mass == pytest.approx(density * mesh.volume, rel=1e-9)
    masses.append(mass)
    extents.append(mesh.extents.max())
  assert MIN_MASS <= min(masses) and max(masses) <= MAX_MASS == 0.6
  assert 0.05 < np.median(masses) < 0.25  # Household weights (the reward's Gamma prior has median 0.19 kg).
  low, high = LEVEL1_EXTENT_RANGE if level == 1 else SIZE_RANGE
  assert low - 1e-9 <= min(extents) and max(extents) <= high + 1e-9
  assert np.median(extents) > 0.08  # Not mostly tiny.


def test_every_family_has_a_documented_material():
  docs = (Path(__file__).resolve().parents[1] / 'docs' / 'objects.md').read_text()
  for level in LEVELS:
    for index, family in enumerate(procedural_families(level)):
      material = procedural_material(level, index)
      assert material.source and material.name
      rows = [line for line in docs.splitlines() if line.startswith(f'| `{family}` |') and material.name in line]
      low, high = material.density
      assert any(f'{low:g}–{high:g}' in row for row in rows), (family, material)


def _top_disc_diameter(mesh):
  """Diameter (m) of the largest disc inside one upward planar facet (normal within 20 degrees of +z)."""
  best, resolution = 0.0, 0.0005
  groups = [list(g) for g in mesh.facets] + [[f] for f in range(len(mesh.faces))]
  for group, normal in zip(groups, list(mesh.facets_normal) + list(mesh.face_normals)):
    triangles = mesh.vertices[mesh.faces[group]][:, :, :2]
    low, high = triangles.reshape(-1, 2).min(axis=0), triangles.reshape(-1, 2).max(axis=0)
    if normal[2] < np.cos(np.radians(20)) or min(high - low) < 0.02:
      continue
    axes = [np.arange(low[i] - resolution, high[i] + 2 * resolution, resolution) for i in range(2)]
    points = np.stack(np.meshgrid(*axes, indexing='ij'), axis=-1).reshape(-1, 2)
    inside = np.zeros(len(points), bool)
    for a, b, c in triangles:
      (u, v), scale = np.linalg.solve(np.c_[b - a, c - a], (points - a).T), 1e-9
      inside |= (u >= -scale) & (v >= -scale) & (u + v <= 1 + scale)
    distance = scipy.ndimage.distance_transform_edt(inside.reshape(len(axes[0]), len(axes[1])))
    best = max(best, 2 * resolution * float(distance.max()))
  return best


@pytest.mark.parametrize('level', LEVELS)
def test_no_object_is_too_thin_for_the_jaws_and_too_narrow_for_the_cup(level):
  # In its most stable resting pose, an object stands >= 2 cm high (the jaws' fingers reach 1 cm below the grasp
  # centre) or offers a flat upward face holding a 2 cm disc (the seed's suction cup).
  for index in range(2 * len(procedural_families(level))):
    mesh = procedural_mesh(level, index)
    poses, probabilities = trimesh.poses.compute_stable_poses(mesh, n_samples=1, threshold=0.0)
    mesh.apply_transform(poses[int(np.argmax(probabilities))])
    assert mesh.extents[2] >= 0.02 or _top_disc_diameter(mesh) >= 0.02, (index, mesh.metadata['family'])


# ---------------------------------------------------------------------------------------------------------
# Distinctness and difficulty.


def _parameter_key(level, index):
  family, params = procedural_params(level, index)
  values = []
  for key in sorted(params):
    value = params[key]
    values.append(str(value) if isinstance(value, str) else np.round(np.asarray(value, np.float64), 12).tobytes())
  return family, tuple(values)


@pytest.mark.parametrize('level', LEVELS)
def test_thousand_objects_per_level_are_distinct(level):
  keys = {_parameter_key(level, index) for index in range(DISTINCT_COUNT)}
  assert len(keys) == DISTINCT_COUNT
  # Built meshes: all distinct with their size, and nearly all in shape alone (scale-invariant; level 1
  # has spheres, which differ only in size).
  sized, shapes = set(), set()
  for index in range(DISTINCT_COUNT):
    mesh = procedural_mesh(level, index)
    extent = mesh.extents.max()
    shape = (tuple(np.round(np.sort(mesh.extents) / extent, 6)), round(mesh.volume / extent**3, 6),
             round(mesh.area / extent**2, 6))
    shapes.add(shape)
    sized.add(shape + (round(extent, 9),))
  assert len(sized) == DISTINCT_COUNT
  assert len(shapes) >= 0.95 * DISTINCT_COUNT


def test_levels_get_less_solid():
  # Full cycles through each level's families: 4 x 6, 4 x 6 and 3 x 9 objects.
  means = {level: np.mean([_solidity(procedural_mesh(level, i)) for i in range(count)])
           for level, count in ((1, 24), (2, 24), (3, 27))}
  assert means[1] > 0.99  # Level 1 is convex.
  assert means[2] < means[1] - 0.2
  assert means[3] < means[2] - 0.05


# ---------------------------------------------------------------------------------------------------------
# Specs.


def test_spec_round_trip_and_resolver():
  assert parse_procedural_spec('procedural:L2/17@3') == (2, 17, 3)
  assert parse_procedural_spec('procedural:L1/5') == (1, 5, 0)
  assert procedural_spec(2, 17, 3) == 'procedural:L2/17@3'
  assert procedural_specs(3, 3) == ['procedural:L3/0', 'procedural:L3/1', 'procedural:L3/2']
  assert procedural_specs(2, 2, seed=3) == ['procedural:L2/0@3', 'procedural:L2/1@3']
  mesh, name = resolve_mesh('procedural:L2/17@3')
  assert name == 'procedural:L2/17@3'
  assert _mesh_digest(mesh) == _mesh_digest(procedural_mesh(2, 17, 3))
  scaled, _ = resolve_mesh('procedural:L2/17@3', scale=2.0)
  np.testing.assert_allclose(scaled.vertices, 2.0 * mesh.vertices)


@pytest.mark.parametrize('spec', [
    'procedural:L4/1', 'procedural:L0/1', 'procedural:L2/-1', 'procedural:L2/x', 'procedural:L2/17@',
    'procedural:2/17', 'procedural:L2/017', 'procedural:L2/1@-3', 'procedural:L2', 'procedural:',
    'procedural:L2/1 ',
])
def test_malformed_spec_is_rejected_with_expected_form(spec):
  with pytest.raises(ValueError) as info:
    resolve_mesh(spec)
  assert repr(spec) in str(info.value)
  assert "'procedural:L{level}/{index}'" in str(info.value)


@pytest.mark.parametrize('call', [
    lambda: procedural_mesh(4, 0), lambda: procedural_mesh(1, -1), lambda: procedural_mesh(1, 0, -2),
    lambda: procedural_mesh(True, 0), lambda: procedural_specs(1, -1), lambda: procedural_mesh(1, 1.5),
])
def test_bad_arguments_are_rejected(call):
  with pytest.raises(ValueError, match='level|index|seed|count'):
    call()


def test_load_object_model_builds_a_procedural_object(tmp_path):
  model = load_object_model('procedural:L1/5', cache_dir=tmp_path, grid_size=32, num_surface_samples=256)
  mesh = procedural_mesh(1, 5)
  np.testing.assert_allclose(float(model.volume), mesh.volume, rtol=1e-5)


# ---------------------------------------------------------------------------------------------------------
# Contact sheet.


def test_contact_sheet_writes_png_of_the_right_grid(tmp_path):
  path = tmp_path / 'sheet.png'
  save_contact_sheet(path, levels=(1, 3), per_level=3, seed=1, cell_pixels=64)
  image = matplotlib.image.imread(path)
  assert image.shape[:2] == (2 * 64, 3 * 64)
  for row in range(2):
    for col in range(3):
      cell = image[row * 64:(row + 1) * 64, col * 64:(col + 1) * 64, :3]
      assert (cell.min(axis=2) < 0.8).mean() > 0.03, (row, col)  # Something drawn in every cell.


def test_contact_sheet_rejects_bad_arguments(tmp_path):
  with pytest.raises(ValueError, match='per_level'):
    save_contact_sheet(tmp_path / 'x.png', per_level=0)
  with pytest.raises(ValueError, match='level'):
    save_contact_sheet(tmp_path / 'x.png', levels=(4,), per_level=1)
