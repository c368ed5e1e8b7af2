"""Depth images and segmentation masks of settled heaps, rendered with MuJoCo (headless OpenGL or ray casting).

A `RenderScene` is one heap as a static MuJoCo model, built once: the bin (floor slab and four walls, exactly
`dexjax.sim.Bin`), the table it stands in (top at z = 0, as the physics' ground plane) and every heap object as its full visual mesh (all faces as given, not the convex hulls) at
its settled pose. A `DepthRenderer` of fixed width x height renders any number of scenes from any `Camera`:

* ``backend='gl'``: MuJoCo's OpenGL renderer on a headless context (EGL, else OSMesa; see
  `dexjax.render.gl`); one pass gives the depth buffer and flat segment colours;
* ``backend='raycast'``: one ray per pixel centre with ``mujoco.mj_multiRay`` (exact ray-triangle and
  ray-box intersections, threads over image rows);
* ``backend='auto'``: GL when a context can be made, else ray casting.

Conventions (both backends): ``depth`` (H, W) float32 is the planar depth (camera-frame z, not the distance
along the ray), metres, NaN where no surface lies within [near, far]; ``mask`` (H, W) int32 is the heap slot
(0..P-1, the slot of the `HeapState` / `SettleResult`, not the object id) of object pixels, `BIN_LABEL` (-1)
for the bin and `INVALID_LABEL` (-2) where depth is NaN. Pixel (row i, column j) looks through the point
u = j, v = i of `dexjax.render.camera` (OpenCV convention).
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import mujoco
import numpy as np
import trimesh
from flax import struct

from dexjax.render import gl
from dexjax.render.camera import Camera
from dexjax.sim.heap import Bin
from dexjax.sim.scene import bin_boxes
from dexjax.sim.settling import SettleResult

BACKENDS = ('auto', 'gl', 'raycast')
#: Mask value of bin (floor and wall) pixels.
BIN_LABEL = -1
#: Mask value of pixels without a surface within [near, far] (depth NaN).
INVALID_LABEL = -2


@struct.dataclass
class RenderSettings:
  """Depth range and ray-casting options (all static).

  Attributes:
    near: nearest rendered depth, metres (GL clips closer geometry; ray casting drops closer hits).
    far: farthest rendered depth, metres; surfaces beyond are invalid.
    raycast_threads: threads of the ray-casting backend; None: ``os.cpu_count()``.
  """

  near: float = struct.field(pytree_node=False, default=0.01)
  far: float = struct.field(pytree_node=False, default=10.0)
  raycast_threads: int | None = struct.field(pytree_node=False, default=None)

  def validate(self) -> None:
    """Raises ValueError naming the field and the expected value."""
    if not (np.isfinite(self.near) and self.near > 0):
      raise ValueError(f'RenderSettings.near: expected a finite number > 0 (metres), got {self.near!r}')
    if not (np.isfinite(self.far) and self.far > self.near):
      raise ValueError(f'RenderSettings.far: expected a finite number > near = {self.near} (metres), '
                       f'got {self.far!r}')
    threads = self.raycast_threads
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
      raise ValueError(f'RenderSettings.raycast_threads: expected None or an int >= 1, got {threads!r}')


@dataclasses.dataclass(frozen=True, eq=False)
class RenderScene:
  """One heap as a static MuJoCo model (build with `build_render_scene`; reuse for every camera).

  Attributes:
    model: the compiled model: every geom static in the world body, collisions off.
    data: its `MjData` with geom poses computed.
    geom_labels: (ngeom,) int32 mask value of each geom: its heap slot, or `BIN_LABEL`.
    num_slots: P, the heap's padded slot count.
  """

  model: mujoco.MjModel
  data: mujoco.MjData
  geom_labels: np.ndarray
  num_slots: int


@dataclasses.dataclass(frozen=True, eq=False)
class DepthImage:
  """One rendered view.

  Attributes:
    depth: (H, W) float32 planar depth (camera-frame z), metres; NaN where no surface is within [near, far].
    mask: (H, W) int32 heap slot per object pixel, `BIN_LABEL` for the bin, `INVALID_LABEL` where depth is NaN.
    backend: the backend that rendered it: ``'gl_egl'``, ``'gl_osmesa'`` or ``'raycast'``.
  """

  depth: np.ndarray
  mask: np.ndarray
  backend: str


def _static_geom(parent: mujoco.MjsBody, **kwargs: Any) -> None:
  """Adds a geom that only renders and ray casts (no collisions), in geom group 0."""
  parent.add_geom(contype=0, conaffinity=0, group=0, **kwargs)


TABLE_HALF_SIZE = 1.0
"""Half the side of the square table the bin stands in, metres (its top is the plane z = 0, like the physics'
ground plane, so pixels beyond the bin see a surface rather than nothing)."""


def render_boxes(b: Bin) -> list[tuple[np.ndarray, np.ndarray]]:
  """(centre (3,), half size (3,)) of the bin's floor slab and four walls (`dexjax.sim.bin_boxes`) and of
  the table (top at z = 0, 5 cm thick, 2 `TABLE_HALF_SIZE` wide), world frame, metres; all labelled bin."""
  table = (np.array([0.0, 0.0, -0.025]), np.array([TABLE_HALF_SIZE, TABLE_HALF_SIZE, 0.025]))
  return [*bin_boxes(b), table]


def _add_bin(spec: mujoco.MjSpec, b: Bin) -> None:
  """The bin and the table it stands in, as boxes (`render_boxes`)."""
  for k, (centre, half) in enumerate(render_boxes(b)):
    _static_geom(spec.worldbody, name=f'bin{k}', type=mujoco.mjtGeom.mjGEOM_BOX, pos=centre, size=half)


def _add_object(spec: mujoco.MjSpec, slot: int, mesh: trimesh.Trimesh, pose: np.ndarray) -> None:
  """Adds the full mesh of heap slot ``slot`` at ``pose`` (7,): position (metres) and quaternion wxyz."""
  spec.add_mesh(name=f'slot{slot}', uservert=np.asarray(mesh.vertices, np.float64).ravel(),
                userface=np.asarray(mesh.faces, np.int32).ravel(), inertia=mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL)
  quat = pose[3:] / np.linalg.norm(pose[3:])
  _static_geom(spec.worldbody, name=f'slot{slot}', type=mujoco.mjtGeom.mjGEOM_MESH, meshname=f'slot{slot}',
               pos=pose[:3], quat=quat)


def _check_heap(meshes: Sequence[trimesh.Trimesh], object_ids: np.ndarray, poses: np.ndarray,
                mask: np.ndarray) -> None:
  """Raises ValueError naming the argument when shapes, ids or poses are invalid."""
  pad = mask.shape[0] if mask.ndim == 1 else -1
  if pad < 0 or object_ids.shape != (pad,) or poses.shape != (pad, 7):
    raise ValueError(f'build_render_scene: expected object_ids (P,), poses (P, 7) and mask (P,), got shapes '
                     f'{object_ids.shape}, {poses.shape} and {mask.shape}')
  bad = [int(i) for i in object_ids[mask] if not 0 <= i < len(meshes)]
  if bad:
    raise ValueError(f'build_render_scene: object_ids: expected ids in [0, {len(meshes)}) (the meshes), got {bad}')
  if not np.all(np.isfinite(poses[mask])) or np.any(np.linalg.norm(poses[mask, 3:], axis=-1) < 1e-9):
    raise ValueError('build_render_scene: poses: expected finite positions and non-zero quaternions (w, x, y, z) '
                     'in the heap\'s slots')


def build_render_scene(meshes: Sequence[trimesh.Trimesh], object_ids: Any, poses: Any, mask: Any, *,
                       bin: Bin = Bin()) -> RenderScene:  # pylint: disable=redefined-builtin
  """The render model of one heap: the bin and each slot's full mesh at its pose.

  Args:
    meshes: the N available meshes in their object frames, metres (``object_ids`` index into them).
    object_ids: (P,) int ids per slot (as `HeapState.object_ids`; ignored where ``mask`` is False).
    poses: (P, 7) object-frame poses in the world frame: position (metres), quaternion (w, x, y, z), as
      `SettleResult.poses` of one heap.
    mask: (P,) bool, the heap's slots.
    bin: the bin's geometry.

  Raises:
    ValueError: bad shapes, ids or poses, an invalid bin, or a mesh MuJoCo rejects (named by slot).
  """
  bin.validate()
  object_ids, poses = np.asarray(object_ids).astype(np.int64), np.asarray(poses, np.float64)
  mask = np.asarray(mask, bool)
  _check_heap(meshes, object_ids, poses, mask)
  spec = mujoco.MjSpec()
  spec.modelname = 'heap_render'
  _add_bin(spec, bin)
  slots = np.flatnonzero(mask)
  for slot in slots:
    _add_object(spec, int(slot), meshes[int(object_ids[slot])], poses[slot])
  try:
    model = spec.compile()
  except ValueError as e:
    raise ValueError(f'build_render_scene: MuJoCo rejected a mesh of slots {slots.tolist()}: {e}') from e
  data = mujoco.MjData(model)
  mujoco.mj_kinematics(model, data)
  labels = np.concatenate([np.full(len(render_boxes(bin)), BIN_LABEL), slots]).astype(np.int32)
  return RenderScene(model=model, data=data, geom_labels=labels, num_slots=int(mask.shape[0]))


def empty_bin_scene(*, bin: Bin = Bin(), num_slots: int = 0) -> RenderScene:  # pylint: disable=redefined-builtin
  """The render model of the empty bin (``num_slots`` padded slots, all empty)."""
  return build_render_scene([], np.full(num_slots, -1), np.tile([0.0, 0, 0, 1, 0, 0, 0], (num_slots, 1)),
                            np.zeros(num_slots, bool), bin=bin)


def settled_heap_scene(meshes: Sequence[trimesh.Trimesh], object_ids: Any, result: SettleResult, heap: int, *,
                       bin: Bin = Bin()) -> RenderScene:  # pylint: disable=redefined-builtin
  """The render model of heap ``heap`` of a `SettleResult` (``object_ids`` (B, P) as `HeapState.object_ids`)."""
  return build_render_scene(meshes, np.asarray(object_ids)[heap], result.poses[heap], result.mask[heap], bin=bin)


def _camera_arrays(camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
  """(fx, fy, cx, cy) (4,), rotation (3, 3) and position (3,) as float64 NumPy arrays; checks them."""
  k = camera.intrinsics
  fxy = np.array([float(k.fx), float(k.fy), float(k.cx), float(k.cy)])
  rotation, position = np.asarray(camera.rotation, np.float64), np.asarray(camera.position, np.float64)
  if not (np.all(np.isfinite(fxy)) and fxy[0] > 0 and fxy[1] > 0):
    raise ValueError(f'Camera.intrinsics: expected finite fx, fy > 0 and finite cx, cy (pixels), got {fxy.tolist()}')
  if rotation.shape != (3, 3) or not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-4):
    raise ValueError('Camera.rotation: expected a (3, 3) rotation matrix (orthonormal columns)')
  if position.shape != (3,) or not np.all(np.isfinite(position)):
    raise ValueError(f'Camera.position: expected 3 finite numbers (metres), got {position.tolist()}')
  return fxy, rotation, position


def gl_view(camera: Camera, near: float, far: float) -> dict[str, Any]:
  """MuJoCo ``MjvGLCamera`` fields that reproduce ``camera`` exactly (frustum through the pixel edges).

  Pixel centres are at integer (u, v), so the image spans u in [-0.5, W - 0.5], v in [-0.5, H - 0.5]; the GL
  camera looks along ``forward`` = our z with ``up`` = -y, and its frustum is given at the near plane.
  """
  (fx, fy, cx, cy), rotation, position = _camera_arrays(camera)
  w, h = camera.intrinsics.width, camera.intrinsics.height
  left, right = near * (-0.5 - cx) / fx, near * (w - 0.5 - cx) / fx
  top, bottom = near * (cy + 0.5) / fy, -near * (h - 0.5 - cy) / fy
  return {'pos': position, 'forward': rotation[:, 2], 'up': -rotation[:, 1],
          'frustum_center': 0.5 * (left + right), 'frustum_width': 0.5 * (right - left),
          'frustum_bottom': bottom, 'frustum_top': top, 'frustum_near': near, 'frustum_far': far,
          'orthographic': 0}


@functools.lru_cache(maxsize=8)
def _unit_depth_rays(fx: float, fy: float, cx: float, cy: float, width: int, height: int) -> np.ndarray:
  """(H W, 3) float64 camera-frame rays through the pixel centres with z = 1, row-major (read-only)."""
  v, u = np.meshgrid(np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing='ij')
  rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1).reshape(-1, 3)
  rays.flags.writeable = False
  return rays


class _RaycastBackend:
  """Per-pixel ray casting with ``mj_multiRay`` over static geoms of group 0, split across threads."""

  def __init__(self, threads: int):
    self._threads = threads
    self._pool = ThreadPoolExecutor(threads) if threads > 1 else None
    self._model, self._datas = None, []

  def _thread_datas(self, scene: RenderScene) -> list[mujoco.MjData]:
    """One `MjData` per thread (ray casting uses the data's scratch stack), made once per scene."""
    if scene.model is not self._model:
      self._model = scene.model
      self._datas = [scene.data] + [_kinematics(scene.model) for _ in range(self._threads - 1)]
    return self._datas

  def render(self, scene: RenderScene, camera: Camera, far: float) -> tuple[np.ndarray, np.ndarray]:
    """(planar depth (H, W) float64 metres, geom id (H, W) int32, -1 for no hit) of ``camera``."""
    (fx, fy, cx, cy), rotation, position = _camera_arrays(camera)
    w, h = camera.intrinsics.width, camera.intrinsics.height
    vec = np.ascontiguousarray(_unit_depth_rays(fx, fy, cx, cy, w, h) @ rotation.T).reshape(-1)
    n = w * h
    geom, dist = np.empty(n, np.int32), np.empty(n, np.float64)
    group = np.array([1, 0, 0, 0, 0, 0], np.uint8)
    bounds = np.linspace(0, n, len(self._thread_datas(scene)) + 1).astype(int)

    def cast(k: int) -> None:
      lo, hi = bounds[k], bounds[k + 1]
      mujoco.mj_multiRay(scene.model, self._datas[k], position, vec[3 * lo:3 * hi], group, 1, -1, geom[lo:hi],
                         dist[lo:hi], None, hi - lo, far)

    if self._pool is None:
      cast(0)
    else:
      list(self._pool.map(cast, range(len(bounds) - 1)))
    return dist.reshape(h, w), geom.reshape(h, w)  # rays have unit z, so the ray parameter is the depth

  def close(self) -> None:
    """Stops the thread pool."""
    if self._pool is not None:
      self._pool.shutdown()
      self._pool = None


def _kinematics(model: mujoco.MjModel) -> mujoco.MjData:
  """A fresh `MjData` of ``model`` with geom poses computed."""
  data = mujoco.MjData(model)
  mujoco.mj_kinematics(model, data)
  return data


def _finish(depth: np.ndarray, geom: np.ndarray, scene: RenderScene, settings: RenderSettings) -> DepthImage:
  """Labels ray-cast pixels and invalidates those without a surface within [near, far]."""
  valid = (geom >= 0) & (depth >= settings.near) & (depth <= settings.far)
  mask = np.where(valid, scene.geom_labels[np.maximum(geom, 0)], INVALID_LABEL).astype(np.int32)
  return DepthImage(depth=np.where(valid, depth, np.nan).astype(np.float32), mask=mask, backend='raycast')


class DepthRenderer:
  """Renders `RenderScene` s to `DepthImage` s of a fixed size; owns its GL context (or ray-casting threads).

  Reuse one renderer across heaps and cameras: a scene's meshes are uploaded to GL once, when it is first
  rendered after another scene. Not thread-safe; use one renderer per thread. Close it (or use ``with``).

  Attributes:
    width, height: image size, pixels.
    backend: the backend that runs: ``'gl_egl'``, ``'gl_osmesa'`` or ``'raycast'``.
    fallback_reason: why ``backend='auto'`` fell back to ray casting (None otherwise).
  """

  def __init__(self, width: int, height: int, *, backend: str = 'auto', gl_platform: str | None = None,
               settings: RenderSettings = RenderSettings()):
    """Creates the renderer.

    Args:
      width, height: image size, pixels (cameras must have these intrinsics sizes).
      backend: ``'auto'`` (GL if a context can be made, else ray casting), ``'gl'`` or ``'raycast'``.
      gl_platform: ``'egl'`` or ``'osmesa'`` to force a GL platform; None: the first that works.
      settings: depth range and ray-casting threads.

    Raises:
      ValueError: bad size, backend, platform or settings.
      RuntimeError: ``backend='gl'`` and no GL platform works here (the message gives each one's reason).
    """
    for name, value in (('width', width), ('height', height)):
      if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f'DepthRenderer.{name}: expected an int >= 1 (pixels), got {value!r}')
    if backend not in BACKENDS:
      raise ValueError(f'DepthRenderer.backend: expected one of {BACKENDS}, got {backend!r}')
    settings.validate()
    self.width, self.height, self.settings = int(width), int(height), settings
    self.fallback_reason = None
    self._gl, self._raycast = None, None
    if backend in ('auto', 'gl'):
      self._gl, self.fallback_reason = _make_gl(self.width, self.height, gl_platform, required=backend == 'gl')
    if self._gl is None:
      self._raycast = _RaycastBackend(settings.raycast_threads or os.cpu_count() or 1)
    self.backend = f'gl_{self._gl.platform}' if self._gl is not None else 'raycast'

  def render(self, scene: RenderScene, camera: Camera) -> DepthImage:
    """The depth image and slot mask of ``scene`` seen from ``camera`` (see the module doc)."""
    k = camera.intrinsics
    if (k.width, k.height) != (self.width, self.height):
      raise ValueError(f'Camera.intrinsics width x height: expected {self.width} x {self.height} (the '
                       f'renderer\'s), got {k.width} x {k.height}')
    if self._gl is not None:
      view = gl_view(camera, self.settings.near, self.settings.far)
      depth, mask = self._gl.render(scene.model, scene.data, scene.geom_labels, view)
      return DepthImage(depth=depth, mask=mask, backend=self.backend)
    if self._raycast is not None:
      depth, geom = self._raycast.render(scene, camera, self.settings.far)
      return _finish(depth, geom, scene, self.settings)
    raise RuntimeError('DepthRenderer.render: the renderer is closed')

  def close(self) -> None:
    """Frees the GL context or stops the ray-casting threads (idempotent)."""
    for backend in (self._gl, self._raycast):
      if backend is not None:
        backend.close()
    self._gl = self._raycast = None

  def __enter__(self) -> DepthRenderer:
    return self

  def __exit__(self, *exc: Any) -> None:
    self.close()


def _make_gl(width: int, height: int, platform: str | None, required: bool
             ) -> tuple[gl.GLDepthBackend | None, str | None]:
  """(GL backend, None), or (None, reason) when no platform works and ``required`` is False."""
  errors = []
  for p in (platform,) if platform is not None else gl.candidate_platforms():
    if (probe := gl.probe_platform(p)) is not None:
      errors.append(probe)
      continue
    try:
      return gl.GLDepthBackend(p, width, height), None
    except (ImportError, RuntimeError, OSError) as e:
      errors.append(f'{p}: {e}')
  reason = 'no headless GL platform works: ' + ('; '.join(errors) or 'none tried')
  if required:
    raise RuntimeError(f'DepthRenderer(backend=\'gl\'): {reason}')
  return None, reason


def render_depth(scene: RenderScene, camera: Camera, *, backend: str = 'auto',
                 settings: RenderSettings = RenderSettings()) -> DepthImage:
  """One image with a throw-away `DepthRenderer` (convenient; reuse a renderer for many images)."""
  with DepthRenderer(camera.intrinsics.width, camera.intrinsics.height, backend=backend,
                     settings=settings) as renderer:
    return renderer.render(scene, camera)
