"""The Dex-Net 4.0 algorithmic supervisor Omega(x): robust grasp sets per object, mapped into a rendered heap.

Seed ("Data Collection Policy"): the supervisor computes robust wrench-resistance quality (M = 25 draws) for a
set of grasps on each 3-D object model, with gripper-pose noise (2.5 mm parallel jaw, 0.1 mm suction), random
friction and mass, and gravity uniform on the sphere (parallel jaw) or within pi/6 of the approach (suction),
i.e. `parallel_jaw_perturbations` / `suction_perturbations`; in a heap it samples uniformly among the grasps
with quality above 75 % that can be executed there.

1. Per object (object frame, cached on disk): `parallel_jaw_grasp_set` / `suction_grasp_set` sample
   ``num_grasps`` candidates (`sample_antipodal_grasps` / `sample_suction_grasps`) and their robust
   probability; `cached_grasp_sets` does this for a list of objects and stores each object's sets in
   ``<cache_dir>/supervisor-<key>.npz`` keyed by the model's arrays, the seed and every parameter that
   affects the sets.
2. Per rendered image and gripper (`parallel_jaw_supervisor_candidates` / `suction_supervisor_candidates`):
   each set grasp of each occupied heap slot is moved by the slot's pose into the world and the camera frame,
   converted to the image grasp the policy would output, and is eligible when it is valid, robust
   (quality > ``threshold``), expressible as an image grasp (approach condition), inside the image away
   from the border, visible (the rendered segmentation at its centre pixel is its slot) and collision-free
   as executed: `parallel_jaw_collisions` / `suction_collisions` on the 3-D grasp re-derived from the image
   grasp (`parallel_jaw_grasp_3d` / `suction_grasp_3d`).
3. `choose_supervisor_grasp` draws one eligible candidate uniformly.

Parallel-jaw approach: the image grasp's approach is the optical axis, so the jaw axis a (camera frame) must be
nearly perpendicular to it: the approach closest to the optical axis among those perpendicular to a is
normalise(z - a_z a), at tilt arcsin |a_z| from z; candidates need tilt <= ``max_tilt``, and the executed grasp
closes along a flattened into the image plane, (cos angle, sin angle, 0). The set keeps the approach the
antipodal sampler found collision-free on the object alone (its fingers and palm have volume, so the robust
quality's ``jaw_collision`` test depends on the approach); in the heap the executed approach is the optical
axis, and whether the gripper fits there, against the target and every other object and the bin, is the
collision test of step 2 (the same solids: `parallel_jaw_collisions`). Apart from that test, the robust
quality does not depend on the approach in distribution: the jaws close along the axis (`close_jaws`), the
friction cones use the contact normals, and with the default perturbations gravity is uniform on the whole
sphere and the rotation noise is isotropic (off by default). With a gravity cone narrower than pi this no longer
holds; such perturbations are not meaningful for the supervisor.
"""

from __future__ import annotations

import dataclasses
import math
import os
import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from dexjax.geometry.cache import atomic_write_npz, content_key, default_cache_dir
from dexjax.geometry.object_model import ObjectModel
from dexjax.geometry.transforms import normalize, quat_to_matrix
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality import robust
from dexjax.quality.grasp_quality import QualityConfig
from dexjax.quality.heap_reward import HeapScene, RewardParams, parallel_jaw_collisions, suction_collisions
from dexjax.render.camera import Camera
from dexjax.sampling.image_grasps import (ImageParallelJawGrasp, ImageSuctionGrasp, angles_from_approach,
                                          parallel_jaw_grasp_3d, suction_grasp_3d)
from dexjax.sampling.object_samplers import AntipodalSampler, sample_antipodal_grasps, sample_suction_grasps

if TYPE_CHECKING:
  from dexjax.sim.heap import Bin

__all__ = [
    'SUPERVISOR_CACHE_FORMAT', 'SupervisorParams', 'GraspSet', 'parallel_jaw_grasp_set', 'suction_grasp_set',
    'grasp_set_cache_key', 'cached_grasp_sets', 'heap_grasp_sets', 'parallel_jaw_supervisor_candidates',
    'suction_supervisor_candidates', 'choose_supervisor_grasp',
]

SUPERVISOR_CACHE_FORMAT: int = 2
"""Bump when the stored grasp sets or the way they are computed change; old cache entries are then ignored.
2: fingers with volume (collision-checked approaches, ``jaw_collision`` in the robust quality)."""

_MODEL_FIELDS = tuple(f.name for f in dataclasses.fields(ObjectModel))


@struct.dataclass
class SupervisorParams:
  """Settings of the algorithmic supervisor (defaults: Dex-Net 4.0).

  Attributes:
    threshold: a grasp is robust when its probability exceeds this (strictly; 0.75).
    max_tilt: largest angle between a parallel-jaw grasp's best approach (perpendicular to its jaw axis) and the
      camera's optical axis, radians (10 degrees).
    max_approach_angle: largest angle between a suction approach and the optical axis, radians (30 degrees, as
      `SuctionImageSampler`).
    boundary: candidate centre pixels must be at least this far from the image border, pixels (68, as the
      image samplers).
    depth_tolerance: with a rendered depth image, a suction target is visible only when its camera-frame z is
      within this of the rendered depth at its pixel, metres (5 mm).
    num_grasps: static, grasps sampled per object and gripper K (100).
    max_checked: static, grasps per image whose collision test runs when the candidates get a PRNG key (32;
      see `parallel_jaw_supervisor_candidates`).
    num_samples: static, Monte-Carlo draws M of the robust quality (25).
    sampler: settings of the antipodal (parallel-jaw) sampler.
  """

  threshold: float = robust.SUPERVISOR_THRESHOLD
  max_tilt: float = math.radians(10.0)
  max_approach_angle: float = math.radians(30.0)
  boundary: float = 68.0
  depth_tolerance: float = 0.005
  num_grasps: int = struct.field(pytree_node=False, default=100)
  max_checked: int = struct.field(pytree_node=False, default=32)
  num_samples: int = struct.field(pytree_node=False, default=robust.SUPERVISOR_SAMPLES)
  sampler: AntipodalSampler = AntipodalSampler()


@struct.dataclass
class GraspSet:
  """Grasps of one object (object frame) and their robust quality; add leading axes for objects or slots.

  Attributes:
    grasps: `ParallelJawGrasp` or `SuctionGrasp` with leading axis K, object frame, metres.
    quality: (K,) float32 robust probability over M draws (0 where not ``valid``).
    valid: (K,) bool, the sampler's validity mask.
  """

  grasps: ParallelJawGrasp | SuctionGrasp
  quality: jax.Array
  valid: jax.Array


def _supervisor_perturbations(perturbations: robust.Perturbations | None, default,
                              params: SupervisorParams) -> robust.Perturbations:
  base = default() if perturbations is None else perturbations
  return base.replace(num_samples=params.num_samples)


def _quality_keys(key: jax.Array, num_grasps: int) -> jax.Array:
  """(num_grasps,) keys ``fold_in(key, i)``: grasp i's robust-quality key (as `evaluate_grasps`)."""
  return jax.vmap(jax.random.fold_in, in_axes=(None, 0))(key, jnp.arange(num_grasps))


@jax.jit
def _sample_jaw_set(key, model, gripper, params, config):
  """(grasps, valid, quality keys) of `parallel_jaw_grasp_set`."""
  k_sample, k_quality = jax.random.split(key)
  grasps, valid = sample_antipodal_grasps(k_sample, model, params.num_grasps, gripper, params.sampler, config)
  return grasps, valid, _quality_keys(k_quality, params.num_grasps)


@jax.jit
def _sample_suction_set(key, model, gripper, params):
  """(grasps, valid, quality keys) of `suction_grasp_set`."""
  k_sample, k_quality = jax.random.split(key)
  grasps, valid = sample_suction_grasps(k_sample, model, params.num_grasps, gripper)
  return grasps, valid, _quality_keys(k_quality, params.num_grasps)


# One compiled robust quality per gripper, called grasp by grasp (the former single jit mapped it over the grasps
# sequentially anyway): sampler plus quality compile in about the time of that jit or less, give the same results
# bit for bit, and the quality is the same executable as any other ``jax.jit(robust_*_quality)`` called with the
# same argument structure in the process.
_jaw_quality = jax.jit(robust.robust_parallel_jaw_quality)
_suction_quality = jax.jit(robust.robust_suction_quality)


def _robust_set(sampled, model, quality, gripper, perturbations, config) -> GraspSet:
  """The `GraspSet` of sampled (grasps, valid, keys): grasp i's probability is ``quality(keys[i], model, grasp i,
  gripper, perturbations, config)``, 0 where not valid."""
  grasps, valid, keys = sampled
  host = jax.tree.map(np.asarray, grasps)
  prob = [quality(k, model, jax.tree.map(lambda a, i=i: a[i], host), gripper, perturbations, config).probability
          for i, k in enumerate(keys)]
  quality_k = jnp.where(valid, jnp.stack(prob) if prob else jnp.zeros(0), 0.0).astype(jnp.float32)
  return GraspSet(grasps=grasps, quality=quality_k, valid=valid)


def parallel_jaw_grasp_set(key: jax.Array, model: ObjectModel, gripper: ParallelJawGripper = ParallelJawGripper(),
                           params: SupervisorParams = SupervisorParams(),
                           perturbations: robust.Perturbations | None = None,
                           config: QualityConfig = QualityConfig()) -> GraspSet:
  """``params.num_grasps`` antipodal grasps on one object and their robust quality (object frame).

  ``key`` splits into (sampling key, quality key); grasp i's quality is `robust_parallel_jaw_quality` with key
  ``fold_in(quality key, i)`` and ``perturbations`` (default `parallel_jaw_perturbations`) with ``num_samples``
  replaced by ``params.num_samples``. The approach of each grasp is the sampler's collision-free one (see the
  module doc); ``config`` also sets the sampler's collision test.

  Runs eagerly (not under `jax.jit`): a compiled sampler, then the compiled robust quality grasp by grasp.
  """
  pert = _supervisor_perturbations(perturbations, robust.parallel_jaw_perturbations, params)
  return _robust_set(_sample_jaw_set(key, model, gripper, params, config), model, _jaw_quality, gripper, pert,
                     config)


def suction_grasp_set(key: jax.Array, model: ObjectModel, gripper: SuctionGripper = SuctionGripper(),
                      params: SupervisorParams = SupervisorParams(), perturbations: robust.Perturbations | None = None,
                      config: QualityConfig = QualityConfig()) -> GraspSet:
  """``params.num_grasps`` suction grasps on one object and their robust quality (object frame); keys,
  perturbations and evaluation as `parallel_jaw_grasp_set` (default `suction_perturbations`)."""
  pert = _supervisor_perturbations(perturbations, robust.suction_perturbations, params)
  return _robust_set(_sample_suction_set(key, model, gripper, params), model, _suction_quality, gripper, pert, config)


# --- On-disk cache -------------------------------------------------------------------------------------------


def _describe(value: Any) -> Any:
  """A JSON-serialisable description of a (nested) dataclass of parameters, arrays or scalars."""
  if dataclasses.is_dataclass(value):
    fields = {f.name: _describe(getattr(value, f.name)) for f in dataclasses.fields(value)}
    return {'type': type(value).__name__, **fields}
  if value is None or isinstance(value, str):
    return value
  if isinstance(value, (tuple, list)):
    return [_describe(v) for v in value]
  return np.asarray(value).tolist()


def _model_arrays(model: ObjectModel) -> list[np.ndarray]:
  return [np.asarray(getattr(model, f)) for f in _MODEL_FIELDS]


def _object_key(model: ObjectModel, key_seed: int) -> jax.Array:
  """The PRNG key of one object: the seed folded with (28 bits of) a hash of the model's arrays, so an object
  gets the same sets wherever it appears in a list."""
  digest = content_key({'kind': 'object_model'}, *_model_arrays(model))
  return jax.random.fold_in(jax.random.key(key_seed), int(digest[:7], 16))


def grasp_set_cache_key(model: ObjectModel, key_seed: int, jaw_gripper: ParallelJawGripper,
                        suction_gripper: SuctionGripper, params: SupervisorParams,
                        jaw_perturbations: robust.Perturbations, suction_perturbations: robust.Perturbations,
                        config: QualityConfig) -> str:
  """Hex SHA-256 of one object's cache entry: format, seed, the model's arrays and every parameter of the sets
  (the effective perturbations; of ``params`` only ``num_grasps``, ``num_samples`` and ``sampler``, since the
  heap-mapping settings do not change the sets)."""
  header = {
      'format': SUPERVISOR_CACHE_FORMAT, 'kind': 'supervisor_grasp_sets', 'seed': int(key_seed),
      'num_grasps': params.num_grasps, 'num_samples': params.num_samples, 'sampler': _describe(params.sampler),
      'jaw_gripper': _describe(jaw_gripper), 'suction_gripper': _describe(suction_gripper),
      'jaw_perturbations': _describe(jaw_perturbations), 'suction_perturbations': _describe(suction_perturbations),
      'config': _describe(config),
  }
  return content_key(header, *_model_arrays(model))


def _flatten(prefix: str, grasp_set: GraspSet) -> dict[str, np.ndarray]:
  grasps = {f'{prefix}.grasps.{f.name}': np.asarray(getattr(grasp_set.grasps, f.name))
            for f in dataclasses.fields(grasp_set.grasps)}
  return {**grasps, f'{prefix}.quality': np.asarray(grasp_set.quality), f'{prefix}.valid': np.asarray(grasp_set.valid)}


def _unflatten(prefix: str, arrays: dict[str, np.ndarray], grasp_type: type, num_grasps: int) -> GraspSet:
  fields = {f.name: arrays[f'{prefix}.grasps.{f.name}'] for f in dataclasses.fields(grasp_type)}
  out = GraspSet(grasps=grasp_type(**fields), quality=arrays[f'{prefix}.quality'], valid=arrays[f'{prefix}.valid'])
  for leaf in jax.tree.leaves(out):
    if leaf.shape[:1] != (num_grasps,):
      raise ValueError(f'{prefix}: leading axis {leaf.shape[:1]}, expected ({num_grasps},)')
  return out


def _read_entry(path: str, key: str, num_grasps: int) -> tuple[GraspSet, GraspSet]:
  with np.load(path, allow_pickle=False) as data:
    arrays = {name: np.array(data[name]) for name in data.files}
  if str(arrays.get('cache_key')) != key:
    raise ValueError('stored key does not match the file name')
  return (_unflatten('jaw', arrays, ParallelJawGrasp, num_grasps),
          _unflatten('suction', arrays, SuctionGrasp, num_grasps))


def _object_sets(model, key_seed, jaw_gripper, suction_gripper, params, jaw_pert, suction_pert, config,
                 directory) -> tuple[GraspSet, GraspSet]:
  """One object's (parallel-jaw, suction) sets as NumPy arrays, from the cache when possible."""
  key = grasp_set_cache_key(model, key_seed, jaw_gripper, suction_gripper, params, jaw_pert, suction_pert, config)
  path = os.path.join(directory, f'supervisor-{key}.npz')
  if os.path.exists(path):
    try:
      return _read_entry(path, key, params.num_grasps)
    except Exception as e:  # Any unreadable entry is recomputed and replaced.
      warnings.warn(f"dexjax supervisor cache: '{path}' is unreadable ({type(e).__name__}: {e}); recomputing",
                    RuntimeWarning, stacklevel=3)
  k_jaw, k_suction = jax.random.split(_object_key(model, key_seed))
  jaw = jax.tree.map(np.asarray, parallel_jaw_grasp_set(k_jaw, model, jaw_gripper, params, jaw_pert, config))
  suction = jax.tree.map(np.asarray, suction_grasp_set(k_suction, model, suction_gripper, params, suction_pert, config))
  try:
    atomic_write_npz(path, {'cache_key': np.array(key), **_flatten('jaw', jaw), **_flatten('suction', suction)})
  except OSError as e:
    warnings.warn(f"dexjax supervisor cache: could not write '{path}' ({e}); continuing without caching",
                  RuntimeWarning, stacklevel=3)
  return jaw, suction


def cached_grasp_sets(models: Sequence[ObjectModel], key_seed: int,
                      jaw_gripper: ParallelJawGripper = ParallelJawGripper(),
                      suction_gripper: SuctionGripper = SuctionGripper(),
                      params: SupervisorParams = SupervisorParams(),
                      jaw_perturbations: robust.Perturbations | None = None,
                      suction_perturbations: robust.Perturbations | None = None,
                      config: QualityConfig = QualityConfig(),
                      cache_dir: str | os.PathLike[str] | None = None) -> tuple[GraspSet, GraspSet]:
  """The supervisor's (parallel-jaw, suction) grasp sets of N objects, each loaded from or written to disk.

  Object n's sets are `parallel_jaw_grasp_set` / `suction_grasp_set` with the two halves of
  ``fold_in(key(key_seed), h)``, h = 28 bits of a hash of the model's arrays (independent of the list order).
  They are stored atomically in ``<cache_dir>/supervisor-<grasp_set_cache_key>.npz``, so a rerun or another
  process loads them; loaded and computed sets are bit-identical.

  Args:
    models: N object models (the set functions compile once per grid size and sample count).
    key_seed: integer seed.
    jaw_gripper, suction_gripper: gripper parameters.
    params: supervisor settings (``num_grasps``, ``num_samples``, ``sampler`` matter here).
    jaw_perturbations, suction_perturbations: robust-quality noise (defaults: the supervisor's).
    config: wrench-resistance settings.
    cache_dir: cache directory; ``default_cache_dir()/supervisor`` when None.

  Returns:
    (parallel-jaw `GraspSet`, suction `GraspSet`) with leading axes (N, K), jax arrays.
  """
  jaw_pert = _supervisor_perturbations(jaw_perturbations, robust.parallel_jaw_perturbations, params)
  suction_pert = _supervisor_perturbations(suction_perturbations, robust.suction_perturbations, params)
  directory = os.fspath(cache_dir) if cache_dir is not None else os.path.join(default_cache_dir(), 'supervisor')
  sets = [_object_sets(m, key_seed, jaw_gripper, suction_gripper, params, jaw_pert, suction_pert, config, directory)
          for m in models]
  stack = lambda *xs: jnp.asarray(np.stack(xs))
  return jax.tree.map(stack, *[s[0] for s in sets]), jax.tree.map(stack, *[s[1] for s in sets])


def heap_grasp_sets(sets: GraspSet, object_ids: jax.Array) -> GraspSet:
  """The sets (P, K) of a heap's slots from the objects' sets (N, K) and the slots' object ids (P,) int32."""
  ids = jnp.clip(object_ids, 0, sets.valid.shape[0] - 1)
  return jax.tree.map(lambda a: a[ids], sets)


# --- Mapping into a rendered heap ----------------------------------------------------------------------------


def _to_camera(pose: jax.Array, camera: Camera, point: jax.Array, direction: jax.Array):
  """Object-frame point (3,) and direction (3,) of the object at ``pose`` (7,) in the camera frame."""
  rot = camera.rotation.T @ quat_to_matrix(pose[3:], xp=jnp)
  return rot @ point + camera.rotation.T @ (pose[:3] - camera.position), normalize(rot @ direction)


def _pixel(camera: Camera, point: jax.Array) -> jax.Array:
  """(2,) pixel (u, v) of a camera-frame point (3,); finite (arbitrary) for points at or behind the camera."""
  k = camera.intrinsics
  z = jnp.where(point[2] > 0, point[2], 1.0)
  return jnp.stack([k.fx * point[0] / z + k.cx, k.fy * point[1] / z + k.cy])


def _visible(uv, z, slot, mask, depth, params: SupervisorParams) -> jax.Array:
  """() bool: in front of the camera, the nearest pixel at least ``boundary`` from the border (gqcnn's
  comparison) and showing ``slot`` in ``mask`` (and, with a depth image, at the rendered depth)."""
  h, w = mask.shape
  b = params.boundary
  pix = jnp.floor(jnp.clip(uv, -1.0, jnp.array([w, h], jnp.float32)) + 0.5).astype(jnp.int32)
  col, row = pix[0], pix[1]
  inside = (z > 0) & (row >= b) & (col >= b) & (row <= h - b) & (col <= w - b)
  row, col = jnp.clip(row, 0, h - 1), jnp.clip(col, 0, w - 1)
  seen = mask[row, col] == slot
  if depth is not None:
    seen &= jnp.abs(depth[row, col] - z) <= params.depth_tolerance
  return inside & seen


def _jaw_candidate(grasp, quality, valid, slot, scene, camera, mask, params):
  """Image grasp of one set grasp and whether it passes every test but the collision test."""
  center, axis = _to_camera(scene.poses[slot], camera, grasp.center, grasp.axis)
  tilt = jnp.arcsin(jnp.clip(jnp.abs(axis[2]), 0.0, 1.0))
  uv = _pixel(camera, center)
  image = ImageParallelJawGrasp(center=uv, angle=jnp.arctan2(axis[1], axis[0]), depth=center[2], width=grasp.width)
  ok = valid & (quality > params.threshold) & scene.mask[slot] & (tilt <= params.max_tilt)
  return image, ok & _visible(uv, center[2], slot, mask, None, params)


def _suction_candidate(grasp, quality, valid, slot, scene, camera, mask, depth, params):
  """Image grasp of one set grasp and whether it passes every test but the collision test."""
  center, approach = _to_camera(scene.poses[slot], camera, grasp.center, grasp.approach)
  angle, approach_angle = angles_from_approach(approach)
  uv = _pixel(camera, center)
  image = ImageSuctionGrasp(center=uv, angle=angle, depth=center[2], approach_angle=approach_angle)
  ok = valid & (quality > params.threshold) & scene.mask[slot] & (approach_angle <= params.max_approach_angle)
  return image, ok & _visible(uv, center[2], slot, mask, depth, params)


def _over_slots(candidate, sets_pk: GraspSet, *args):
  """Applies ``candidate(grasp, quality, valid, slot, *args)`` to every (slot, grasp); outputs flattened to P*K."""
  per_slot = jax.vmap(candidate, in_axes=(0, 0, 0, None) + (None,) * len(args))
  slots = jnp.arange(sets_pk.valid.shape[0], dtype=jnp.int32)
  out = jax.vmap(per_slot, in_axes=(0, 0, 0, 0) + (None,) * len(args))(
      sets_pk.grasps, sets_pk.quality, sets_pk.valid, slots, *args)
  return jax.tree.map(lambda a: a.reshape((-1,) + a.shape[2:]), out)


def _collision_free(images, passed: jax.Array, collides, key: jax.Array | None, max_checked: int,
                    scores: jax.Array | None = None) -> jax.Array:
  """(C,) bool: ``passed`` and collision-free. With a ``key``, only ``max_checked`` of the passed grasps, drawn
  uniformly without replacement (Gumbel top-k), are tested (the others come out False): picking uniformly among
  the collision-free ones of a uniform subset picks uniformly among all collision-free grasps. With ``scores``
  (C,) instead, the ``max_checked`` passed grasps of highest score are tested (best first)."""
  if scores is None and (key is None or max_checked >= passed.shape[0]):
    return passed & ~jax.vmap(collides)(images)
  rank = jax.random.gumbel(key, passed.shape) if scores is None else scores
  top, idx = jax.lax.top_k(jnp.where(passed, rank, -jnp.inf), min(max_checked, passed.shape[0]))
  free = jnp.isfinite(top) & ~jax.vmap(collides)(jax.tree.map(lambda a: a[idx], images))
  return jnp.zeros_like(passed).at[idx].set(free)


def parallel_jaw_supervisor_candidates(
    sets_pk: GraspSet, scene: HeapScene, bin_: Bin, camera: Camera, mask: jax.Array,
    params: SupervisorParams = SupervisorParams(), gripper: ParallelJawGripper = ParallelJawGripper(),
    reward_params: RewardParams = RewardParams(), key: jax.Array | None = None, best_first: bool = False
) -> tuple[ImageParallelJawGrasp, jax.Array]:
  """The parallel-jaw set grasps of one heap as image grasps of one camera, and which the supervisor may pick.

  Candidate (p, k) at index p K + k: set grasp k of slot p moved by ``scene.poses[p]`` into the camera frame;
  image centre = its projected centre (u, v) (continuous), depth = its camera-frame z, angle = atan2(a_y, a_x)
  of its camera-frame jaw axis a, width unchanged. Eligible when valid, quality > ``threshold``, slot occupied,
  tilt arcsin |a_z| <= ``max_tilt``, the nearest pixel >= ``boundary`` from the border and ``mask`` shows slot
  p there, and `parallel_jaw_collisions` of the executed grasp (`parallel_jaw_grasp_3d` of the image grasp:
  approach = optical axis, axis flattened into the image plane) finds no object or bin collision.

  Args:
    sets_pk: `GraspSet` (P, K) aligned with the heap's slots (`heap_grasp_sets`).
    scene: the heap (P slots).
    bin_: the bin (static under `jax.jit`).
    camera: the camera of the image.
    mask: (H, W) int32 rendered segmentation: slot index, -1 bin or table, -2 invalid.
    params: supervisor settings.
    gripper: the parallel-jaw gripper (its finger and palm sizes are the collision solids).
    reward_params: the heap reward's settings; ``reward_params.quality`` gives the collision tolerance and
      sampling, shared with the heap reward.
    key: with a PRNG key, the collision test runs on ``params.max_checked`` grasps drawn uniformly among
      those passing the other tests (the rest are not eligible); None tests all P K.
    best_first: instead, the collision test runs on the ``params.max_checked`` grasps of highest quality passing
      the other tests (static; the supervisor as a policy, `dexjax.bench.SupervisorPolicy`).

  Returns:
    (`ImageParallelJawGrasp` with leading axis P K, eligible (P K,) bool).
  """
  images, passed = _over_slots(_jaw_candidate, sets_pk, scene, camera, mask, params)
  collides = lambda g: jnp.any(jnp.stack(parallel_jaw_collisions(parallel_jaw_grasp_3d(camera, g), scene, bin_,
                                                                 gripper, reward_params)))
  scores = sets_pk.quality.reshape(-1) if best_first else None
  return images, _collision_free(images, passed, collides, key, params.max_checked, scores)


def suction_supervisor_candidates(
    sets_pk: GraspSet, scene: HeapScene, bin_: Bin, camera: Camera, mask: jax.Array,
    params: SupervisorParams = SupervisorParams(), gripper: SuctionGripper = SuctionGripper(),
    reward_params: RewardParams = RewardParams(), depth: jax.Array | None = None,
    key: jax.Array | None = None, best_first: bool = False) -> tuple[ImageSuctionGrasp, jax.Array]:
  """The suction set grasps of one heap as image grasps of one camera, and which the supervisor may pick.

  As `parallel_jaw_supervisor_candidates`, with angle and approach angle from the camera-frame approach
  (`angles_from_approach`), the condition approach angle <= ``max_approach_angle`` instead of the tilt, and
  `suction_collisions` of `suction_grasp_3d` of the image grasp. Visibility: the mask at the centre pixel must
  show the grasp's slot, which rules out targets hidden by other objects; a target hidden by another part of
  its own object passes this test, so pass the rendered ``depth`` (H, W) metres to also require the target's
  camera-frame z within ``params.depth_tolerance`` of the rendered depth there. ``key``, ``best_first``: as there.
  """
  images, passed = _over_slots(_suction_candidate, sets_pk, scene, camera, mask, depth, params)
  collides = lambda g: jnp.any(jnp.stack(suction_collisions(suction_grasp_3d(camera, g), scene, bin_, gripper,
                                                            reward_params)))
  scores = sets_pk.quality.reshape(-1) if best_first else None
  return images, _collision_free(images, passed, collides, key, params.max_checked, scores)


def choose_supervisor_grasp(key: jax.Array, eligible: jax.Array) -> tuple[jax.Array, jax.Array]:
  """Index () int32 drawn uniformly among the True entries of ``eligible`` (C,) bool (Gumbel-max), and ok ()
  bool, False (index 0) when none is eligible."""
  scores = jnp.where(eligible, jax.random.gumbel(key, eligible.shape), -jnp.inf)
  ok = jnp.any(eligible)
  return jnp.where(ok, jnp.argmax(scores), 0).astype(jnp.int32), ok
