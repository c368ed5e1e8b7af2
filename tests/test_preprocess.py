"""Observation pre-processing of real depth images: inpainting, file loading, plane / background segmentation.

References are independent: exact planes and `scipy.interpolate.griddata` for the inpainting, a NumPy ray
caster of a floor with boxes seen by a camera tilted 20 degrees (`look_at`) for the segmentations, and PNGs
written by Pillow for the loaders.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
from scipy import ndimage
import pytest
from PIL import Image
from scipy.interpolate import griddata

from dexjax.policy.depth_io import load_depth, load_segmask, save_depth
from dexjax.policy.preprocess import (background_mask, fit_plane, inpaint_depth, plane_mask,
                                      prepare_observation)
from dexjax.render.camera import Camera, Intrinsics, look_at

H, W = 96, 128
_ROWS, _COLS = np.mgrid[0:H, 0:W].astype(np.float64)

# Scene: floor z = 0, camera 0.6 m from the origin, tilted 20 degrees from the vertical; boxes (lo, hi) corners.
_TILT = math.radians(20.0)
_EYE = np.array([0.0, -0.6 * math.sin(_TILT), 0.6 * math.cos(_TILT)])
K = Intrinsics(fx=120.0, fy=120.0, cx=(W - 1) / 2, cy=(H - 1) / 2, width=W, height=H)
CAMERA = Camera(K, look_at(jnp.asarray(_EYE, jnp.float32), jnp.zeros(3)), jnp.asarray(_EYE, jnp.float32))
BOXES = [((-0.10, -0.04, 0.0), (-0.02, 0.05, 0.04)), ((0.03, -0.09, 0.0), (0.12, -0.01, 0.025))]


def _render(boxes, hole_fraction=0.0, seed=0):
  """(depth (H, W) metres with NaN holes, pixels whose ray hits a box before the floor (H, W) bool)."""
  rays = np.stack([(_COLS - K.cx) / K.fx, (_ROWS - K.cy) / K.fy, np.ones_like(_COLS)], axis=-1)
  directions = rays @ np.asarray(CAMERA.rotation, np.float64).T  # ray parameter t = camera-frame depth
  depth = -_EYE[2] / directions[..., 2]
  on_box = np.zeros((H, W), bool)
  with np.errstate(divide='ignore', invalid='ignore'):
    for lo, hi in boxes:
      t1, t2 = (np.asarray(lo) - _EYE) / directions, (np.asarray(hi) - _EYE) / directions
      near, far = np.minimum(t1, t2).max(axis=-1), np.maximum(t1, t2).min(axis=-1)
      hit = (near <= far) & (near > 0) & (near < depth)
      depth, on_box = np.where(hit, near, depth), on_box | hit
  holes = np.random.default_rng(seed).random((H, W)) < hole_fraction
  return np.where(holes, np.nan, depth).astype(np.float32), on_box


def _iou(a, b):
  return (a & b).sum() / (a | b).sum()


def _holes(seed=0, fraction=0.05, blocks=((30, 70, 40, 80),)):
  holes = np.random.default_rng(seed).random((H, W)) < fraction
  for r0, r1, c0, c1 in blocks:
    holes[r0:r1, c0:c1] = True
  holes[[0, -1], :] = holes[:, [0, -1]] = False  # interior holes: the border is extended flat, not linearly
  return holes


# --- inpaint_depth ---

def test_inpaint_reproduces_a_tilted_plane_and_keeps_valid_pixels():
  floor, _ = _render([])  # the floor seen by the tilted camera: 1 / depth is linear in pixels
  holes = _holes()
  depth = np.where(holes, np.nan, floor)
  filled = np.asarray(inpaint_depth(depth))
  assert np.array_equal(filled[~holes], floor[~holes])
  assert np.abs(filled - floor).max() < 2e-4  # a 40 x 40 hole on a floor 0.52 to 0.70 m away
  filled = np.asarray(inpaint_depth(np.where(_holes(seed=1, fraction=0.3), 0.0, floor)))  # 0 marks holes too
  assert np.abs(filled - floor).max() < 2e-4


def test_inpaint_matches_linear_interpolation_on_a_curved_surface():
  surface = (0.6 + 0.04 * np.exp(-((_ROWS - 40) ** 2 + (_COLS - 70) ** 2) / (2 * 25.0 ** 2))).astype(np.float32)
  holes = _holes(seed=2, blocks=((20, 28, 30, 38), (50, 56, 90, 100), (36, 44, 62, 70)))
  filled = np.asarray(inpaint_depth(np.where(holes, np.inf, surface)))
  linear = griddata(np.argwhere(~holes), surface[~holes], np.argwhere(holes), method='linear')
  # the membrane interpolates 1 / depth and is not piecewise linear: close to, not equal to, griddata
  assert np.abs(filled[holes] - linear).max() < 5e-4
  assert np.abs(filled - surface).max() < 1e-3


def test_inpaint_fills_big_holes_within_the_valid_range():
  surface, _ = _render(BOXES)
  holes = _holes(seed=3, fraction=0.5, blocks=((10, 60, 20, 70), (0, 96, 110, 128)))
  filled = np.asarray(inpaint_depth(np.where(holes, np.nan, surface)))
  assert np.isfinite(filled).all()
  valid = surface[~holes]
  assert valid.min() - 1e-6 <= filled.min() and filled.max() <= valid.max() + 1e-6  # maximum principle


def test_inpaint_all_invalid_gives_nan():
  assert np.isnan(np.asarray(inpaint_depth(np.zeros((H, W), np.float32)))).all()


# --- load_depth / load_segmask ---

def _png(path, array):
  Image.fromarray(array).save(path)
  return path


def test_load_depth_uint16_png_millimetres(tmp_path):
  mm = np.random.default_rng(0).integers(300, 1200, (H, W)).astype(np.uint16)
  mm[5, 7] = 0  # a hole stays a hole
  depth = load_depth(_png(tmp_path / 'd.png', mm))
  assert depth.dtype == np.float32 and depth.shape == (H, W)
  np.testing.assert_array_equal(depth, (mm * 0.001).astype(np.float32))
  np.testing.assert_array_equal(load_depth(tmp_path / 'd.png', depth_scale=0.0005), (mm * 0.0005).astype(np.float32))


def test_load_depth_npy_variants(tmp_path):
  metres = np.full((H, W, 1), 0.7, np.float32)
  np.save(tmp_path / 'a.npy', metres)
  np.testing.assert_array_equal(load_depth(tmp_path / 'a.npy'), metres[..., 0])
  np.save(tmp_path / 'mm.npy', np.full((H, W), 700, np.uint16))  # integer arrays are millimetres by default
  np.testing.assert_allclose(load_depth(tmp_path / 'mm.npy'), 0.7, rtol=1e-6)
  np.savez(tmp_path / 'one.npz', depth=metres)
  np.testing.assert_array_equal(load_depth(tmp_path / 'one.npz'), metres[..., 0])


@pytest.mark.parametrize('kind, needle', [
    ('png8', '8-bit PNG; depth must be a 16-bit PNG'), ('rgb', 'RGB PNG'), ('mm', 'looks like millimetres: pass '
    '--depth-scale 0.001'), ('nan', 'no valid pixel'), ('shape', 'expected an (H, W) or (H, W, 1) depth image, '
    'got shape (96, 128, 3)'), ('unit', 'implausibly small'), ('text', 'not a PNG, .npy or .npz file'),
    ('npz2', 'exactly one array')])
def test_load_depth_errors(tmp_path, kind, needle):
  path = tmp_path / f'{kind}.bin'
  if kind == 'png8':
    _png(path.with_suffix('.png'), np.full((H, W), 100, np.uint8))
  elif kind == 'rgb':
    _png(path.with_suffix('.png'), np.zeros((H, W, 3), np.uint8))
  elif kind in ('mm', 'nan', 'shape', 'unit'):
    array = {'mm': np.full((H, W), 650.0), 'nan': np.full((H, W), np.nan), 'shape': np.ones((H, W, 3)),
             'unit': np.full((H, W), 0.6 / 65.535)}[kind]
    np.save(path.with_suffix('.npy'), array.astype(np.float32))
  elif kind == 'npz2':
    np.savez(path.with_suffix('.npz'), a=np.ones((H, W)), b=np.ones((H, W)))
  else:
    path.with_suffix('.txt').write_text('0.6 0.6\n')
  path = next(tmp_path.glob(f'{kind}.*'))
  with pytest.raises(ValueError, match='.') as error:
    load_depth(path)
  assert str(path) in str(error.value) and needle in str(error.value), str(error.value)


def test_save_depth_writes_the_16_bit_png_load_depth_reads(tmp_path):
  """Pillow decodes a single-channel 16-bit PNG of the depth in whole units (holes 0); `load_depth` reads it back
  to within half a unit; depths a 16-bit unit cannot hold are refused, naming the file."""
  depth = np.random.default_rng(1).uniform(0.3, 1.2, (H, W))
  depth[3, 4], depth[5, 6], depth[7, 8] = np.nan, 0.0, -1.0  # invalid: written as 0
  path = save_depth(tmp_path / 'd.png', depth)
  with Image.open(path) as image:
    assert image.mode in ('I;16', 'I;16B') and image.format == 'PNG'
    raw = np.asarray(image)
  valid = np.isfinite(depth) & (depth > 0)
  np.testing.assert_array_equal(raw, np.where(valid, np.round(np.nan_to_num(depth) * 1000), 0))
  back = load_depth(path)
  assert np.abs(back[valid] - depth[valid]).max() <= 0.0005 + 1e-7 and np.all(back[~valid] == 0)
  fine = load_depth(save_depth(tmp_path / 'f.png', depth, depth_scale=1e-4), depth_scale=1e-4)
  assert np.abs(fine[valid] - depth[valid]).max() <= 0.00005 + 1e-7
  for bad, scale in ((np.full((H, W), 70.0), 0.001), (np.full((H, W), 0.0004), 0.001)):
    with pytest.raises(ValueError, match='do not fit a 16-bit PNG') as error:
      save_depth(tmp_path / 'bad.png', bad, scale)
    assert 'bad.png' in str(error.value)
  with pytest.raises(ValueError, match='depth_scale'):
    save_depth(tmp_path / 'bad.png', depth, depth_scale=0.0)
  assert not (tmp_path / 'bad.png').exists()


def test_load_depth_missing_file(tmp_path):
  with pytest.raises(FileNotFoundError, match='nope.png'):
    load_depth(tmp_path / 'nope.png')


def test_load_segmask(tmp_path):
  mask = np.zeros((H, W), bool)
  mask[10:20, 30:50] = True
  rgba = np.zeros((H, W, 4), np.uint8)
  rgba[..., 3] = 255  # opaque background: alpha is ignored
  rgba[mask, 1] = 200
  np.testing.assert_array_equal(load_segmask(_png(tmp_path / 'm.png', rgba), (H, W)), mask)
  np.testing.assert_array_equal(load_segmask(_png(tmp_path / 'g.png', mask.astype(np.uint8) * 255), (H, W)), mask)
  np.save(tmp_path / 'm.npy', mask[..., None])
  np.testing.assert_array_equal(load_segmask(tmp_path / 'm.npy', (H, W)), mask)
  with pytest.raises(ValueError, match=r'm\.png: the segmask is 96x128 \(H x W\) but the depth image is 48x64'):
    load_segmask(tmp_path / 'm.png', (48, 64))
  with pytest.raises(ValueError, match=r'e\.png: the segmask has no object pixel'):
    load_segmask(_png(tmp_path / 'e.png', np.zeros((H, W), np.uint8)), (H, W))


# --- plane and background segmentation ---

def test_plane_fit_on_a_tilted_floor():
  floor, _ = _render([], hole_fraction=0.05)
  rays = np.stack([(_COLS - K.cx) / K.fx, (_ROWS - K.cy) / K.fy, np.ones_like(_COLS)], axis=-1)
  points = (rays * floor[..., None])[np.isfinite(floor)]
  normal, offset, fraction = fit_plane(points)
  up = np.asarray(CAMERA.rotation, np.float64).T @ np.array([0.0, 0.0, 1.0])  # world +z in the camera frame
  np.testing.assert_allclose(normal, up, atol=1e-5)
  np.testing.assert_allclose(offset, _EYE[2], atol=1e-5)  # the camera is 0.6 cos(20 deg) above the floor
  assert fraction == 1.0


def test_plane_mask_finds_the_boxes_despite_holes():
  depth, on_box = _render(BOXES, hole_fraction=0.05)
  valid = np.isfinite(depth)
  mask = plane_mask(depth, CAMERA)
  assert not mask[~valid].any()
  assert _iou(mask, on_box & valid) > 0.95
  np.testing.assert_array_equal(plane_mask(depth, K), mask)  # intrinsics suffice


WALLS = [((-0.22, -0.17, 0.0), (-0.20, 0.5, 0.06)), ((0.20, -0.17, 0.0), (0.22, 0.5, 0.06)),
         ((-0.22, -0.17, 0.0), (0.22, -0.15, 0.06)), ((-0.22, 0.48, 0.0), (0.22, 0.5, 0.06))]


def test_plane_mask_drops_a_bin_rim_cut_by_the_image_border():
  """Walls 6 cm high around the boxes, the far one out of view: the rim is a U cut by the image border, not a
  closed ring, yet it is dropped and the boxes are kept."""
  depth, _ = _render(BOXES + WALLS)
  box_depth, on_box = _render(BOXES)
  objects = on_box & (box_depth == depth)
  rim = _render(WALLS)[1] & ~objects
  assert rim.sum() > 300 and (rim[0].any() or rim[-1].any())  # the rim is seen and touches the border
  assert not ndimage.binary_fill_holes(rim)[~rim].any()  # and encloses nothing by itself
  mask = plane_mask(depth, CAMERA)
  assert not (mask & rim).any()
  assert _iou(mask, objects) > 0.95


def test_background_mask_finds_the_boxes():
  depth, on_box = _render(BOXES, hole_fraction=0.05, seed=1)
  empty, _ = _render([], hole_fraction=0.05, seed=2)
  mask = np.asarray(background_mask(depth, empty))
  valid = np.isfinite(depth) & np.isfinite(empty)
  assert not mask[~valid].any()
  assert _iou(mask, on_box & valid) > 0.95


# --- prepare_observation ---

def test_prepare_observation_plane():
  depth, on_box = _render(BOXES, hole_fraction=0.05)
  valid = np.isfinite(depth)
  observation, info = prepare_observation(depth[..., None], CAMERA, boundary=10)
  mask, filled = np.asarray(observation.mask), np.asarray(observation.depth)
  assert info['segmentation'] == 'plane' and info['mask_pixels'] == mask.sum() > 0
  assert info['invalid_pixels'] == (~valid).sum() and info['invalid_fraction'] == pytest.approx((~valid).mean())
  assert info['interior_mask_pixels'] == mask[10:-10, 10:-10].sum()
  assert not mask[~valid].any() and _iou(mask, on_box & valid) > 0.95
  assert np.isfinite(filled).all() and np.array_equal(filled[valid], depth[valid])


def test_prepare_observation_background_and_user_mask():
  depth, on_box = _render(BOXES, hole_fraction=0.05)
  empty, _ = _render([])
  observation, info = prepare_observation(depth, K, background=empty)
  assert info['segmentation'] == 'background' and _iou(np.asarray(observation.mask), on_box & np.isfinite(depth)) > 0.95
  np.testing.assert_array_equal(np.asarray(observation.camera.rotation), np.eye(3))  # intrinsics: identity pose
  user = np.zeros((H, W), np.uint8)
  user[40:60, 20:50] = 1
  observation, info = prepare_observation(depth, CAMERA, user, background=empty, segment='background')
  assert info['segmentation'] == 'segmask'
  np.testing.assert_array_equal(np.asarray(observation.mask), (user > 0) & np.isfinite(depth))


def test_prepare_observation_errors():
  depth, _ = _render(BOXES)
  with pytest.raises(ValueError) as error:
    prepare_observation(depth[:64, :80], CAMERA)
  message = str(error.value)
  assert '64x80 (H x W)' in message and '96x128' in message and 'rescale the intrinsics' in message, message
  with pytest.raises(ValueError, match='no valid pixel'):
    prepare_observation(np.full((H, W), np.nan), CAMERA)
  with pytest.raises(ValueError, match='looks like millimetres'):
    prepare_observation(depth * 1000, CAMERA)
  with pytest.raises(ValueError, match='no object pixels: nothing rises more than 0.005 m above the dominant'):
    prepare_observation(_render([])[0], CAMERA)
  with pytest.raises(ValueError, match="'background' needs a background depth image"):
    prepare_observation(depth, CAMERA, segment='background')
  with pytest.raises(ValueError, match=r'mask: the image is 96x64 \(H x W\)'):
    prepare_observation(depth, CAMERA, np.ones((H, 64)))
  with pytest.raises(ValueError, match='no object pixels: the segmask covers no valid depth'):
    prepare_observation(np.where(_COLS < 64, np.nan, depth), CAMERA, _COLS < 64)
