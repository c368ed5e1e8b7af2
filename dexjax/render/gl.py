"""Headless OpenGL context selection for MuJoCo rendering: EGL, then OSMesa, probed without risk.

MuJoCo's Python package reads ``MUJOCO_GL`` once, when ``import mujoco`` runs (``mujoco/__init__.py`` imports
``mujoco.rendering.classic.gl_context``, which imports ``mujoco.egl``, ``mujoco.osmesa`` or, when the variable
is unset, ``mujoco.glfw``). `dexjax` imports mujoco at package import, so setting the variable here would be
too late; this module never relies on it. Instead it creates a context of the chosen platform explicitly
(``mujoco.egl.GLContext`` / ``mujoco.osmesa.GLContext``), which the renderer makes current itself.

Two facts shape the selection:

* PyOpenGL binds one platform per process, fixed by ``PYOPENGL_PLATFORM`` when ``OpenGL`` is first imported
  (``mujoco.egl`` sets it to ``egl``, ``mujoco.osmesa`` to ``osmesa``); once bound, the other platform cannot
  be loaded in the same process;
* a broken driver can fail at import, at context creation, or crash the process.

So each candidate platform is first probed in a short-lived child process (a context, a MuJoCo render
context and one frame); only a platform that passed is loaded here. Once a platform is bound in this process
(by us, by ``MUJOCO_GL``, or by other code importing PyOpenGL), only that one is offered.
"""

from __future__ import annotations

import functools
import importlib
import os
import subprocess
import sys
import weakref
from typing import Any

import mujoco
import numpy as np

#: Headless platforms in order of preference (EGL is usually faster and can use a GPU; OSMesa is software).
GL_PLATFORMS = ('egl', 'osmesa')

_PROBE_TIMEOUT_S = 120.0
_NOTHING = -2  # label of pixels where nothing was drawn (rendering.INVALID_LABEL)
_GEOM_CATEGORIES = mujoco.mjtCatBit.mjCAT_STATIC | mujoco.mjtCatBit.mjCAT_DYNAMIC
_PROBE_SCRIPT = '''
import importlib, sys
import mujoco
platform = sys.argv[1]
context = importlib.import_module('mujoco.' + platform).GLContext(16, 16)
context.make_current()
model = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size=".1"/></worldbody></mujoco>')
data = mujoco.MjData(model)
mujoco.mj_forward(model, data)
scene = mujoco.MjvScene(model, maxgeom=10)
camera = mujoco.MjvCamera()
mujoco.mjv_defaultFreeCamera(model, camera)
mujoco.mjv_updateScene(model, data, mujoco.MjvOption(), None, camera, mujoco.mjtCatBit.mjCAT_ALL, scene)
render_context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100)
mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, render_context)
mujoco.mjr_render(mujoco.MjrRect(0, 0, 16, 16), scene, render_context)
render_context.free()
context.free()
print('ok')
'''


def bound_platform() -> str | None:
  """The PyOpenGL platform already loaded in this process (``'egl'``, ``'osmesa'``, ``'glx'``, ...) or None."""
  if 'OpenGL.platform' not in sys.modules:
    return None
  return os.environ.get('PYOPENGL_PLATFORM', '').strip().lower() or 'default'


def _check_platform(platform: str) -> None:
  """Raises ValueError naming ``platform`` when it is not one of `GL_PLATFORMS`."""
  if platform not in GL_PLATFORMS:
    raise ValueError(f'gl_platform: expected one of {GL_PLATFORMS}, got {platform!r}')


@functools.lru_cache(maxsize=None)
def probe_platform(platform: str) -> str | None:
  """Tries ``platform`` in a child process (cached): None when it renders, else the reason it failed."""
  _check_platform(platform)
  env = {k: v for k, v in os.environ.items() if k != 'PYOPENGL_PLATFORM'}
  env['MUJOCO_GL'] = platform  # so the child's ``import mujoco`` binds the same platform
  try:
    run = subprocess.run([sys.executable, '-c', _PROBE_SCRIPT, platform], env=env, capture_output=True,
                         text=True, timeout=_PROBE_TIMEOUT_S, check=False)
  except (OSError, subprocess.TimeoutExpired) as e:
    return f'{platform}: probe failed: {e}'
  if run.returncode == 0 and run.stdout.strip().endswith('ok'):
    return None
  lines = (run.stderr or run.stdout).strip().splitlines()
  return f'{platform}: exit code {run.returncode}: {lines[-1] if lines else "no output"}'


def candidate_platforms() -> tuple[str, ...]:
  """Platforms worth probing: the bound one if any, else ``MUJOCO_GL`` first when it names one."""
  bound = bound_platform()
  if bound is not None:
    return (bound,) if bound in GL_PLATFORMS else ()
  preferred = os.environ.get('MUJOCO_GL', '').strip().lower()
  return tuple(sorted(GL_PLATFORMS, key=lambda p: p != preferred))


def available_platforms() -> tuple[str, ...]:
  """Platforms that can render in this process, in order of preference (probing every candidate once)."""
  return tuple(p for p in candidate_platforms() if probe_platform(p) is None)


def unavailable_reasons() -> dict[str, str]:
  """{platform: why it cannot be used here} for every platform of `GL_PLATFORMS` that is unusable."""
  candidates = candidate_platforms()
  reasons = {}
  for platform in GL_PLATFORMS:
    if platform not in candidates:
      reasons[platform] = f'{platform}: PyOpenGL is already bound to {bound_platform()!r} in this process'
    elif (reason := probe_platform(platform)) is not None:
      reasons[platform] = reason
  return reasons


def create_context(platform: str, width: int, height: int) -> Any:
  """A current headless GL context (``mujoco.<platform>.GLContext``) for images up to width x height.

  Raises:
    ValueError: ``platform`` is not one of `GL_PLATFORMS`.
    RuntimeError: the platform cannot be used in this process (see `unavailable_reasons`).
  """
  _check_platform(platform)
  if platform not in candidate_platforms() or probe_platform(platform) is not None:
    raise RuntimeError(f'gl_platform {platform!r} is unavailable: '
                       f'{unavailable_reasons().get(platform, "unknown reason")}')
  module = importlib.import_module(f'mujoco.{platform}')
  context = module.GLContext(width, height)
  context.make_current()
  return context


class _Resources:
  """The GL context and the uploaded model's render context; freed together (also at interpreter exit)."""

  def __init__(self, context: Any):
    self.context, self.render_context = context, None

  def free_model(self) -> None:
    """Frees the uploaded model's GL buffers (the context stays)."""
    if self.render_context is not None and self.context is not None:
      self.context.make_current()
      self.render_context.free()
    self.render_context = None

  def free(self) -> None:
    """Frees everything (idempotent)."""
    self.free_model()
    if self.context is not None:
      self.context.free()
      self.context = None


class GLDepthBackend:
  """Depth images and slot masks of MuJoCo models with one headless GL context of fixed size.

  The scene is uploaded (``MjrContext``: meshes to GL buffers) once per model and kept until another model is
  rendered. One pass with MuJoCo's segmentation flags draws every geom in a flat colour encoding its segment
  id (no lighting, no multisampling, no face culling) and fills the depth buffer (32-bit float, reversed z).
  """

  def __init__(self, platform: str, width: int, height: int):
    self.platform = platform
    self.width, self.height = width, height
    self._resources = _Resources(create_context(platform, width, height))
    self._finalizer = weakref.finalize(self, self._resources.free)
    self._model, self._scene, self._segid_labels = None, None, None
    self._rgb = np.empty((height, width, 3), np.uint8)
    self._depth = np.empty((height, width), np.float32)

  def _load(self, model: mujoco.MjModel, data: mujoco.MjData, geom_labels: np.ndarray) -> None:
    """Uploads ``model`` (if not the loaded one) and maps segment colours to labels."""
    if model is self._model:
      return
    self._resources.free_model()
    self._model = None
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, self.width)
    model.vis.global_.offheight = max(model.vis.global_.offheight, self.height)
    model.vis.quality.offsamples = 0  # no multisampling: segment colours must not blend at edges
    model.vis.quality.shadowsize = 0  # no shadows are drawn; the default 4096^2 shadow map made every upload slow
    scene = mujoco.MjvScene(model, maxgeom=model.ngeom + 16)
    camera = mujoco.MjvCamera()
    mujoco.mjv_defaultFreeCamera(model, camera)
    mujoco.mjv_updateScene(model, data, mujoco.MjvOption(), None, camera, _GEOM_CATEGORIES, scene)
    for flag, value in ((mujoco.mjtRndFlag.mjRND_SEGMENT, 1), (mujoco.mjtRndFlag.mjRND_IDCOLOR, 1),
                        (mujoco.mjtRndFlag.mjRND_CULL_FACE, 0), (mujoco.mjtRndFlag.mjRND_SHADOW, 0),
                        (mujoco.mjtRndFlag.mjRND_REFLECTION, 0), (mujoco.mjtRndFlag.mjRND_SKYBOX, 0)):
      scene.flags[flag] = value
    self._resources.context.make_current()
    render_context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_50)
    mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, render_context)
    render_context.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
    self._resources.render_context = render_context
    self._model, self._scene = model, scene
    self._segid_labels = _segid_labels(scene, geom_labels)

  def render(self, model: mujoco.MjModel, data: mujoco.MjData, geom_labels: np.ndarray, view: dict[str, Any]
             ) -> tuple[np.ndarray, np.ndarray]:
    """Renders ``model`` from the GL camera ``view`` (see `dexjax.render.rendering.gl_view`).

    Args:
      model, data: the scene (``data`` holds the geom poses).
      geom_labels: (ngeom,) int32 label of each geom.
      view: ``MjvGLCamera`` fields.

    Returns:
      (depth (H, W) float32 planar depth, metres, NaN where nothing was drawn; labels (H, W) int32, -2 where
      nothing was drawn), rows top to bottom.
    """
    if self._resources.context is None:
      raise RuntimeError('GLDepthBackend.render: the backend is closed')
    self._load(model, data, geom_labels)
    for camera in self._scene.camera:
      for name, value in view.items():
        setattr(camera, name, value)
    self._resources.context.make_current()
    rect = mujoco.MjrRect(0, 0, self.width, self.height)
    mujoco.mjr_render(rect, self._scene, self._resources.render_context)
    mujoco.mjr_readPixels(self._rgb, self._depth, rect, self._resources.render_context)
    labels = _decode_labels(self._rgb[::-1], self._segid_labels)
    depth = _metric_depth(self._depth[::-1], view['frustum_near'], view['frustum_far'])
    depth[labels == _NOTHING] = np.nan
    return depth, labels

  def close(self) -> None:
    """Frees the GL resources and the context (idempotent)."""
    self._finalizer()
    self._model = self._scene = None


def _segid_labels(scene: mujoco.MjvScene, geom_labels: np.ndarray) -> np.ndarray:
  """(max(ngeom + 1, 256),) int32 label of each colour value segid + 1; `_NOTHING` for background (0)."""
  table = np.full(max(scene.ngeom + 1, 256), _NOTHING, np.int32)
  for k in range(scene.ngeom):
    geom = scene.geoms[k]
    if geom.segid >= 0 and geom.objtype == mujoco.mjtObj.mjOBJ_GEOM:
      table[geom.segid + 1] = geom_labels[geom.objid]
  return table


def _decode_labels(rgb: np.ndarray, segid_labels: np.ndarray) -> np.ndarray:
  """(H, W) int32 labels of segment colours (H, W, 3) uint8 (value segid + 1 = r + 256 g + 65536 b)."""
  if len(segid_labels) == 256:  # at most 255 geoms: the red channel holds the whole value
    return segid_labels[rgb[..., 0]]
  value = rgb[..., 0].astype(np.int64) | (rgb[..., 1].astype(np.int64) << 8) | (rgb[..., 2].astype(np.int64) << 16)
  return segid_labels[np.minimum(value, len(segid_labels) - 1)]


def _metric_depth(buffer: np.ndarray, near: float, far: float) -> np.ndarray:
  """Planar depth (H, W) float32, metres, from a reversed-z depth buffer (1 at ``near``, 0 at ``far``).

  The inverse of MuJoCo's projection (``glFrustum`` then z -> (1 - z) / 2), as in ``mujoco.Renderer``;
  float32 arithmetic costs < 0.01 mm at 1 m for near = 1 cm.
  """
  c = np.float32(0.5 * (far + near) / (far - near) - 0.5)
  d = np.float32(far * near / (far - near))
  out = np.add(buffer, c, dtype=np.float32)
  return np.divide(d, out, out=out)
