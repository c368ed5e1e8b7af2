"""Reading a user's depth image and segmask from files, with the checks that catch the usual real-image mistakes.

Depth files (`load_depth`; `save_depth` writes the 16-bit PNG), recognised by their content, not their extension:

* ``.npy``: an (H, W) or (H, W, 1) array: floats are metres, uint16 millimetres (a raw sensor dump, 16UC1) unless
  ``depth_scale`` says otherwise; other integer types (e.g. int64) are refused, naming the dtype;
* ``.npz``: the same, holding exactly one array;
* PNG: single-channel 16-bit (the usual uint16 depth PNG of RealSense, Kinect, ROS ``16UC1``), ``depth_scale``
  metres per unit, 0.001 (millimetres) by default. An 8-bit or colour PNG cannot hold a depth image (it is a
  visualisation) and is refused. PNGs are decoded with Pillow (it comes with matplotlib).

Invalid pixels (0, NaN, inf, negative) are kept as they are; `dexjax.policy.preprocess.prepare_observation`
inpaints them and leaves them out of the mask. `check_depth_image` refuses an image without a valid pixel or
whose median valid depth is implausible for metres (the usual millimetres-as-metres mistake). Segmasks
(`load_segmask`): PNG of any bit depth, grey or colour (non-zero = object), ``.npy`` or ``.npz``.
Errors are ValueError (FileNotFoundError for a missing file) naming the file and what was expected.
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

MIN_MEDIAN_DEPTH = 0.02  # metres: a valid median below this is not a grasping camera's depth in metres
MAX_MEDIAN_DEPTH = 20.0  # metres: above this the image is almost surely millimetres (or other units)

_PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'
_NPY_MAGIC = b'\x93NUMPY'
_ZIP_MAGIC = b'PK\x03\x04'
_COLOUR_TYPES = {0: 'greyscale', 2: 'RGB', 3: 'palette', 4: 'greyscale with alpha', 6: 'RGBA'}
_EXPECTED_DEPTH = 'an (H, W) or (H, W, 1) depth image (.npy, .npz, or a single-channel 16-bit PNG)'
_DEPTH_DTYPES = ('a float array of metres (float32 or float64) or a uint16 array of sensor units (millimetres unless '
                 '--depth-scale says otherwise, as a 16UC1 depth image)')


def _kind(path: str | os.PathLike, what: str) -> str:
  """'png', 'npy' or 'npz' by the file's first bytes; FileNotFoundError naming ``what`` / ValueError otherwise."""
  name = os.fspath(path)
  if not Path(path).is_file():
    raise FileNotFoundError(f'{name}: no such file; expected {what}')
  with open(path, 'rb') as f:
    head = f.read(8)
  for kind, magic in (('png', _PNG_SIGNATURE), ('npy', _NPY_MAGIC), ('npz', _ZIP_MAGIC)):
    if head.startswith(magic):
      return kind
  raise ValueError(f'{name}: not a PNG, .npy or .npz file (it starts with {head!r})')


def _png_header(path: str | os.PathLike) -> tuple[int, int]:
  """(bit depth, colour type) from the PNG's IHDR chunk."""
  with open(path, 'rb') as f:
    data = f.read(33)
  if len(data) < 33 or data[12:16] != b'IHDR':
    raise ValueError(f'{os.fspath(path)}: a truncated or malformed PNG (no IHDR chunk)')
  return data[24], data[25]


def _read_png(path: str | os.PathLike) -> np.ndarray:
  """The PNG's pixels as an array (H, W) or (H, W, C), decoded by Pillow."""
  try:
    from PIL import Image
  except ImportError:
    raise ImportError(f'{os.fspath(path)}: reading PNG files needs Pillow: pip install pillow') from None
  try:
    with Image.open(path) as image:
      return np.asarray(image.convert('RGBA') if image.mode == 'P' else image)
  except (OSError, ValueError) as e:
    raise ValueError(f'{os.fspath(path)}: could not decode the PNG: {e}') from None


def _read_array(path: str | os.PathLike, kind: str) -> np.ndarray:
  """The array of a ``.npy`` file or of a ``.npz`` file holding exactly one array."""
  name = os.fspath(path)
  try:
    if kind == 'npy':
      return np.load(path, allow_pickle=False)
    with np.load(path, allow_pickle=False) as archive:
      arrays = {key: archive[key] for key in archive.files}
  except (OSError, EOFError, ValueError, zipfile.BadZipFile) as e:
    raise ValueError(f'{name}: could not read it as a NumPy .{kind} file: {e}') from None
  if len(arrays) != 1:
    raise ValueError(f'{name}: expected an .npz file holding exactly one array, got {sorted(arrays)}')
  return next(iter(arrays.values()))


def _single_channel(name: str, array: np.ndarray, what: str) -> np.ndarray:
  """(H, W) view of an (H, W) or (H, W, 1) array; ValueError naming ``name`` otherwise."""
  if array.ndim == 3 and array.shape[-1] == 1:
    array = array[..., 0]
  if array.ndim != 2 or 0 in array.shape:
    hint = ' (a colour image? expected one channel)' if array.ndim == 3 else ''
    raise ValueError(f'{name}: expected an (H, W) or (H, W, 1) {what}, got shape {array.shape}{hint}')
  return array


def _real(name: str, array: np.ndarray) -> np.ndarray:
  """``array`` as a NumPy array; ValueError unless its dtype is integer or floating."""
  array = np.asarray(array)
  if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
    raise ValueError(f'{name}: expected a real-valued depth image, got dtype {array.dtype}')
  return array


def _check_dtype(name: str, array: np.ndarray) -> None:
  """ValueError naming ``name`` for an integer depth array other than uint16 (a sensor's raw units): no sensor
  writes int64 (``np.array`` of Python integers does), so its unit is anyone's guess. Non-real dtypes: `_real`."""
  if np.issubdtype(array.dtype, np.integer) and array.dtype != np.uint16:
    raise ValueError(f'{name}: dtype {array.dtype}; expected {_DEPTH_DTYPES}: convert it first (e.g. '
                     'depth.astype(np.uint16) for millimetres, or depth / 1000.0 for metres)')


def check_depth_image(depth: np.ndarray, name: str = 'depth') -> np.ndarray:
  """A depth image in metres as (H, W) float32, with invalid pixels (NaN, inf, <= 0) left as they are.

  Args:
    depth: (H, W) or (H, W, 1) real array, metres.
    name: what to call it in errors (a file name, or 'depth').
  Raises:
    ValueError: naming ``name``: wrong shape or dtype, no valid pixel, or a median valid depth outside
      [`MIN_MEDIAN_DEPTH`, `MAX_MEDIAN_DEPTH`] metres (e.g. millimetres: pass --depth-scale 0.001).
  """
  depth = _single_channel(name, _real(name, depth), 'depth image').astype(np.float32)
  valid = np.isfinite(depth) & (depth > 0)
  if not valid.any():
    raise ValueError(f'{name}: no valid pixel (every depth is 0, NaN, infinite or negative); expected depths in '
                     'metres with at least the scene valid')
  median = float(np.median(depth[valid]))
  if median > MAX_MEDIAN_DEPTH:
    raise ValueError(f'{name}: median depth {median:.6g} m is implausible for metres (expected '
                     f'{MIN_MEDIAN_DEPTH:g}-{MAX_MEDIAN_DEPTH:g} m): it looks like millimetres: pass --depth-scale '
                     '0.001 (depth_scale=0.001), or convert the image to metres')
  if median < MIN_MEDIAN_DEPTH:
    raise ValueError(f'{name}: median depth {median:.6g} m is implausibly small (expected {MIN_MEDIAN_DEPTH:g}-'
                     f'{MAX_MEDIAN_DEPTH:g} m): was it scaled twice, or normalised to [0, 1] (e.g. by '
                     "matplotlib's imread)? Pass the raw depth and the right --depth-scale")
  return depth


def _depth_scale(name: str, depth_scale: float | None, default: float) -> float:
  """``depth_scale`` (metres per unit) checked, or ``default`` when None."""
  if depth_scale is None:
    return default
  if not np.isfinite(depth_scale) or depth_scale <= 0:
    raise ValueError(f'{name}: depth_scale: expected a finite number > 0 (metres per unit), got {depth_scale!r}')
  return float(depth_scale)


def _png_depth(path: str | os.PathLike) -> np.ndarray:
  """The raw uint16 (H, W) pixels of a single-channel 16-bit PNG; ValueError for any other PNG."""
  name = os.fspath(path)
  bits, colour = _png_header(path)
  if colour != 0:
    raise ValueError(f'{name}: a {_COLOUR_TYPES.get(colour, f"colour type {colour}")} PNG; expected a '
                     'single-channel (greyscale) 16-bit depth PNG: a colour PNG is a visualisation, not depth')
  if bits != 16:
    raise ValueError(f'{name}: an {bits}-bit PNG; depth must be a 16-bit PNG (e.g. uint16 millimetres): an '
                     f'{bits}-bit image is a visualisation that has lost the depth')
  return _read_png(path)


def load_depth(path: str | os.PathLike, depth_scale: float | None = None) -> np.ndarray:
  """Reads a depth image file into (H, W) float32 metres; invalid pixels stay 0 / NaN (see `check_depth_image`).

  Args:
    path: a ``.npy`` / ``.npz`` array or a single-channel 16-bit PNG (recognised by content).
    depth_scale: metres per stored unit; None: 0.001 (millimetres) for a PNG or an integer array, 1 (metres)
      for a float array.
  Raises:
    FileNotFoundError: no such file.
    ValueError: naming the file and what was expected: not a PNG / NumPy file, an 8-bit or colour PNG, a shape
      other than (H, W) or (H, W, 1), no valid pixel, or implausible units.
  """
  name = os.fspath(path)
  kind = _kind(path, _EXPECTED_DEPTH)
  if kind == 'png':
    raw, default = _png_depth(path), 0.001
  else:
    raw = _read_array(path, kind)
    default = 0.001 if np.issubdtype(raw.dtype, np.integer) else 1.0
    _check_dtype(name, raw)
  scale = _depth_scale(name, depth_scale, default)
  return check_depth_image(_real(name, raw).astype(np.float64) * scale, name)


def save_depth(path: str | os.PathLike, depth: np.ndarray, depth_scale: float = 0.001) -> Path:
  """Writes a depth image as a single-channel 16-bit PNG of integer units, as depth sensors and ROS (``16UC1``)
  store them; `load_depth` reads it back (with the same ``depth_scale``) to within half a unit.

  Args:
    path: the PNG to write.
    depth: (H, W) or (H, W, 1) depth, metres; invalid pixels (0, NaN, inf, negative) are written as 0.
    depth_scale: metres per stored unit (0.001: millimetres, 65.535 m at most).
  Returns:
    ``path`` as a Path.
  Raises:
    ValueError: naming the file: wrong shape or dtype, a bad ``depth_scale``, a valid depth beyond 65,535 units
      or below half a unit (it would read back as a hole).
  """
  name = os.fspath(path)
  scale = _depth_scale(name, depth_scale, 0.001)
  depth = _single_channel(name, _real(name, depth), 'depth image').astype(np.float64)
  valid = np.isfinite(depth) & (depth > 0)
  units = np.round(np.where(valid, depth, 0.0) / scale)
  if valid.any() and (units[valid].max() > np.iinfo(np.uint16).max or units[valid].min() < 1):
    far, near = float(depth[valid].max()), float(depth[valid].min())
    raise ValueError(f'{name}: depths {near:.6g}-{far:.6g} m do not fit a 16-bit PNG at depth_scale {scale:g} m per '
                     f'unit (expected {0.5 * scale:.6g}-{np.iinfo(np.uint16).max * scale:.6g} m): choose another '
                     'depth_scale')
  try:
    from PIL import Image
  except ImportError:
    raise ImportError(f'{name}: writing PNG files needs Pillow: pip install pillow') from None
  Image.fromarray(units.astype(np.uint16)).save(path, format='PNG')
  return Path(path)


def load_segmask(path: str | os.PathLike, shape: tuple[int, int]) -> np.ndarray:
  """Reads a segmask into (H, W) bool: non-zero (any channel of a colour PNG; alpha ignored) = object.

  Args:
    path: a PNG (any bit depth, grey, palette or colour), ``.npy`` or ``.npz`` (H, W) or (H, W, 1) array.
    shape: (H, W) of the depth image it must match, pixels.
  Raises:
    FileNotFoundError: no such file.
    ValueError: naming the file: unreadable, a shape other than ``shape`` (both named), or no object pixel.
  """
  name = os.fspath(path)
  kind = _kind(path, 'a segmask (PNG, .npy or .npz)')
  array = _read_array(path, kind) if kind != 'png' else _read_png(path)
  if kind == 'png' and array.ndim == 3:
    array = array[..., :3] if array.shape[-1] >= 3 else array[..., :1]  # drop the alpha channel
    array = np.any(array != 0, axis=-1)
  array = _single_channel(name, array, 'segmask')
  if tuple(array.shape) != tuple(shape):
    raise ValueError(f'{name}: the segmask is {array.shape[0]}x{array.shape[1]} (H x W) but the depth image is '
                     f'{shape[0]}x{shape[1]}; expected a segmask pixel-aligned with the depth image')
  mask = (array != 0) & ~np.isnan(array) if np.issubdtype(array.dtype, np.floating) else array != 0
  if not mask.any():
    raise ValueError(f'{name}: the segmask has no object pixel (every pixel is 0); expected the objects to be '
                     'non-zero')
  return mask


__all__ = ['MAX_MEDIAN_DEPTH', 'MIN_MEDIAN_DEPTH', 'check_depth_image', 'load_depth', 'load_segmask', 'save_depth']
