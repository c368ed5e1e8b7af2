"""Cameras of a generation run: the seed's distribution, or the user's intrinsics and (optionally) pose.

A camera file given to ``python -m dexjax.generate --camera-config FILE`` is one of

* a YAML mapping of `dexjax.render.CameraDistribution` fields (``radius``, ``theta_deg``, ``phi_deg``,
  ``center_x``, ``center_y``, ``focal``, ``cx``, ``cy``, ``width``, ``height``): ranges replacing the seed's;
* an intrinsics file (our JSON, a ROS CameraInfo as JSON or YAML, a camera_calibration YAML; see
  `dexjax.render.load_intrinsics`): every image uses these intrinsics (fx and fy may differ) and image size,
  the pose is still drawn from the distribution;
* a posed camera file (`dexjax.render.save_camera`: intrinsics plus ``rotation`` and ``position``): every image
  is taken from exactly this camera, which must be above the bin's floor and look down at it
  (`dexjax.render.intrinsics_io.check_camera_view`; otherwise every image would be empty).

The file's values (not its path) are stored in the `GenerateConfig`, so they are part of the run's fingerprint.
"""

from __future__ import annotations

import dataclasses
import os

import jax
import jax.numpy as jnp
import numpy as np

from dexjax.config import ConfigError, load_yaml, override, parse_yaml
from dexjax.render.camera import Camera, Intrinsics
from dexjax.render.distribution import CameraDistribution, sample_camera
from dexjax.render.intrinsics_io import check_camera_view, load_camera_or_intrinsics

_DISTRIBUTION_FIELDS = frozenset(f.name for f in dataclasses.fields(CameraDistribution))


def _is_distribution(path: str) -> bool:
  """True if ``path`` is a YAML mapping whose keys are all `CameraDistribution` fields."""
  if os.path.splitext(path)[1].lower() not in ('.yaml', '.yml'):
    return False
  try:
    with open(path, encoding='utf-8') as f:
      data = parse_yaml(f.read(), path)
  except (OSError, UnicodeDecodeError, ConfigError):
    return False  # load_intrinsics reports the problem
  return isinstance(data, dict) and bool(data) and set(data) <= _DISTRIBUTION_FIELDS


def _config_error(path: str, error: ValueError) -> ConfigError:
  """``error`` (a message starting with ``path``, or not) as a `ConfigError` of the file ``path``."""
  message = str(error)
  return ConfigError(path, '', message[len(path) + 2:] if message.startswith(f'{path}: ') else message)


def apply_camera_file(config, path: str | os.PathLike[str]):
  """``config`` (a `GenerateConfig`) with the camera of ``path`` applied (see the module docstring).

  Raises:
    ConfigError: the file cannot be read, or a field is missing or invalid (named with the file).
  """
  path = os.fspath(path)
  if _is_distribution(path):
    dist = override(config.camera, load_yaml(path), source=path, section='camera')
    try:
      dist.validate()
    except ValueError as e:  # also an image side past MAX_IMAGE_SIDE (dexjax.render.camera.check_image_side)
      raise ConfigError(path, 'camera', str(e)) from None
    return dataclasses.replace(config, camera=dist, camera_intrinsics=(), camera_pose=())
  try:
    k, camera = load_camera_or_intrinsics(path)
    if camera is not None:
      check_camera_view(path, camera, floor_height=0.0, far=config.render.far)  # the bin's floor is z = 0
  except OSError as e:
    raise ConfigError(path, '', f'cannot read the file ({e.strerror})') from None
  except ValueError as e:
    raise _config_error(path, e) from None
  pose = () if camera is None else tuple(float(x) for x in np.asarray(camera.rotation).reshape(-1)) + tuple(
      float(x) for x in np.asarray(camera.position))
  intrinsics = (float(k.fx), float(k.fy), float(k.cx), float(k.cy), float(k.width), float(k.height))
  return dataclasses.replace(config, camera_intrinsics=intrinsics, camera_pose=pose)


def image_size(config) -> tuple[int, int]:
  """(width, height) in pixels of the run's images."""
  if config.camera_intrinsics:
    return int(config.camera_intrinsics[4]), int(config.camera_intrinsics[5])
  return config.camera.width, config.camera.height


def camera_distribution(config) -> CameraDistribution:
  """The distribution whose draws `run_camera` post-processes (its size matches `image_size`)."""
  width, height = image_size(config)
  return config.camera.replace(width=width, height=height)


def run_camera(key: jax.Array, config) -> Camera:
  """One camera of the run: drawn from the distribution, with the fixed intrinsics and pose where set."""
  camera = sample_camera(key, camera_distribution(config))
  if config.camera_intrinsics:
    fx, fy, cx, cy, width, height = config.camera_intrinsics
    camera = camera.replace(intrinsics=Intrinsics(fx=jnp.float32(fx), fy=jnp.float32(fy), cx=jnp.float32(cx),
                                                  cy=jnp.float32(cy), width=int(width), height=int(height)))
  if config.camera_pose:
    pose = np.asarray(config.camera_pose, np.float32)
    camera = camera.replace(rotation=jnp.asarray(pose[:9].reshape(3, 3)), position=jnp.asarray(pose[9:]))
  return camera


__all__ = ['apply_camera_file', 'camera_distribution', 'image_size', 'run_camera']
