"""Reading and writing camera intrinsics and poses as small JSON files (and ROS CameraInfo dumps).

Formats (see docs/cameras.md):

* ours: ``{"fx": 575.0, "fy": 575.0, "cx": 260.0, "cy": 260.0, "width": 500, "height": 500}``, plus
  ``"rotation"`` (3 x 3 rows, world-from-camera) and ``"position"`` (3, metres) for a posed camera;
* a ROS ``sensor_msgs/CameraInfo`` dumped to JSON or YAML (ROS 1 ``K``/``D`` or ROS 2 ``k``/``d``):
  ``width``, ``height`` and the row-major 3 x 3 ``K`` are read; ``D``, ``R``, ``P``, ``distortion_model``,
  ``header``, ``binning_*`` and ``roi`` are ignored, with a UserWarning when ``D`` is non-zero;
* a ``camera_calibration`` / ``camera_info_manager`` YAML (``image_width``, ``image_height``,
  ``camera_matrix: {data: [...]}``, ``distortion_coefficients: {data: [...]}``).

Files ending in ``.yaml`` or ``.yml`` are parsed as YAML, anything else as JSON (by
`dexjax.config.parse_yaml_documents` and `parse_json`: deep nesting and duplicate YAML keys are refused). We always
write JSON. Width and height are at most `MAX_IMAGE_SIDE` pixels (`dexjax.render.camera.check_image_side`), focal
lengths at most `MAX_FOCAL_LENGTH` pixels and the principal point lies in the image (0 <= cx <= width,
0 <= cy <= height).
Errors name the file, the field and the expected value.
"""

from __future__ import annotations

import json
import math
import numbers
import os
import warnings
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from dexjax.config import ConfigError, number_hint, parse_json, parse_yaml_documents
from dexjax.render.camera import MAX_FOCAL_LENGTH, Camera, Intrinsics, check_image_side

ROTATION_TOLERANCE = 1e-4  # max |R^T R - I| and |det R - 1| accepted for a stored rotation



def _read_mapping(path: str | os.PathLike) -> dict[str, Any]:
  """The top-level mapping of the JSON or YAML file ``path`` (read by `dexjax.config.parse_json` or
  `parse_yaml_documents`: too deep nesting and duplicate YAML keys are refused, naming the line)."""
  name = os.fspath(path)
  try:
    text = Path(path).read_text(encoding='utf-8')
  except UnicodeDecodeError as e:
    raise ValueError(f'{name}: not a text file (byte {e.start} is not UTF-8); expected a JSON or YAML mapping of '
                     'camera fields') from None
  is_yaml = Path(path).suffix.lower() in ('.yaml', '.yml')
  try:
    if is_yaml:
      documents = [d for d in parse_yaml_documents(text, name, expected=None) if d is not None]  # `rostopic echo`
      data = documents[0] if documents else None  # ends with '---'
    else:
      data = parse_json(text, name, expected=None)
  except ConfigError as e:
    kind = 'YAML' if is_yaml else 'JSON'
    raise ValueError(f'{name}: expected a {kind} mapping of camera fields, could not parse it: '
                     f'{e.field + ": " if e.field else ""}{e.problem}') from None
  if not isinstance(data, dict):
    raise ValueError(f'{name}: expected a mapping of camera fields at the top level, got {type(data).__name__}')
  return data


def _number(name: str, field: str, value: Any, expected: str = 'a finite number', ok=None) -> float:
  """``value`` as a float; raises ValueError naming ``name`` and ``field`` unless finite and ``ok(value)``."""
  message = f'{name}: {field}: expected {expected}, got {value!r}{number_hint(value)}'
  if isinstance(value, bool) or not isinstance(value, numbers.Real):
    raise ValueError(message)
  x = float(value)
  if not math.isfinite(x) or (ok is not None and not ok(x)):
    raise ValueError(message)
  return x


def _field(name: str, data: dict[str, Any], *fields: str) -> tuple[str, Any]:
  """(field, value) of the first of ``fields`` present in ``data``; raises ValueError if none is."""
  for field in fields:
    if field in data:
      return field, data[field]
  raise ValueError(f'{name}: {fields[0]}: missing field (expected {" or ".join(fields)})')


def _principal_point(name: str, fields: tuple[str, str], cx: float, cy: float, width: int, height: int) -> None:
  """Raises ValueError naming the field (``fields``: the names of cx and cy in the file) unless the principal
  point lies in the image: 0 <= cx <= width, 0 <= cy <= height."""
  for field, value, size, side in ((fields[0], cx, width, 'width'), (fields[1], cy, height, 'height')):
    if not 0 <= value <= size:
      raise ValueError(f'{name}: {field}: expected a number in [0, {side} = {size}] (pixels; the principal point '
                       f'lies in the image), got {value:g}')


def _make_intrinsics(name: str, fx: float, fy: float, cx: float, cy: float, width: int, height: int, *,
                     fields: tuple[str, str] = ('cx', 'cy')) -> Intrinsics:
  """`Intrinsics` with float32 scalar arrays, once the principal point is checked (`_principal_point`)."""
  _principal_point(name, fields, cx, cy, width, height)
  return Intrinsics(fx=jnp.float32(fx), fy=jnp.float32(fy), cx=jnp.float32(cx), cy=jnp.float32(cy),
                    width=width, height=height)


#: What a focal length must be (`_focal`).
_FOCAL = f'a finite number > 0 and <= {MAX_FOCAL_LENGTH:.0e} (pixels; MAX_FOCAL_LENGTH)'


def _focal(name: str, field: str, value: Any, expected: str = _FOCAL) -> float:
  """A focal length fx or fy in (0, `MAX_FOCAL_LENGTH`] pixels; ValueError naming ``name`` and ``field``."""
  return _number(name, field, value, expected, lambda x: 0 < x <= MAX_FOCAL_LENGTH)


def _plain_intrinsics(name: str, data: dict[str, Any]) -> Intrinsics:
  """Intrinsics from our ``fx, fy, cx, cy, width, height`` fields."""
  fx = _focal(name, 'fx', _field(name, data, 'fx')[1])
  fy = _focal(name, 'fy', _field(name, data, 'fy')[1])
  cx = _number(name, 'cx', _field(name, data, 'cx')[1], 'a finite number (pixels)')
  cy = _number(name, 'cy', _field(name, data, 'cy')[1], 'a finite number (pixels)')
  width = check_image_side(name, 'width', _field(name, data, 'width')[1])
  height = check_image_side(name, 'height', _field(name, data, 'height')[1])
  return _make_intrinsics(name, fx, fy, cx, cy, width, height)


def _flat_numbers(value: Any) -> list[Any] | None:
  """A flat list from a flat or nested (row-major) list, or None if ``value`` is not a list."""
  if not isinstance(value, (list, tuple)):
    return None
  if all(isinstance(row, (list, tuple)) for row in value):
    return [x for row in value for x in row]
  return list(value)


def _matrix_k(name: str, field: str, value: Any) -> tuple[float, float, float, float]:
  """(fx, fy, cx, cy) from a row-major 3 x 3 camera matrix [fx, s, cx, 0, fy, cy, 0, 0, 1]."""
  expected = 'a row-major 3x3 camera matrix [fx, 0, cx, 0, fy, cy, 0, 0, 1] (9 numbers)'
  k = _flat_numbers(value)
  if k is None or len(k) != 9:
    raise ValueError(f'{name}: {field}: expected {expected}, got {value!r}')
  k = [_number(name, f'{field}[{i}]', x, f'a finite number in {expected}') for i, x in enumerate(k)]
  focal = f'{_FOCAL}; an all-zero K means the camera is uncalibrated'
  fx = _focal(name, f'{field}[0] (fx)', k[0], focal)
  fy = _focal(name, f'{field}[4] (fy)', k[4], focal)
  if k[3] != 0 or k[6] != 0 or k[7] != 0 or k[8] != 1:
    raise ValueError(f'{name}: {field}: expected {expected}, got {value!r}')
  if k[1] != 0:
    warnings.warn(f'{name}: {field}[1]: skew {k[1]} is ignored (dexjax pinholes have no skew)', UserWarning,
                  stacklevel=4)
  return fx, fy, k[2], k[5]


def _warn_distortion(name: str, field: str, value: Any) -> None:
  """UserWarning if the distortion coefficients ``value`` contain a non-zero number."""
  coefficients = _flat_numbers(value) or []
  if any(isinstance(c, numbers.Real) and c != 0 for c in coefficients):
    warnings.warn(f'{name}: {field}: non-zero distortion coefficients {coefficients} are ignored (dexjax '
                  'cameras are undistorted pinholes); for rectified images use the left 3x3 block of P',
                  UserWarning, stacklevel=4)


def _ros_intrinsics(name: str, data: dict[str, Any]) -> Intrinsics:
  """Intrinsics from a ROS CameraInfo dump (``width``, ``height``, ``K``/``k``, ``D``/``d``)."""
  field, k = _field(name, data, 'K', 'k')
  fx, fy, cx, cy = _matrix_k(name, field, k)
  width = check_image_side(name, 'width', _field(name, data, 'width')[1])
  height = check_image_side(name, 'height', _field(name, data, 'height')[1])
  for d in ('D', 'd'):
    if d in data:
      _warn_distortion(name, d, data[d])
  return _make_intrinsics(name, fx, fy, cx, cy, width, height, fields=(f'{field}[2] (cx)', f'{field}[5] (cy)'))


def _calibration_intrinsics(name: str, data: dict[str, Any]) -> Intrinsics:
  """Intrinsics from a camera_calibration YAML (``image_width``, ``camera_matrix: {data}``, ...)."""
  matrix = data['camera_matrix']
  if not isinstance(matrix, dict) or 'data' not in matrix:
    raise ValueError(f'{name}: camera_matrix: expected a mapping with data: [9 numbers], got {matrix!r}')
  fx, fy, cx, cy = _matrix_k(name, 'camera_matrix.data', matrix['data'])
  width = check_image_side(name, 'image_width', _field(name, data, 'image_width')[1])
  height = check_image_side(name, 'image_height', _field(name, data, 'image_height')[1])
  distortion = data.get('distortion_coefficients')
  if isinstance(distortion, dict) and 'data' in distortion:
    _warn_distortion(name, 'distortion_coefficients.data', distortion['data'])
  return _make_intrinsics(name, fx, fy, cx, cy, width, height,
                          fields=('camera_matrix.data[2] (cx)', 'camera_matrix.data[5] (cy)'))


def _intrinsics_from_mapping(name: str, data: dict[str, Any]) -> Intrinsics:
  """Intrinsics from whichever supported format ``data`` is in (ours first)."""
  if 'fx' in data:
    return _plain_intrinsics(name, data)
  if 'K' in data or 'k' in data:
    return _ros_intrinsics(name, data)
  if 'camera_matrix' in data:
    return _calibration_intrinsics(name, data)
  raise ValueError(f'{name}: fx: missing field (expected fx, fy, cx, cy, width, height, or a ROS CameraInfo '
                   'with K, width, height)')


def _decimal(value: Any) -> Any:
  """``value`` (a scalar or array) as Python floats, each the shortest decimal that reads back to the same number
  in its own precision: a float32 575.8 is written 575.8, not 575.7999877929688."""
  array = np.asarray(value)
  if array.dtype == np.float32:
    return np.vectorize(lambda v: float(str(np.float32(v))), otypes=[float])(array).tolist()
  return np.asarray(array, np.float64).tolist()


def _intrinsics_dict(name: str, intrinsics: Intrinsics) -> dict[str, Any]:
  """Our JSON fields of ``intrinsics``, checked as `load_intrinsics` would check them."""
  try:
    data = {f: float(_decimal(getattr(intrinsics, f))) for f in ('fx', 'fy', 'cx', 'cy')}
  except TypeError:
    raise ValueError(f'{name}: fx: expected scalar intrinsics (one camera, not a batch), '
                     f'got fx of shape {np.shape(intrinsics.fx)}') from None
  data.update(width=intrinsics.width, height=intrinsics.height)
  _plain_intrinsics(name, data)
  return data


def _write_json(path: str | os.PathLike, data: dict[str, Any]) -> None:
  """Writes ``data`` as indented JSON."""
  Path(path).write_text(json.dumps(data, indent=2) + '\n', encoding='utf-8')


def save_intrinsics(path: str | os.PathLike, intrinsics: Intrinsics) -> None:
  """Writes one camera's ``intrinsics`` to ``path`` as JSON ``{fx, fy, cx, cy, width, height}`` (pixels)."""
  _write_json(path, _intrinsics_dict(os.fspath(path), intrinsics))


def load_intrinsics(path: str | os.PathLike) -> Intrinsics:
  """Reads `Intrinsics` (float32 scalars) from our JSON, a ROS CameraInfo JSON/YAML or a calibration YAML.

  Raises:
    ValueError: naming the file, the field and the expected value, for a missing, non-finite or
      out-of-range field or a malformed K.
  Warns:
    UserWarning: if distortion coefficients are non-zero (distortion is ignored).
  """
  return _intrinsics_from_mapping(os.fspath(path), _read_mapping(path))


def _rotation(name: str, value: Any) -> np.ndarray:
  """(3, 3) float64 rotation from nested rows; raises ValueError unless orthonormal with det +1."""
  expected = (f'a 3x3 rotation matrix as 3 rows of 3 finite numbers (orthonormal, det +1, tolerance '
              f'{ROTATION_TOLERANCE})')
  rows = value if isinstance(value, (list, tuple)) else None
  if rows is None or len(rows) != 3 or not all(isinstance(r, (list, tuple)) and len(r) == 3 for r in rows):
    raise ValueError(f'{name}: rotation: expected {expected}, got {value!r}')
  m = np.array([[_number(name, f'rotation[{i}][{j}]', x) for j, x in enumerate(r)]
                for i, r in enumerate(rows)])
  error = np.abs(m.T @ m - np.eye(3)).max()
  det = np.linalg.det(m)
  if error > ROTATION_TOLERANCE or abs(det - 1.0) > ROTATION_TOLERANCE:
    raise ValueError(f'{name}: rotation: expected {expected}, got max |R^T R - I| = {error:.3g} and '
                     f'det = {det:.6g}')
  return m


def _position(name: str, value: Any) -> np.ndarray:
  """(3,) float64 camera position, metres; raises ValueError unless 3 finite numbers."""
  if not isinstance(value, (list, tuple)) or len(value) != 3:
    raise ValueError(f'{name}: position: expected 3 finite numbers (metres), got {value!r}')
  return np.array([_number(name, f'position[{i}]', x, 'a finite number (metres)') for i, x in enumerate(value)])


def save_camera(path: str | os.PathLike, camera: Camera) -> None:
  """Writes one posed ``camera`` to ``path`` as JSON: intrinsics fields plus ``rotation`` (3 rows of 3,
  world-from-camera) and ``position`` (3, metres). The rotation is checked as `load_camera` checks it."""
  name = os.fspath(path)
  data = _intrinsics_dict(name, camera.intrinsics)
  _rotation(name, np.asarray(camera.rotation, np.float64).tolist())  # checked as load_camera checks it
  _position(name, np.asarray(camera.position, np.float64).tolist())
  data['rotation'] = _decimal(camera.rotation)
  data['position'] = _decimal(camera.position)
  _write_json(path, data)


def load_camera(path: str | os.PathLike) -> Camera:
  """Reads a posed `Camera` written by `save_camera` (float32 arrays; intrinsics in any accepted format).

  Raises:
    ValueError: naming the file and the field, for bad intrinsics, a missing or malformed ``rotation`` (not
      orthonormal with det +1 within 1e-4) or ``position`` (not 3 finite numbers).
  """
  name = os.fspath(path)
  data = _read_mapping(path)
  intrinsics = _intrinsics_from_mapping(name, data)
  rotation = _rotation(name, _field(name, data, 'rotation')[1])
  position = _position(name, _field(name, data, 'position')[1])
  return Camera(intrinsics=intrinsics, rotation=jnp.asarray(rotation, jnp.float32),
                position=jnp.asarray(position, jnp.float32))


def load_pose(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
  """(rotation (3, 3), position (3,) metres), float64, of a posed camera file: its ``rotation`` (world-from-camera,
  checked as `load_camera` checks it) and ``position``; intrinsics fields, if any, are not read (a world pose
  needs none).

  Raises:
    ValueError: naming the file and the field (``rotation`` or ``position``) with the expected value.
  """
  name = os.fspath(path)
  data = _read_mapping(path)
  return _rotation(name, _field(name, data, 'rotation')[1]), _position(name, _field(name, data, 'position')[1])


def check_camera_view(name: str, camera: Camera, floor_height: float = 0.0, far: float | None = None) -> Camera:
  """Checks that a posed camera can see the bin: its centre is above the floor (world z = ``floor_height``,
  metres), closer to it than the renderer's ``far`` depth (metres; None: not checked), and at least one pixel's
  ray goes down toward it. Returns ``camera``.

  A camera below the floor or looking away from it renders an image without a valid pixel; this finds it before
  any rendering. (Every ray of the image lies in the cone spanned by the four corner rays, so checking those
  is exact for the floor plane.)

  Raises:
    ValueError: naming ``name`` and the field (``position`` or ``rotation``) with the expected value.
  """
  position = np.asarray(camera.position, np.float64)
  if not position[2] > floor_height:
    raise ValueError(f'{name}: position: expected a camera above the floor (position[2] > {floor_height:g} m), '
                     f'got position[2] = {position[2]:g} m')
  if far is not None and position[2] - floor_height >= far:
    raise ValueError(f'{name}: position: expected a camera less than the far depth {far:g} m above the floor, got '
                     f'position[2] = {position[2]:g} m (every pixel would be beyond the depth range)')
  k = camera.intrinsics
  fx, fy, cx, cy = (float(np.asarray(v)) for v in (k.fx, k.fy, k.cx, k.cy))
  corners = np.array([[(u - cx) / fx, (v - cy) / fy, 1.0] for u in (0.0, k.width - 1.0)
                      for v in (0.0, k.height - 1.0)])
  down = corners @ np.asarray(camera.rotation, np.float64).T
  if not (down[:, 2] < 0).any():
    axis = np.asarray(camera.rotation, np.float64)[:, 2]
    raise ValueError(f'{name}: rotation: expected a camera looking down at the bin (the optical axis, the third '
                     f'column, with a negative z component, e.g. [0, 0, -1]), got optical axis '
                     f'[{axis[0]:.3g}, {axis[1]:.3g}, {axis[2]:.3g}]: no pixel can see the floor')
  return camera


def load_camera_or_intrinsics(path: str | os.PathLike) -> tuple[Intrinsics, Camera | None]:
  """(intrinsics, posed camera or None) of a file: a `save_camera` file (it has ``rotation``) gives both, an
  intrinsics file (any format `load_intrinsics` reads) only the intrinsics. Errors as those two functions."""
  data = _read_mapping(path)
  if 'rotation' in data:
    camera = load_camera(path)
    return camera.intrinsics, camera
  return load_intrinsics(path), None

