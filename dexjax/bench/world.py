"""The simulated bin of a benchmark trial: fill it, look at it, take an object out, let the rest settle.

`PickingWorld` holds what a process needs for trials of one object set (built like a generation run's objects,
from a `dexjax.generate.GenerateConfig`: the same object sources, bin, settling physics, camera distribution,
sensor noise, grippers and reward): the prepared objects, their collision bodies and quality models, and a
depth renderer. A trial's state is a `BinState` (plain NumPy arrays, P padded slots): which objects are in the
bin, where, and their friction. Every step is a function of the state and a key, so a trial restarted from a
logged state continues exactly as it would have.

* `PickingWorld.fill`: the seed's protocol, "the bin is filled with a random configuration of objects": the
  trial's objects (all of the set, or a random subset) are dropped from the heap distribution's drop area,
  intersecting drops raised (`dexjax.sim.drop_poses`), and settled; objects that leave the bin are taken out.
* `PickingWorld.observe`: the depth image (and true segmentation) from a camera, with the run's sensor noise;
  `PickingWorld.empty_bin` the background image of that camera.
* `PickingWorld.remove`: the object lifted out, the rest settled again from where they lay
  (`dexjax.sim.settle` with ``start_poses``); `PickingWorld.settle_again` for a heap disturbed in place.
"""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from dexjax.generate.cameras import image_size
from dexjax.generate.config import GenerateConfig
from dexjax.generate.labels import LabelParams
from dexjax.generate.pipeline import label_params, usable_objects
from dexjax.quality.heap_reward import HeapScene, heap_scene
from dexjax.render.camera import Camera
from dexjax.render.noise import noisy_depth
from dexjax.render.rendering import DepthRenderer, build_render_scene, empty_bin_scene
from dexjax.objects.collision import HullSettings, cached_collision_hulls
from dexjax.sim.bodies import heap_objects
from dexjax.sim.heap import HeapState, sample_heap_state
from dexjax.sim.contact_loads import resting_loads
from dexjax.sim.settling import settle

_PROCEDURAL_LEVEL = re.compile(r'procedural:L([123])/')

BENCHMARK_HULLS = HullSettings(max_hulls=64, resolution=400_000)
"""The decomposition the physics judge's gripper meets: up to 64 convex pieces per concave object at 400,000
voxels (the datasets' 8 at 100,000 fill a bowl's cavity: their union over-covers a procedural bowl by 58-63 % of
its volume, a hollow level-3 part by up to 118 %; 64 pieces: 11-14 % and 8-36 %; docs/benchmark.md). The gripper
then meets the cavities the images and the labels see; objects keep the datasets' 8 pieces for each other (64 for
all of 25 objects made a judged attempt 60 s instead of 2 s); convex objects keep their own hull either way."""


def object_level(name: str) -> int | None:
  """The seed's difficulty level of an object named by its source: 1-3 for ``procedural:L<k>/...``, else None."""
  match = _PROCEDURAL_LEVEL.match(name)
  return int(match.group(1)) if match else None


@dataclasses.dataclass(frozen=True)
class BinState:
  """The objects in the bin (P padded slots, NumPy).

  Attributes:
    object_ids: (P,) int32 index into `PickingWorld.names` (-1 in empty slots).
    mask: (P,) bool, the slot's object is in the bin.
    poses: (P, 7) float64 object-frame poses in the world (xyz metres, quaternion wxyz).
    friction: (P,) float32 Coulomb friction of each object (drawn once, when the bin is filled).
  """

  object_ids: np.ndarray
  mask: np.ndarray
  poses: np.ndarray
  friction: np.ndarray

  @property
  def count(self) -> int:
    """Objects left in the bin."""
    return int(self.mask.sum())

  def to_json(self) -> dict[str, Any]:
    """Plain lists (exact: float64 poses survive a JSON round trip as Python floats)."""
    return {'object_ids': self.object_ids.tolist(), 'mask': self.mask.tolist(), 'poses': self.poses.tolist(),
            'friction': self.friction.astype(np.float64).tolist()}

  @classmethod
  def from_json(cls, data: dict[str, Any]) -> BinState:
    return cls(object_ids=np.asarray(data['object_ids'], np.int32), mask=np.asarray(data['mask'], bool),
               poses=np.asarray(data['poses'], np.float64), friction=np.asarray(data['friction'], np.float32))


class PickingWorld:
  """The objects, physics and renderer of a benchmark's trials (one per process; close it, or use ``with``).

  Attributes:
    config: the `GenerateConfig` the world is built from (objects, bin, settle, camera, noise, grippers).
    names: the N usable objects' names; `BinState.object_ids` index into this list.
    levels: the N objects' difficulty levels (1-3 for procedural objects of that level, else None).
    rejected: object sources or files that could not be used, with reasons.
    cache_dir: the object cache the world was built from (None: the default), also the supervisor's grasp sets'.
    grip_hulls: per object, the finer convex decomposition the physics judge's gripper meets near the grasp
      (the ``grip_decomposition``, `BENCHMARK_HULLS` by default); the bodies keep the datasets' decomposition for
      settling and for each other.
    params: the analytic reward's `LabelParams` (grippers, perturbations, reward settings, bin).
  """

  def __init__(self, config: GenerateConfig, *, cache_dir: str | os.PathLike[str] | None = None,
               grip_decomposition: HullSettings = BENCHMARK_HULLS):
    self.config, self.cache_dir = config, cache_dir
    prepared, self.rejected = usable_objects(config, cache_dir)
    self.names = [p.name for p in prepared]
    self.levels = [object_level(name) for name in self.names]
    self.meshes = [p.mesh for p in prepared]
    self.models = [p.model for p in prepared]
    self.bodies = heap_objects(prepared)
    self.grip_hulls = [cached_collision_hulls(p.mesh, cache_dir=cache_dir, **grip_decomposition.kwargs())
                       for p in prepared]
    self.params: LabelParams = label_params(config)
    width, height = image_size(config)
    self.renderer = DepthRenderer(width, height, backend=config.dataset.render_backend, settings=config.render)
    self._scenes: tuple[Any, dict[Any, HeapScene], Any] = (None, {}, None)  # (state id, scenes, the state)

  def close(self) -> None:
    self.renderer.close()

  def __enter__(self) -> PickingWorld:
    return self

  def __exit__(self, *exc: Any) -> None:
    self.close()

  def heap_state(self, state: BinState) -> HeapState:
    """The `HeapState` of a bin (slots, ids, mask, friction; float32 poses) for `dexjax.sim` functions."""
    ids = np.where(state.mask, state.object_ids, 0).astype(np.int32)
    return HeapState(object_ids=ids, mask=state.mask.copy(), positions=state.poses[:, :3].astype(np.float32),
                     quaternions=state.poses[:, 3:].astype(np.float32), friction=state.friction.copy())

  def fill(self, key: jax.Array, count: int, object_ids: Sequence[int] | None = None) -> BinState:
    """A bin of ``count`` distinct objects drawn from the N usable ones (all of them when ``count == N``), or of
    the given ``object_ids`` (``count`` of them, indices into `names`), dropped and settled; objects that left the
    bin are out of the returned state.

    Raises:
      ValueError: ``count`` is not in [1, N], or ``object_ids`` are not ``count`` distinct indices in [0, N).
    """
    n = len(self.names)
    if not 1 <= count <= n:
      raise ValueError(f'per-trial object count: expected an integer in [1, {n}] (the usable objects), got {count}')
    dist = self.config.heap.replace(count_mean=float(count), min_count=count, max_count=count)
    heap = jax.device_get(sample_heap_state(key, n, dist))
    if object_ids is not None:
      ids = [int(i) for i in object_ids]
      if len(ids) != count or len(set(ids)) != count or not all(0 <= i < n for i in ids):
        raise ValueError(f'object_ids: expected {count} distinct object indices in [0, {n}), got {ids}')
      heap = heap.replace(object_ids=np.asarray(ids, np.int32))
    result = settle(self.bodies, heap, backend='rollout', settings=self.config.settle)
    mask = result.mask[0] & ~result.left_bin[0]
    return BinState(object_ids=np.where(mask, heap.object_ids, -1).astype(np.int32), mask=mask,
                    poses=result.poses[0].astype(np.float64), friction=np.asarray(heap.friction, np.float32))

  def settle_again(self, state: BinState) -> BinState:
    """The state after the bin's objects settle from their current poses (objects leaving the bin are out)."""
    if not state.count:
      return state
    result = settle(self.bodies, self.heap_state(state), backend='rollout', settings=self.config.settle,
                    start_poses=state.poses)
    mask = state.mask & ~result.left_bin[0]
    poses = np.where(state.mask[:, None], result.poses[0], state.poses)
    return BinState(object_ids=np.where(mask, state.object_ids, -1).astype(np.int32), mask=mask, poses=poses,
                    friction=state.friction)

  def remove(self, state: BinState, slot: int) -> BinState:
    """The state after the object in ``slot`` is lifted out and the others settle again."""
    if not state.mask[slot]:
      raise ValueError(f'remove: slot {slot} holds no object (objects in slots {np.flatnonzero(state.mask).tolist()})')
    mask = state.mask.copy()
    mask[slot] = False
    ids = state.object_ids.copy()
    ids[slot] = -1
    return self.settle_again(dataclasses.replace(state, mask=mask, object_ids=ids))

  def scene(self, state: BinState, known_mass: bool = False, loads: bool = False) -> HeapScene:
    """The analytic reward's view of the bin: the objects' models in slot order, poses, friction and masses (the
    labels' law: each object's mass drawn about its simulated mass; with ``known_mass``, the simulated mass as it
    is; with ``loads``, the load each object carries from its neighbours at rest,
    `dexjax.sim.contact_loads.resting_loads`). The last state's scenes are kept, so the judges and the supervisor
    of one attempt share one copy of the stacked distance grids and measure the loads once."""
    if self._scenes[0] != id(state):
      self._scenes = (id(state), {}, state)  # the state is kept so that its id is not reused while cached
    scenes = self._scenes[1]
    if (known_mass, loads) not in scenes:
      base = scenes.get((False, False))
      if base is None:
        base = scenes[(False, False)] = heap_scene(self.models, state.object_ids, state.mask, state.poses,
                                                   state.friction, mass=self.masses(state))
      carried = jnp.asarray(self.loads(state)) if loads else None
      scenes[(known_mass, loads)] = base.replace(loads=carried, mass_known=known_mass)
    return scenes[(known_mass, loads)]

  def masses(self, state: BinState) -> np.ndarray:
    """(P,) float32 each slot's simulated mass, kg (1 in empty slots)."""
    return np.array([self.bodies[i].mass if i >= 0 else 1.0 for i in state.object_ids.tolist()], np.float32)

  def loads(self, state: BinState) -> np.ndarray:
    """(P, 6) float32 the load on each slot's object from its neighbours at rest (force N, torque N m about its
    centre of mass; world frame; `dexjax.sim.contact_loads.resting_loads`), zero in empty slots."""
    if not state.count:
      return np.zeros((state.mask.shape[0], 6), np.float32)
    return resting_loads(self.bodies, self.heap_state(state), state.poses, self.config.settle)

  def observe(self, key: jax.Array, state: BinState, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(depth (H, W) float32 metres with the run's sensor noise, NaN where invalid; the true segmentation
    (H, W) int32: the heap slot of each object pixel, `dexjax.render.BIN_LABEL` for the bin,
    `dexjax.render.INVALID_LABEL` where nothing was seen)."""
    scene = build_render_scene(self.meshes, np.where(state.mask, state.object_ids, -1), state.poses, state.mask,
                               bin=self.config.bin)
    rendered = self.renderer.render(scene, camera)
    depth = noisy_depth(key, rendered.depth, self.config.noise)
    return np.asarray(depth, np.float32), np.asarray(rendered.mask, np.int32)

  def empty_bin(self, camera: Camera) -> np.ndarray:
    """(H, W) float32 depth of the empty bin from ``camera`` (noise-free): the background image a bin-picking
    cell records once, for segmenting objects by background subtraction."""
    return np.asarray(self.renderer.render(empty_bin_scene(bin=self.config.bin), camera).depth, np.float32)


__all__ = ['BinState', 'PickingWorld', 'object_level']
