"""Tests for the mesh-folder loader, `prepare_object` caching and ``python -m dexjax.objects`` (check, masses,
preview)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import scipy.stats
import trimesh

from dexjax.geometry import cache as cache_mod
from dexjax.objects import load_mesh_folder, prepare_object
from dexjax.objects import collision as collision_mod
from dexjax.objects import folder as folder_mod
from dexjax.objects.__main__ import main

GOOD = ['box', 'cylinder', 'open', 'scene', 'sphere']  # 'open' loads with an ImperfectMeshWarning
BAD = {  # file -> words the reason must contain
    'empty.obj': 'empty file',
    'flat.obj': 'zero volume',
    'garbage.ply': 'could not be read as PLY',
    'nan.obj': 'NaN',
    'notes.xyz': 'unsupported extension .xyz; expected one of .obj, .stl, .ply, .glb',
}


def _write_good(directory, unit: float = 1.0) -> None:
  """Box (OBJ), cylinder (STL), sphere (PLY) and a two-box scene (GLB); sizes in metres times 1 / unit."""
  s = 1.0 / unit
  trimesh.creation.box((0.05 * s, 0.04 * s, 0.03 * s)).export(directory / 'box.obj')
  trimesh.creation.cylinder(0.02 * s, 0.05 * s, sections=32).export(directory / 'cylinder.stl')
  trimesh.creation.icosphere(2, radius=0.03 * s).export(directory / 'sphere.ply')
  scene = trimesh.Scene()
  for x in (-0.03, 0.03):
    scene.add_geometry(trimesh.creation.box((0.02 * s,) * 3),
                       transform=trimesh.transformations.translation_matrix([x * s, 0, 0]))
  scene.export(directory / 'scene.glb')


def _write_bad(directory) -> None:
  (directory / 'empty.obj').write_bytes(b'')
  (directory / 'nan.obj').write_text('v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n')
  (directory / 'flat.obj').write_text('v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n')
  (directory / 'notes.xyz').write_text('0 0 0\n')
  (directory / 'garbage.ply').write_bytes(np.random.default_rng(0).bytes(700))
  (directory / 'box.mtl').write_text('newmtl x\n')  # Companion file: skipped.
  (directory / '.DS_Store').write_bytes(b'\x00')  # Hidden file: skipped.


def _write_imperfect(directory) -> None:
  cylinder = trimesh.creation.cylinder(0.02, 0.05, sections=32)
  open_top = cylinder.faces[cylinder.face_normals[:, 2] < 0.9]  # A 32-edge hole: too large to fill.
  trimesh.Trimesh(cylinder.vertices, open_top, process=False).export(directory / 'open.stl')


@pytest.fixture
def mixed(tmp_path):
  directory = tmp_path / 'objects'
  directory.mkdir()
  _write_good(directory)
  _write_imperfect(directory)
  _write_bad(directory)
  return directory


def test_mixed_folder_loads_the_good_and_explains_the_bad(mixed):
  report = load_mesh_folder(mixed)
  assert [o.name for o in report.loaded] == GOOD
  assert [r.file for r in report.rejected] == sorted(BAD)
  for rejection in report.rejected:
    assert BAD[rejection.file] in rejection.reason, rejection
  by_name = {o.name: o for o in report.loaded}
  for obj in report.loaded:
    assert obj.mesh.is_watertight and obj.mesh.volume > 0
    assert os.path.samefile(os.path.dirname(obj.path), mixed)
  np.testing.assert_allclose(by_name['box'].mesh.extents, [0.05, 0.04, 0.03], rtol=1e-6)
  # GLB scene: both boxes, placed by their node transforms, in one mesh.
  np.testing.assert_allclose(by_name['scene'].mesh.volume, 2 * 0.02**3, rtol=1e-5)
  np.testing.assert_allclose(by_name['scene'].mesh.extents, [0.08, 0.02, 0.02], rtol=1e-5)
  assert by_name['scene'].mesh.body_count == 2
  # The open cylinder: loaded as the solid its winding number encloses, with the warning kept.
  assert [o.name for o in report.loaded if o.warnings] == ['open']
  assert 'open.stl' in str(by_name['open'].warnings[0]) and '32 open edges' in str(by_name['open'].warnings[0])
  np.testing.assert_allclose(by_name['open'].mesh.volume, np.pi * 0.02**2 * 0.05, rtol=0.02)


def test_millimetre_folder_scaled_to_metres(tmp_path):
  _write_good(tmp_path, unit=0.001)
  report = load_mesh_folder(tmp_path, scale=0.001)
  assert [o.name for o in report.loaded] == [g for g in GOOD if g != 'open'] and not report.rejected
  box = next(o for o in report.loaded if o.name == 'box')
  np.testing.assert_allclose(box.mesh.extents, [0.05, 0.04, 0.03], rtol=1e-6)
  with pytest.raises(ValueError, match='scale: expected a finite number > 0'):
    load_mesh_folder(tmp_path, scale=-1.0)


def test_unexpected_exception_becomes_a_rejection(mixed, monkeypatch):
  real = folder_mod.load_mesh

  def flaky(path, **kwargs):
    if path.endswith('sphere.ply'):
      raise RuntimeError('boom')
    return real(path, **kwargs)

  monkeypatch.setattr(folder_mod, 'load_mesh', flaky)
  report = load_mesh_folder(mixed)
  assert [o.name for o in report.loaded] == ['box', 'cylinder', 'open', 'scene']
  assert {r.file: r.reason for r in report.rejected}['sphere.ply'] == 'RuntimeError: boom'


def test_recursive_and_ambiguous_names(tmp_path):
  (tmp_path / 'sub').mkdir()
  (tmp_path / '.hidden').mkdir()
  trimesh.creation.box((0.02,) * 3).export(tmp_path / 'sub' / 'cube.obj')
  trimesh.creation.box((0.02,) * 3).export(tmp_path / '.hidden' / 'cube.obj')
  trimesh.creation.box((0.03,) * 3).export(tmp_path / 'mug.obj')
  trimesh.creation.box((0.03,) * 3).export(tmp_path / 'mug.stl')
  assert [o.name for o in load_mesh_folder(tmp_path).loaded] == ['mug.obj', 'mug.stl']
  assert [o.name for o in load_mesh_folder(tmp_path, recursive=True).loaded] == ['mug.obj', 'mug.stl', 'sub/cube']
  with pytest.raises(FileNotFoundError, match='missing'):
    load_mesh_folder(tmp_path / 'missing')
  with pytest.raises(NotADirectoryError, match='mug.obj'):
    load_mesh_folder(tmp_path / 'mug.obj')


def test_check_json_shape_and_exit_codes(mixed, tmp_path, capsys):
  assert main(['check', str(mixed), '--json']) == 0
  out = json.loads(capsys.readouterr().out)
  assert list(out) == ['loaded', 'rejected', 'warnings']
  assert out['loaded'] == GOOD
  assert [w['name'] for w in out['warnings']] == ['open'] and 'winding number' in out['warnings'][0]['warning']
  assert [sorted(r) for r in out['rejected']] == [['file', 'reason']] * len(BAD)
  assert {r['file']: BAD[r['file']] in r['reason'] for r in out['rejected']} == {f: True for f in BAD}

  only_bad = tmp_path / 'bad'
  only_bad.mkdir()
  _write_bad(only_bad)
  assert main(['check', str(only_bad), '--json']) == 1
  out = json.loads(capsys.readouterr().out)
  assert out['loaded'] == [] and len(out['rejected']) == len(BAD)

  mm = tmp_path / 'mm'
  mm.mkdir()
  _write_good(mm, unit=0.001)
  assert main(['check', str(mm), '--json', '--scale', '0.001']) == 0
  assert json.loads(capsys.readouterr().out)['loaded'] == [g for g in GOOD if g != 'open']

  assert main(['check', str(mixed)]) == 0  # Human-readable report.
  text = capsys.readouterr().out
  assert 'notes.xyz' in text and 'unsupported extension' in text and '5 loaded (1 with warnings), 5 rejected' in text
  assert 'warning' in text and 'open edges' in text


def test_check_missing_directory_is_a_usage_error(tmp_path):
  missing = tmp_path / 'no_such_dir'
  result = subprocess.run([sys.executable, '-m', 'dexjax.objects', 'check', str(missing), '--json'],
                          capture_output=True, text=True, timeout=120)
  assert result.returncode == 2
  assert str(missing) in result.stderr and 'does not exist' in result.stderr
  assert result.stdout == ''


def test_prepare_object_cache_hit_then_miss_on_changed_content(tmp_path, monkeypatch):
  builds, decompositions = [], []
  real_build, real_hulls = cache_mod.build_object_model, collision_mod.collision_hulls
  monkeypatch.setattr(cache_mod, 'build_object_model', lambda mesh, **kw: builds.append(1) or real_build(mesh, **kw))
  monkeypatch.setattr(collision_mod, 'collision_hulls',
                      lambda mesh, **kw: decompositions.append(1) or real_hulls(mesh, **kw))
  folder, cache = tmp_path / 'objects', tmp_path / 'cache'
  folder.mkdir()
  trimesh.creation.box((0.05, 0.04, 0.03)).export(folder / 'box.obj')
  kwargs = dict(cache_dir=cache, grid_size=16, num_surface_samples=32)

  (loaded,) = load_mesh_folder(folder).loaded
  first = prepare_object(loaded, **kwargs)
  assert (len(builds), len(decompositions)) == (1, 1)
  assert first.name == 'box' and first.source == loaded.path and first.mesh is loaded.mesh
  np.testing.assert_allclose(float(first.model.volume), 0.05 * 0.04 * 0.03, rtol=1e-4)
  assert len(first.hulls) == 1 and first.hulls[0].shape == (8, 3)
  entries = sorted(p.name for p in cache.iterdir())

  (loaded,) = load_mesh_folder(folder).loaded  # A fresh load of the same file: same key, no rebuild.
  second = prepare_object(loaded, **kwargs)
  assert (len(builds), len(decompositions)) == (1, 1)
  assert sorted(p.name for p in cache.iterdir()) == entries
  np.testing.assert_array_equal(np.asarray(second.model.sdf), np.asarray(first.model.sdf))
  np.testing.assert_array_equal(second.hulls[0], first.hulls[0])

  trimesh.creation.box((0.06, 0.04, 0.03)).export(folder / 'box.obj')  # Edited file: new entries.
  (loaded,) = load_mesh_folder(folder).loaded
  third = prepare_object(loaded, **kwargs)
  assert (len(builds), len(decompositions)) == (2, 2)
  np.testing.assert_allclose(float(third.model.volume), 0.06 * 0.04 * 0.03, rtol=1e-4)
  assert len([p for p in cache.iterdir() if p.suffix == '.npz']) == 2
  assert len(list((cache / 'hulls').iterdir())) == 2


def test_preview_command_calls_the_contact_sheet(tmp_path, monkeypatch, capsys):
  from dexjax.objects import preview
  calls = []
  monkeypatch.setattr(preview, 'save_contact_sheet', lambda path, **kw: calls.append((path, kw)))
  out = str(tmp_path / 'sheet.png')
  assert main(['--preview', out, '--per-level', '2', '--seed', '7']) == 0
  assert calls == [(out, {'levels': (1, 2, 3), 'per_level': 2, 'seed': 7})]
  assert out in capsys.readouterr().out
  assert main(['--preview', out, '--per-level', '0']) == 2
  assert main(['--preview', out, 'check', str(tmp_path)]) == 2
  assert main([]) == 2


def test_preview_writes_a_png(tmp_path):
  out = tmp_path / 'sheet.png'
  assert main(['--preview', str(out), '--per-level', '1', '--seed', '3']) == 0
  assert out.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_masses_command_matches_the_heap_physics(tmp_path, capsys):
  from dexjax.objects import load_object_set, prepare_object_set
  from dexjax.sim import heap_objects
  assert main(['masses', 'procedural:L1/0:6', 'builtin:box', '--json']) == 0
  out = json.loads(capsys.readouterr().out)
  assert list(out) == ['objects', 'summary', 'prior', 'max_mass', 'rejected']
  report = load_object_set(['procedural:L1/0:6', 'builtin:box'])
  prepared, rejected = prepare_object_set(report, cache_dir=tmp_path, model=False)
  assert not rejected
  physics = {o.name: o.mass for o in heap_objects(prepared)}
  assert [o['name'] for o in out['objects']] == list(physics)
  for row in out['objects']:
    assert row['mass'] == pytest.approx(physics[row['name']], rel=1e-12)
    assert row['extents'] == sorted(row['extents'])
  procedural_rows = out['objects'][:6]
  assert [r['family'] for r in procedural_rows] == ['box', 'cylinder', 'rounded_box', 'prism', 'frustum', 'ball']
  assert all(r['material'] and r['mass'] == pytest.approx(r['density'] * r['volume']) for r in procedural_rows)
  box = out['objects'][6]
  assert (box['family'], box['material'], box['density']) == (None, None, 500.0)
  masses = np.array(list(physics.values()))
  assert out['summary']['count'] == 7 and out['summary']['median'] == pytest.approx(np.median(masses))
  assert out['summary']['above_prior_mean'] == pytest.approx(np.mean(masses > 0.25))
  assert out['max_mass'] == 0.6 and out['summary']['above_max_mass'] == 0.0
  prior = out['prior']  # Gamma, mean 0.25 kg, variance 0.05 kg^2: shape 1.25, scale 0.2 kg.
  assert prior['sd'] == pytest.approx(0.05**0.5)
  assert prior['median'] == pytest.approx(scipy.stats.gamma(1.25, scale=0.2).median())
  assert prior['above_max_mass'] == pytest.approx(scipy.stats.gamma(1.25, scale=0.2).sf(0.6))

  assert main(['masses', 'procedural:L1/0:6']) == 0  # The human-readable table: one line per object, a summary.
  lines = capsys.readouterr().out.splitlines()
  assert lines[0].split()[:3] == ['name', 'family', 'material'] and len(lines) == 1 + 6 + 2
  assert lines[1].startswith('procedural:L1/0 ') and 'boxed goods' in lines[1]
  assert f"{physics['procedural:L1/0']:.3f}" in lines[1]
  assert lines[7].startswith('6 objects: mean') and 'above MAX_MASS 0.6 kg' in lines[7]
  assert lines[8].startswith('prior (Gamma, mean 0.25 kg, sd 0.224 kg)')


def test_masses_command_bad_sources(tmp_path, capsys):
  for source, words in (('procedural:L9/0', "'procedural:L{level}/{index}'"),
                        ('procedural:L1/4:2', '0 <= start <= stop'),
                        (str(tmp_path / 'missing.obj'), 'missing.obj: file not found'),
                        ('builtin:nope', "unknown builtin object 'nope'")):
    assert main(['masses', 'procedural:L1/0', source]) == 2, source
    err = capsys.readouterr().err
    assert err.startswith('error: ') and words in err and len(err.strip().splitlines()) == 1, err
  empty = tmp_path / 'empty'
  empty.mkdir()
  (empty / 'broken.obj').write_bytes(b'')
  assert main(['masses', str(empty)]) == 1  # A folder whose only file is broken: nothing to weigh.
  err = capsys.readouterr().err
  assert 'broken.obj' in err and 'could be loaded' in err
  result = subprocess.run([sys.executable, '-m', 'dexjax.objects', 'masses', 'procedural:L1/x'],
                          capture_output=True, text=True, timeout=120)
  assert result.returncode == 2 and not result.stdout
  assert "error: procedural:L1/x: object spec 'procedural:L1/x': expected" in result.stderr
