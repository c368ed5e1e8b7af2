"""Object sets (built-ins, procedural ranges, files, folders), heap pictures and ``python -m dexjax.sim``."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

import dexjax.sim as sim
from dexjax.objects import BUILTIN_OBJECTS, expand_object_sources, load_object_set, prepare_object_set
from dexjax.objects import procedural_mesh
from dexjax.sim.__main__ import main as sim_main


def test_expand_sources():
  assert expand_object_sources(['procedural:L2/3:6@4']) == [
      'procedural:L2/3@4', 'procedural:L2/4@4', 'procedural:L2/5@4']
  assert expand_object_sources(['procedural:L1/0:0']) == []
  assert expand_object_sources(['builtin:all']) == [f'builtin:{n}' for n in BUILTIN_OBJECTS]
  assert expand_object_sources(['a/b.obj', 'procedural:L3/7']) == ['a/b.obj', 'procedural:L3/7']
  for bad in ('procedural:L4/0:3', 'procedural:L1/5:2', 'procedural:L1/0:x', 'procedural:L1/-1:3'):
    with pytest.raises(ValueError, match='procedural:L{level}/{start}:{stop}'):
      expand_object_sources([bad])


def test_load_object_set_mixes_sources_and_reports_bad_ones(tmp_path):
  folder = tmp_path / 'mine'
  folder.mkdir()
  trimesh.creation.box((0.05, 0.04, 0.03)).export(folder / 'box.obj')
  (folder / 'empty.stl').write_bytes(b'')
  single = tmp_path / 'cyl.stl'
  trimesh.creation.cylinder(20.0, 50.0, sections=24).export(single)  # millimetres
  report = load_object_set(['builtin:cube', 'procedural:L1/0:2', str(folder), str(single), 'builtin:nope',
                            str(tmp_path / 'missing.obj'), 'builtin:cube'], scale=0.001)
  names = [o.name for o in report.loaded]
  assert names == ['builtin:cube', 'procedural:L1/0', 'procedural:L1/1', 'mine/box', 'cyl']
  # Built-in and procedural objects are never scaled; files are.
  np.testing.assert_allclose(report.loaded[1].mesh.vertices, procedural_mesh(1, 0).vertices)
  np.testing.assert_allclose(report.loaded[3].mesh.extents, [5e-5, 4e-5, 3e-5], rtol=1e-6)
  np.testing.assert_allclose(report.loaded[4].mesh.extents, [0.04, 0.04, 0.05], rtol=1e-3)
  reasons = {r.file: r.reason for r in report.rejected}
  assert set(reasons) == {str(folder / 'empty.stl'), 'builtin:nope', str(tmp_path / 'missing.obj'), 'builtin:cube'}
  assert 'empty file' in reasons[str(folder / 'empty.stl')]
  assert 'nope' in reasons['builtin:nope']
  assert 'duplicate object name' in reasons['builtin:cube']
  with pytest.raises(ValueError, match='scale'):
    load_object_set(['builtin:cube'], scale=0.0)


def test_prepare_object_set_caches_and_reports_failures(tmp_path, monkeypatch):
  report = load_object_set(['builtin:cube', 'builtin:l_shape', 'builtin:sphere'])
  from dexjax.objects import folder as folder_mod
  real = folder_mod.cached_collision_hulls

  def flaky(mesh, **kwargs):
    if len(mesh.vertices) > 100:  # the sphere
      raise RuntimeError('decomposition exploded')
    return real(mesh, **kwargs)

  monkeypatch.setattr(folder_mod, 'cached_collision_hulls', flaky)
  prepared, rejected = prepare_object_set(report, cache_dir=tmp_path, model=False)
  assert [p.name for p in prepared] == ['builtin:cube', 'builtin:l_shape'] and all(p.model is None for p in prepared)
  assert len(rejected) == 1 and rejected[0].file == 'builtin:sphere' and 'decomposition exploded' in rejected[0].reason
  assert len(prepared[1].hulls) >= 2  # the L is not convex: decomposed
  assert list((tmp_path / 'hulls').glob('*.npz'))  # cached
  objects = sim.heap_objects(prepared)
  assert [o.name for o in objects] == ['builtin:cube', 'builtin:l_shape']
  np.testing.assert_allclose(objects[0].mass, 500.0 * 0.04 ** 3)


@pytest.fixture(scope='module')
def heap_rows(tmp_path_factory):
  cache = tmp_path_factory.mktemp('cache')
  return sim.procedural_heap_rows(levels=(1, 3), heaps_per_level=2, pool=6, seed=1, cache_dir=cache)


def test_procedural_heap_rows_settle_every_level(heap_rows):
  assert [row.label for row in heap_rows] == ['level 1', 'level 3']
  for row in heap_rows:
    r = row.result
    assert r.poses.shape == (2, 10, 7) and len(row.meshes) == 6
    assert np.all(r.mask == (row.object_ids >= 0))
    assert not r.diverged.any()
    inside = r.mask & ~r.left_bin
    assert np.all(r.centers[..., 2][inside] > 0) and np.all(r.centers[..., 2][inside] < 0.2)


def test_posed_meshes_follow_the_poses(heap_rows):
  row = heap_rows[0]
  placed = sim.posed_meshes(row.meshes, row.object_ids[0], row.result.poses[0], row.result.mask[0])
  assert [slot for slot, _ in placed] == list(np.flatnonzero(row.result.mask[0]))
  for slot, mesh in placed:
    original = row.meshes[row.object_ids[0, slot]]
    # The posed mesh's centre of mass is the settled centre of mass; its volume is unchanged.
    np.testing.assert_allclose(mesh.center_mass, row.result.centers[0, slot], atol=1e-6)
    np.testing.assert_allclose(mesh.volume, original.volume, rtol=1e-9)
    assert mesh.bounds[0, 2] > -0.002  # rests on the floor, not in it


def test_save_heap_sheet_writes_the_grid(heap_rows, tmp_path):
  from PIL import Image
  out = tmp_path / 'heaps.png'
  sim.save_heap_sheet(out, heap_rows, cell_pixels=100)
  image = np.asarray(Image.open(out).convert('RGB'))
  assert image.shape == (200, 200, 3)
  for r in range(2):  # every cell shows grey floor and coloured objects
    for c in range(2):
      cell = image[r * 100:(r + 1) * 100, c * 100:(c + 1) * 100].astype(int)
      assert (np.abs(cell - 217) < 3).all(axis=-1).sum() > 500
      assert (cell.max(axis=-1) - cell.min(axis=-1) > 60).sum() > 20
  with pytest.raises(ValueError, match='rows'):
    sim.save_heap_sheet(out, [])


def test_sim_cli_settle(tmp_path, capsys, monkeypatch):
  monkeypatch.setenv('DEXJAX_CACHE', str(tmp_path / 'cache'))
  out = tmp_path / 'heaps.npz'
  code = sim_main(['settle', 'builtin:all', 'builtin:bogus', '--heaps', '3', '--seed', '2', '--json',
                   '--out', str(out)])
  summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
  assert code == 1  # builtin:bogus was rejected
  assert summary['heaps'] == 3 and summary['rejected_objects'] == 1 and summary['backend'] == 'rollout'
  saved = np.load(out)
  assert saved['poses'].shape == (3, 10, 7) and saved['object_names'].tolist() == [
      f'builtin:{n}' for n in BUILTIN_OBJECTS]
  assert int(saved['mask'].sum()) == summary['objects']
  assert sim_main(['settle', 'builtin:cube', '--heaps', '2']) == 2  # fewer than 3 objects
  assert 'at least 3' in capsys.readouterr().err
  assert sim_main(['settle', 'procedural:L9/0:3']) == 2


def test_sim_cli_preview(tmp_path, capsys, monkeypatch):
  monkeypatch.setenv('DEXJAX_CACHE', str(tmp_path / 'cache'))
  out = tmp_path / 'heaps.png'
  assert sim_main(['preview', str(out), '--levels', '1', '--heaps-per-level', '2', '--pool', '4']) == 0
  printed = capsys.readouterr().out
  assert 'level 1: 2 heaps' in printed and f'wrote {out}' in printed
  from PIL import Image
  assert Image.open(out).size == (600, 300)
  assert sim_main(['preview', str(out), '--levels', '4']) == 2
  assert sim_main(['preview', str(out), '--pool', '2']) == 2  # fewer objects than a heap needs
