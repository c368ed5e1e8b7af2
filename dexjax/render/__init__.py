"""Depth cameras: the Dex-Net 4.0 camera distribution, intrinsics files, depth rendering with masks, noise.

`Camera` / `Intrinsics` are pytrees (OpenCV convention: x right, y down, z forward; depth = camera-frame z in
metres); `project` / `deproject` are jittable single-camera functions (`vmap` to batch). `sample_camera` draws
the seed's camera distribution. `DepthRenderer` renders `RenderScene` s (a settled heap built once) to depth
images with per-pixel heap-slot masks, with headless OpenGL (EGL or OSMesa) or MuJoCo ray casting. Sensor
noise (`apply_sensor_noise`) is optional and off by default. See ``docs/cameras.md`` and ``docs/rendering.md``.
"""

from dexjax.render.camera import (Camera, Intrinsics, camera_to_world, deproject, look_at, pixel_rays, project,
                                  world_to_camera)
from dexjax.render.distribution import CameraDistribution, camera_from_spherical, sample_camera, spherical_from_camera
from dexjax.render.intrinsics_io import (ROTATION_TOLERANCE, check_camera_view, load_camera,
                                         load_camera_or_intrinsics, load_intrinsics, save_camera, save_intrinsics)
from dexjax.render.noise import (SensorNoise, apply_sensor_noise, dropout, noisy_depth, gamma_depth_noise,
                                 gaussian_process_noise)
from dexjax.render.rendering import (BACKENDS, BIN_LABEL, INVALID_LABEL, TABLE_HALF_SIZE, DepthImage, DepthRenderer,
                                     RenderScene, RenderSettings, build_render_scene, empty_bin_scene,
                                     render_boxes, render_depth, settled_heap_scene)

__all__ = [
    "Camera", "Intrinsics", "camera_to_world", "deproject", "look_at", "pixel_rays", "project", "world_to_camera",
    "CameraDistribution", "camera_from_spherical", "sample_camera", "spherical_from_camera", "ROTATION_TOLERANCE", "check_camera_view", "load_camera", "load_camera_or_intrinsics",
    "load_intrinsics", "save_camera", "save_intrinsics", "SensorNoise", "apply_sensor_noise", "noisy_depth", "dropout",
    "gamma_depth_noise", "gaussian_process_noise", "BACKENDS", "BIN_LABEL", "INVALID_LABEL", "TABLE_HALF_SIZE",
    "render_boxes", "DepthImage", "DepthRenderer", "RenderScene", "RenderSettings", "build_render_scene", "empty_bin_scene", "render_depth",
    "settled_heap_scene", "save_depth_png",
]


def __getattr__(name: str):
  """Lazily provides `save_depth_png` (imports matplotlib only when drawing)."""
  if name == 'save_depth_png':
    from dexjax.render.preview import save_depth_png  # pylint: disable=g-import-not-at-top
    return save_depth_png
  raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
