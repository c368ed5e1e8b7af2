"""Depth rendering (`dexjax.render.rendering`) against exact NumPy ray casting of box scenes.

The reference intersects every pixel ray with the bin's boxes and the objects' boxes analytically (slab
method), giving the planar depth, the slot label and the face hit; pixels within 1 px of a change of face are
silhouette/crease pixels and are excluded from exact comparisons. GL tests require a headless GL platform
and fail (not skip) without one: CI installs Mesa (see ``.ci/run``).
"""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from dexjax.render import rendering
from dexjax.render.camera import Camera, Intrinsics, deproject, look_at
from dexjax.sim.heap import Bin
from dexjax.sim.scene import quat_to_matrix

W, H = 64, 48
INTRINSICS = Intrinsics(fx=55.0, fy=57.0, cx=30.25, cy=24.75, width=W, height=H)
# Slot 0: a 10 x 6 x 4 cm box resting on the floor, turned 30 degrees about z; slot 1 empty; slot 2: a 5 cm
# cube floating, tilted about an oblique axis. Mesh ids differ from slots on purpose.
BOX_HALF = np.array([0.05, 0.03, 0.02])
CUBE_HALF = np.array([0.025, 0.025, 0.025])
_AXIS = np.array([1.0, 2.0, 0.5]) / np.linalg.norm([1.0, 2.0, 0.5])
POSES = np.array([
    [0.03, -0.02, 0.02, np.cos(np.pi / 12), 0.0, 0.0, np.sin(np.pi / 12)],
    [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
    [-0.07, 0.06, 0.07, np.cos(0.4), *(np.sin(0.4) * _AXIS)]])
OBJECT_IDS = np.array([1, -1, 0])
MASK = np.array([True, False, True])
MESHES = [trimesh.creation.box(extents=2 * CUBE_HALF), trimesh.creation.box(extents=2 * BOX_HALF)]


def _camera(eye, target, intrinsics=INTRINSICS) -> Camera:
  eye = jnp.asarray(eye, jnp.float32)
  return Camera(intrinsics, look_at(eye, jnp.asarray(target, jnp.float32)), eye)


CAMERAS = {'top': _camera([0.0, 0.0, 0.4], [0.0, 0.0, 0.0]),
           'oblique': _camera([0.2, -0.17, 0.25], [-0.01, 0.01, 0.02])}


def _boxes(with_objects=True):
  """[(centre, rotation, half size, label)] of the reference scene."""
  boxes = [(c, np.eye(3), h, rendering.BIN_LABEL) for c, h in rendering.render_boxes(Bin())]
  if with_objects:
    for slot, half in ((0, BOX_HALF), (2, CUBE_HALF)):
      boxes.append((POSES[slot, :3], quat_to_matrix(POSES[slot, 3:]), half, slot))
  return boxes


def _reference(camera, boxes):
  """Exact (planar depth (H, W), label (H, W), face id (H, W)) by ray-box intersection; NaN / -2 / -1 if no hit."""
  k = camera.intrinsics
  v, u = np.meshgrid(np.arange(k.height), np.arange(k.width), indexing='ij')
  rays = np.stack([(u - float(k.cx)) / float(k.fx), (v - float(k.cy)) / float(k.fy), np.ones(u.shape)], -1)
  rotation, origin = np.asarray(camera.rotation, np.float64), np.asarray(camera.position, np.float64)
  dirs = rays @ rotation.T  # unit camera z: the ray parameter is the planar depth
  depth = np.full(u.shape, np.inf)
  label, face = np.full(u.shape, -2), np.full(u.shape, -1)
  for b, (centre, rot, half, lab) in enumerate(boxes):
    o, d = (origin - centre) @ rot, dirs @ rot
    with np.errstate(divide='ignore', invalid='ignore'):
      t1, t2 = (-half - o) / d, (half - o) / d
    t_near, t_far = np.minimum(t1, t2), np.maximum(t1, t2)
    enter, leave = t_near.max(-1), t_far.min(-1)
    hit = (enter <= leave) & (enter > 0) & (enter < depth)
    depth = np.where(hit, enter, depth)
    label = np.where(hit, lab, label)
    axis = t_near.argmax(-1)
    side = np.take_along_axis(d, axis[..., None], -1)[..., 0] > 0
    face = np.where(hit, 6 * b + 2 * axis + side, face)
  return np.where(np.isfinite(depth), depth, np.nan), label, face


def _interior(*maps):
  """(H, W) bool: pixels whose 3 x 3 neighbourhood has one value in every map (edges are excluded)."""
  ok = np.ones(maps[0].shape, bool)
  for m in maps:
    padded = np.pad(m, 1, mode='edge')
    for di in range(3):
      for dj in range(3):
        ok &= padded[di:di + m.shape[0], dj:dj + m.shape[1]] == m
  return ok


@pytest.fixture(scope='module')
def scene():
  return rendering.build_render_scene(MESHES, OBJECT_IDS, POSES, MASK)


@pytest.fixture(scope='module')
def gl_renderer():
  with rendering.DepthRenderer(W, H, backend='gl') as renderer:  # raises (fails) when GL is unavailable
    yield renderer


@pytest.fixture(scope='module')
def ray_renderer():
  with rendering.DepthRenderer(W, H, backend='raycast') as renderer:
    yield renderer


@pytest.fixture(params=['gl', 'raycast'])
def renderer(request, gl_renderer, ray_renderer):
  return gl_renderer if request.param == 'gl' else ray_renderer


@pytest.mark.parametrize('view', ['top', 'oblique'])
def test_depth_and_mask_match_exact_ray_box_intersection(renderer, scene, view):
  camera = CAMERAS[view]
  image = renderer.render(scene, camera)
  ref_depth, ref_label, ref_face = _reference(camera, _boxes())
  interior = _interior(ref_face)
  assert image.depth.shape == (H, W) and image.depth.dtype == np.float32 and image.mask.dtype == np.int32
  assert renderer.backend.startswith('gl_') == (renderer.backend != 'raycast')
  valid = interior & np.isfinite(ref_depth)
  assert valid.sum() > 0.25 * W * H and (interior & (ref_label == 0)).sum() > 20
  assert (interior & (ref_label == 2)).sum() > 10
  np.testing.assert_array_less(np.abs(image.depth[valid] - ref_depth[valid]), 1e-3)
  np.testing.assert_array_equal(image.mask[interior], ref_label[interior])
  assert np.all(np.isnan(image.depth[interior & (ref_label == -2)]))
  assert set(np.unique(image.mask)) <= {-2, -1, 0, 2}  # slots, never mesh ids (slot 2 is mesh 0)


def test_depth_is_planar_not_ray_length(gl_renderer, scene):
  camera = CAMERAS['oblique']
  image = gl_renderer.render(scene, camera)
  ref_depth, _, ref_face = _reference(camera, _boxes())
  k = camera.intrinsics
  v, u = np.meshgrid(np.arange(H), np.arange(W), indexing='ij')
  stretch = np.sqrt(((u - float(k.cx)) / float(k.fx)) ** 2 + ((v - float(k.cy)) / float(k.fy)) ** 2 + 1.0)
  valid = _interior(ref_face) & np.isfinite(ref_depth) & (stretch > 1.1)
  assert valid.sum() > 50
  ray_length = ref_depth * stretch
  assert np.all(np.abs(image.depth[valid] - ray_length[valid]) > 0.02)
  np.testing.assert_array_less(np.abs(image.depth[valid] - ref_depth[valid]), 1e-3)


@pytest.mark.parametrize('view', ['top', 'oblique'])
def test_backends_agree(gl_renderer, ray_renderer, scene, view):
  a = gl_renderer.render(scene, CAMERAS[view])
  b = ray_renderer.render(scene, CAMERAS[view])
  assert a.backend.startswith('gl_') and b.backend == 'raycast'
  interior = _interior(a.mask, b.mask)
  np.testing.assert_array_equal(a.mask[interior], b.mask[interior])
  both = interior & np.isfinite(a.depth)
  np.testing.assert_array_equal(np.isfinite(a.depth[interior]), np.isfinite(b.depth[interior]))
  np.testing.assert_array_less(np.abs(a.depth[both] - b.depth[both]), 1e-3)


def test_backends_agree_on_curved_mesh(gl_renderer, ray_renderer):
  sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.04)
  scene = rendering.build_render_scene([sphere], [0], [[0.01, 0.0, 0.04, 1.0, 0, 0, 0]], [True])
  a, b = gl_renderer.render(scene, CAMERAS['oblique']), ray_renderer.render(scene, CAMERAS['oblique'])
  interior = _interior(a.mask, b.mask)
  assert (interior & (a.mask == 0)).sum() > 20
  np.testing.assert_array_equal(a.mask[interior], b.mask[interior])
  finite = interior & np.isfinite(a.depth)
  np.testing.assert_array_less(np.abs(a.depth[finite] - b.depth[finite]), 1e-3)


@pytest.mark.parametrize('view', ['top', 'oblique'])
def test_empty_bin_renders_floor_and_walls_only(renderer, view):
  camera = CAMERAS[view]
  image = renderer.render(rendering.empty_bin_scene(num_slots=3), camera)
  ref_depth, ref_label, ref_face = _reference(camera, _boxes(with_objects=False))
  interior = _interior(ref_face)
  assert set(np.unique(image.mask)) <= {-2, -1} and np.mean(image.mask == -1) > 0.5
  np.testing.assert_array_equal(image.mask[interior], ref_label[interior])
  valid = interior & np.isfinite(ref_depth)
  np.testing.assert_array_less(np.abs(image.depth[valid] - ref_depth[valid]), 1e-3)


def test_deprojected_box_pixels_lie_on_the_box_faces(gl_renderer, scene):
  camera = CAMERAS['oblique']
  image = gl_renderer.render(scene, camera)
  points = np.asarray(deproject(camera, jnp.asarray(image.depth)), np.float64)
  _, _, ref_face = _reference(camera, _boxes())
  pick = _interior(ref_face, image.mask) & (image.mask == 0)
  assert pick.sum() > 20
  local = (points[pick] - POSES[0, :3]) @ quat_to_matrix(POSES[0, 3:])
  gap = BOX_HALF - np.abs(local)  # >= 0 inside; 0 on a face
  np.testing.assert_array_less(-gap, 1e-3)
  np.testing.assert_array_less(gap.min(axis=1), 1e-3)


def test_camera_from_json_renders_like_camera_in_code(gl_renderer, scene, tmp_path):
  camera = CAMERAS['oblique']
  k = camera.intrinsics
  fields = {'fx': 55.0, 'fy': 57.0, 'cx': 30.25, 'cy': 24.75, 'width': W, 'height': H,
            'rotation': np.asarray(camera.rotation).tolist(), 'position': np.asarray(camera.position).tolist()}
  path = tmp_path / 'camera.json'
  path.write_text(json.dumps(fields))  # written by hand, read by the library
  from dexjax.render.intrinsics_io import load_camera, save_camera
  from_json = load_camera(path)
  save_camera(tmp_path / 'again.json', from_json)  # and a round trip through the library's writer
  assert json.loads((tmp_path / 'again.json').read_text())['fx'] == 55.0
  assert (k.width, k.height) == (from_json.intrinsics.width, from_json.intrinsics.height)
  a, b = gl_renderer.render(scene, camera), gl_renderer.render(scene, from_json)
  np.testing.assert_array_equal(a.mask, b.mask)
  np.testing.assert_allclose(a.depth, b.depth, rtol=0, atol=1e-6)


def test_500_by_500_smoke(scene):
  intrinsics = Intrinsics(fx=520.0, fy=520.0, cx=249.5, cy=249.5, width=500, height=500)
  camera = _camera([0.0, 0.0, 0.7], [0.0, 0.0, 0.0], intrinsics)
  image = rendering.render_depth(scene, camera, backend='gl')
  ref_depth, ref_label, ref_face = _reference(camera, _boxes())
  interior = _interior(ref_face)
  assert image.depth.shape == (500, 500) and image.backend.startswith('gl_')
  assert np.mean(image.mask[interior] == ref_label[interior]) == 1.0
  valid = interior & np.isfinite(ref_depth)
  assert np.max(np.abs(image.depth[valid] - ref_depth[valid])) < 1e-3


def test_bad_inputs_name_the_field(ray_renderer, scene):
  small = _camera([0, 0, 0.7], [0, 0, 0], Intrinsics(fx=50.0, fy=50.0, cx=15.5, cy=11.5, width=32, height=24))
  with pytest.raises(ValueError, match='width x height: expected 64 x 48'):
    ray_renderer.render(scene, small)
  with pytest.raises(ValueError, match='backend'):
    rendering.DepthRenderer(W, H, backend='vulkan')
  with pytest.raises(ValueError, match='object_ids'):
    rendering.build_render_scene(MESHES, [5, -1, 0], POSES, MASK)
  with pytest.raises(ValueError, match='RenderSettings.far'):
    rendering.DepthRenderer(W, H, backend='raycast', settings=rendering.RenderSettings(near=0.5, far=0.1))


def test_auto_picks_gl_here_and_reports_it(scene):
  with rendering.DepthRenderer(W, H) as renderer:  # CI has Mesa: auto must not silently fall back
    assert renderer.backend in ('gl_egl', 'gl_osmesa') and renderer.fallback_reason is None
    assert renderer.render(scene, CAMERAS['top']).backend == renderer.backend


def test_render_cli_heap_and_backends(tmp_path, capsys, monkeypatch):
  import json as _json
  from dexjax.render.__main__ import main as render_main
  monkeypatch.setenv('DEXJAX_CACHE', str(tmp_path / 'cache'))
  out, npz = tmp_path / 'heap.png', tmp_path / 'heap.npz'
  (tmp_path / 'k.json').write_text(_json.dumps({'fx': 60.0, 'fy': 60.0, 'cx': 31.5, 'cy': 23.5, 'width': 64,
                                                'height': 48}))
  args = ['heap', str(out), '--seed', '1', '--objects', 'builtin:all', '--backend', 'gl', '--npz', str(npz)]
  assert render_main(args + ['--camera', str(tmp_path / 'k.json')]) == 0
  saved = np.load(npz)
  assert saved['depth'].shape == (48, 64) and saved['mask'].shape == (48, 64) and out.stat().st_size > 0
  np.testing.assert_allclose(saved['intrinsics'], [60.0, 60.0, 31.5, 23.5])
  slots = set(np.unique(saved['mask'])) - {-2, -1}
  assert 3 <= len(slots) <= len(saved['object_names'])  # every object of a settled heap in a 0.7 m view
  valid = np.isfinite(saved['depth'])
  assert valid.all() and np.all((saved['depth'] > 0.5) & (saved['depth'] < 1.0))  # the table fills the frame
  assert 'wrote' in capsys.readouterr().out
  (tmp_path / 'bad.json').write_text(_json.dumps({'fx': -1, 'fy': 60.0, 'cx': 31.5, 'cy': 23.5, 'width': 64,
                                                  'height': 48}))
  assert render_main(args + ['--camera', str(tmp_path / 'bad.json')]) == 2
  assert 'fx' in capsys.readouterr().err
  assert render_main(['backends']) == 0
  assert _json.loads(capsys.readouterr().out)['available']  # CI installs the GL packages
