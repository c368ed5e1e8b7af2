"""One shard of a generation run: settle heaps, render them, label actions with tau and S, and write the shard.

`ShardGenerator` holds what every shard of a run shares (objects and their models, the supervisor's grasp sets,
a depth renderer, the jitted labeller); `ShardGenerator.generate` makes the content of shard i, a function of
(config, seed, i) only:

* randomness comes from ``jax.random.key(shard_seed(seed, i))``, split into heap, camera, noise and label
  keys; image j of the shard folds j into each;
* heaps: ``ceil(images_per_shard / images_per_heap)`` heaps drawn from the heap distribution and settled
  together with the MuJoCo C engine; heap h has the dataset-wide id ``i * heaps_per_shard + h``;
* a heap whose simulation diverged is dropped (its images are not made; counted in the stats); objects
  that left the bin are removed from the heap before rendering and labelling;
* image j: camera, render (depth and slot mask), optional sensor noise on the depth the policy sees (its
  holes inpainted as a policy's observation, ``dataset.inpaint_holes``: `policy_depth`); collecting on-policy
  (``collection.policy``), the learned policy plans on that depth with the objects' rendered pixels that returned
  as its mask (a perfect segmentation) and its scored grasps become the candidates (`dexjax.generate.on_policy`,
  its key from a stream of its own); then `label_image` on
  the heap's `HeapScene` (settled poses, the state's per-object friction and each object's simulated mass, which
  the image also stores as ``object_friction`` and ``object_mass``; the labels draw each object's mass about its
  own, labels version 8); rows that exist (``ok``) are kept, in order.

`generate_shard` is the picklable task a worker process (or Ray worker) runs: it keeps one `ShardGenerator` per
process and config, and writes the shard with `dexjax.data.finish_shard`.
"""

from __future__ import annotations

import atexit
import math
import os
import time
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from dexjax.compile_cache import persistent_compilation_cache
from dexjax.data.manifest import finish_shard
from dexjax.data.shards import shard_seed
from dexjax.generate import supervisor as sup
from dexjax.generate.cameras import image_size, run_camera
from dexjax.generate.config import GenerateConfig, fingerprint
from dexjax.generate.labels import ImageRows, LabelParams, label_image
from dexjax.generate.on_policy import collection_models, collection_policy, plan_candidates
from dexjax.objects.folder import Rejection
from dexjax.objects.sets import NoObjectsError, usable_objects  # re-exported: callers import them from here too
from dexjax.quality.heap_reward import HeapScene, heap_scene, scene_slot_ids
from dexjax.policy.observation import observation
from dexjax.render.noise import noisy_depth
from dexjax.render.rendering import DepthRenderer, build_render_scene
from dexjax.sim.bodies import heap_objects
from dexjax.sim.heap import sample_heap_states
from dexjax.sim.settling import settle

_label = jax.jit(label_image)
_plan = jax.jit(plan_candidates)
_STAGES = ('settle', 'render', 'label', 'write')
_POLICY_STREAM = 0x9011C7  # folded into a shard's key: the on-policy plans' stream, apart from the four others


def policy_depth(depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
  """(the depth a policy plans on, the pixels the sensor returned) of a sensor image (H, W) float32 metres:
  holes (NaN, inf, <= 0; `dexjax.render.noise.dropout`) inpainted as `dexjax.policy.prepare_observation` does,
  (H, W) bool returns; an image without holes comes back as it is (every pixel returned)."""
  from dexjax.policy.preprocess import inpaint_depth  # pylint: disable=g-import-not-at-top  (loads the policies)
  depth = np.asarray(depth, np.float32)
  observed = np.isfinite(depth) & (depth > 0)
  if observed.all():
    return depth, observed
  return np.asarray(inpaint_depth(depth), np.float32), observed


def label_params(config: GenerateConfig) -> LabelParams:
  """The `LabelParams` of a run's config."""
  g = config.grippers
  m = config.reward.num_samples
  return LabelParams(parallel_jaw_sampler=config.parallel_jaw_sampler, suction_sampler=config.suction_sampler,
                     parallel_jaw=g.parallel_jaw, suction=g.suction,
                     parallel_jaw_perturbations=g.parallel_jaw_perturbations.replace(num_samples=m),
                     suction_perturbations=g.suction_perturbations.replace(num_samples=m), reward=config.reward,
                     supervisor=config.supervisor, policy=config.policy, bin=config.bin)


def supervisor_sets(config: GenerateConfig, models: Sequence[Any], cache_dir: str | os.PathLike[str] | None = None
                    ) -> tuple[sup.GraspSet, sup.GraspSet]:
  """The supervisor's (parallel-jaw, suction) grasp sets of the run's object models, (N, K), cached on disk in
  ``cache_dir/supervisor`` (default: the supervisor's default cache)."""
  g = config.grippers
  return sup.cached_grasp_sets(models, config.seed, jaw_gripper=g.parallel_jaw, suction_gripper=g.suction,
                               params=config.supervisor, jaw_perturbations=g.parallel_jaw_perturbations,
                               suction_perturbations=g.suction_perturbations, config=g.config,
                               cache_dir=os.path.join(cache_dir, 'supervisor') if cache_dir is not None else None)


def stage_names(config: GenerateConfig) -> tuple[str, ...]:
  """The stages a run's shards time (``stats['seconds']``): settle, render, label, write, and the learned policy's
  plans when it collects on-policy."""
  return _STAGES + (('plan',) if config.collection.policy != 'tau' else ())


def _empty_stats(config: GenerateConfig) -> dict[str, Any]:
  return {'heaps': 0, 'diverged_heaps': 0, 'objects_left_bin': 0, 'images': 0,
          'seconds': {stage: 0.0 for stage in stage_names(config)}}


def _shard_keys(seed: int, index: int) -> jax.Array:
  """Shard ``index``'s four keys: heaps, cameras, sensor noise, labels (image j folds j into each)."""
  return jax.random.split(jax.random.key(shard_seed(seed, index)), 4)


def _policy_key(seed: int, index: int, image_index: int) -> jax.Array:
  """The key of the learned policy's plan on image ``image_index`` of shard ``index`` (on-policy collection)."""
  stream = jax.random.fold_in(jax.random.key(shard_seed(seed, index)), _POLICY_STREAM)
  return jax.random.fold_in(stream, image_index)


def image_label_key(seed: int, shard_index: int, image_index: int) -> jax.Array:
  """The key `label_image` got for image ``image_index`` of shard ``shard_index`` of a run with ``seed``."""
  return jax.random.fold_in(_shard_keys(seed, shard_index)[3], image_index)


class ShardGenerator:
  """Makes shards of one run (see the module docstring); one per process. Close it (or use ``with``).

  Attributes:
    config: the run's `GenerateConfig`.
    names: the N object names; image ``object_ids`` index into this list.
    rejected: object sources or files that could not be used, with reasons.
    masses: (N,) float32 each object's simulated mass, kg (`dexjax.sim.heap_object`: what the physics lifts and
      the labels' mass law centres on).
  """

  def __init__(self, config: GenerateConfig, *, cache_dir: str | os.PathLike[str] | None = None,
               progress: bool = False):
    self.config = config
    prepared, rejected = usable_objects(config, cache_dir, progress)
    self.rejected: list[Rejection] = rejected
    self.names = [p.name for p in prepared]
    self.meshes = [p.mesh for p in prepared]
    self.models = [p.model for p in prepared]
    self.heap_objects = heap_objects(prepared)
    self.masses = np.array([o.mass for o in self.heap_objects], np.float32)
    self.params = label_params(config)
    self.grasp_sets = supervisor_sets(config, self.models, cache_dir)
    width, height = image_size(config)
    self.renderer = DepthRenderer(width, height, backend=config.dataset.render_backend, settings=config.render)
    self.fingerprint = fingerprint(config)
    self.shards_made = 0
    self.collector = None  # the learned policy of on-policy collection, loaded as the config recorded it
    if config.collection.policy == 'on_policy':
      c = config.collection
      models, _ = collection_models(c.model, c.model_digest)
      self.collector = collection_policy(models, c.cem)

  def close(self) -> None:
    self.renderer.close()

  def __enter__(self) -> ShardGenerator:
    return self

  def __exit__(self, *exc: Any) -> None:
    self.close()

  @property
  def heaps_per_shard(self) -> int:
    d = self.config.dataset
    return math.ceil(d.images_per_shard / d.images_per_heap)

  def _heap_scene(self, ids: np.ndarray, mask: np.ndarray, poses: np.ndarray, friction: np.ndarray,
                  mass: np.ndarray) -> tuple[HeapScene, Any, Any]:
    """The reward's scene of one heap (its P models stacked in slot order, the state's friction and the objects'
    masses per slot, `_slot_masses`) and its slots' grasp sets."""
    scene = heap_scene(self.models, ids, mask, poses, friction, mass=mass)
    slot_ids = scene_slot_ids(ids, mask)
    pj, su = (jax.tree.map(lambda a: jnp.asarray(np.asarray(a)[slot_ids]), s) for s in self.grasp_sets)
    return scene, pj, su

  def _slot_masses(self, ids: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(P,) float32 each slot's object's mass, kg (0 in empty slots)."""
    return np.where(mask, self.masses[np.maximum(ids, 0)], 0.0).astype(np.float32)

  def generate(self, index: int) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, Any]]:
    """The images, rows and stats of shard ``index`` (stats: counts and per-stage seconds; not stored)."""
    config, stats = self.config, _empty_stats(self.config)
    k_heap, k_camera, k_noise, k_label = _shard_keys(config.seed, index)
    clock = time.perf_counter()
    states = sample_heap_states(k_heap, self.heaps_per_shard, len(self.heap_objects), config.heap)
    result = settle(self.heap_objects, states, backend='rollout', settings=config.settle)
    stats['seconds']['settle'] += time.perf_counter() - clock
    images: list[dict[str, np.ndarray]] = []
    rows: list[dict[str, np.ndarray]] = []
    all_ids, all_friction = np.asarray(states.object_ids), np.asarray(states.friction, np.float32)
    for h in range(self.heaps_per_shard):
      stats['heaps'] += 1
      if result.diverged[h]:
        stats['diverged_heaps'] += 1
        continue
      mask = result.mask[h] & ~result.left_bin[h]
      stats['objects_left_bin'] += int((result.mask[h] & result.left_bin[h]).sum())
      ids, poses = np.where(mask, all_ids[h], -1).astype(np.int32), result.poses[h]
      friction = np.where(mask, all_friction[h], 0.0).astype(np.float32)
      if not mask.any():
        continue
      mass = self._slot_masses(ids, mask)
      clock = time.perf_counter()
      render_scene = build_render_scene(self.meshes, ids, poses, mask, bin=config.bin)
      scene, pj_sets, su_sets = self._heap_scene(ids, mask, poses, friction, mass)
      stats['seconds']['render'] += time.perf_counter() - clock
      for c in range(config.dataset.images_per_heap):
        j = h * config.dataset.images_per_heap + c
        if j >= config.dataset.images_per_shard:
          break
        image, image_rows = self._image(j, h, index, ids, mask, poses, friction, mass, render_scene, scene, pj_sets,
                                        su_sets, (k_camera, k_noise, k_label), stats)
        image_rows['image_index'] = np.full(len(image_rows['gripper']), len(images), np.int32)
        images.append(image)
        rows.append(image_rows)
    stacked_images, stacked_rows = _stack(images, rows)
    self.shards_made += 1
    return stacked_images, stacked_rows, stats

  def _image(self, j, h, index, ids, mask, poses, friction, mass, render_scene, scene, pj_sets, su_sets, keys,
             stats):
    """Image ``j`` of the shard (heap ``h``): render, noise, label; returns (image fields, row fields)."""
    config = self.config
    k_camera, k_noise, k_label = (jax.random.fold_in(k, j) for k in keys)
    clock = time.perf_counter()
    camera = run_camera(k_camera, config)
    rendered = self.renderer.render(render_scene, camera)
    depth = noisy_depth(k_noise, rendered.depth, config.noise)
    if config.dataset.inpaint_holes:  # the labeller's one compiled form takes the returned pixels (all, mostly)
      depth, observed = policy_depth(depth)
    else:
      observed = np.ones(np.shape(depth), bool)
    stats['seconds']['render'] += time.perf_counter() - clock
    candidates = None
    if self.collector is not None:
      clock = time.perf_counter()
      obs = observation(depth, camera, (rendered.mask >= 0) & observed)
      candidates = _plan(_policy_key(config.seed, index, j), obs, self.collector)
      stats['seconds']['plan'] += time.perf_counter() - clock
    clock = time.perf_counter()
    out: ImageRows = _label(k_label, jnp.asarray(depth), jnp.asarray(rendered.mask), camera, scene, pj_sets,
                            su_sets, self.params, jnp.asarray(rendered.depth), observed, candidates)
    out = jax.tree.map(np.asarray, out)
    stats['seconds']['label'] += time.perf_counter() - clock
    stats['images'] += 1
    k = camera.intrinsics
    names = np.array([self.names[int(i)] if m else '' for i, m in zip(ids, mask)])
    image = {'depth': np.asarray(depth, np.float32), 'mask': np.asarray(rendered.mask, np.int32),
             'camera_intrinsics': np.array([k.fx, k.fy, k.cx, k.cy], np.float32),
             'camera_rotation': np.asarray(camera.rotation, np.float32),
             'camera_translation': np.asarray(camera.position, np.float32),
             'heap_id': np.int64(index * self.heaps_per_shard + h), 'object_ids': ids.astype(np.int32),
             'object_poses': np.asarray(poses, np.float32), 'object_names': names,
             'object_friction': friction, 'object_mass': mass}
    keep = out.ok
    image_rows = {'gripper': out.gripper[keep].astype(np.int8), 'center': out.center[keep].astype(np.float32),
                  'angle': out.angle[keep].astype(np.float32), 'grasp_depth': out.grasp_depth[keep].astype(np.float32),
                  'approach_angle': out.approach_angle[keep].astype(np.float32),
                  'grasp_pose': out.grasp_pose[keep].astype(np.float32), 'reward': out.reward[keep].astype(np.int8),
                  'robust_probability': out.robust_probability[keep].astype(np.float32),
                  'failure': out.failure[keep].astype(np.int8), 'target_slot': out.target_slot[keep].astype(np.int8),
                  'policy': out.policy[keep].astype(np.int8)}
    return image, image_rows


def _stack(images: Sequence[dict[str, np.ndarray]], rows: Sequence[dict[str, np.ndarray]]):
  """Image fields stacked along N and row fields concatenated along M (empty arrays when there are none)."""
  from dexjax.data.shards import IMAGE_SCHEMA, ROW_SCHEMA  # pylint: disable=g-import-not-at-top
  if not images:
    raise RuntimeError('every heap of this shard diverged or lost all its objects; no image was made')
  stacked_images = {k: np.stack([im[k] for im in images]) for k in IMAGE_SCHEMA}
  stacked_rows = {k: np.concatenate([r[k] for r in rows]) for k in ROW_SCHEMA}
  return stacked_images, stacked_rows


_GENERATORS: dict[str, ShardGenerator] = {}


def close_process_generators() -> None:
  """Closes and forgets this process's generators (their renderers hold GL contexts); runs at exit too."""
  while _GENERATORS:
    _GENERATORS.popitem()[1].close()


def process_generator(config: GenerateConfig, cache_dir: str | os.PathLike[str] | None = None) -> ShardGenerator:
  """This process's `ShardGenerator` for ``config`` (made once, then reused)."""
  key = f'{fingerprint(config)}:{config.seed}:{cache_dir}'
  if key not in _GENERATORS:
    _GENERATORS[key] = ShardGenerator(config, cache_dir=cache_dir)
    # Registered after the GL context exists, so it runs before GL's own exit handler ends the display.
    atexit.register(close_process_generators)
  return _GENERATORS[key]


def generate_shard(index: int, config: GenerateConfig, out_dir: str, cache_dir: str | None = None) -> dict[str, Any]:
  """Makes and writes shard ``index`` of the run in ``out_dir``; returns its stats and row summary fields.

  The task a worker runs (picklable with `functools.partial`). The shard is written atomically and recorded in
  the manifest (`dexjax.data.finish_shard`). Programs compiled for it are kept in JAX's persistent cache
  (`dexjax.compile_cache`), so a resumed run or a new worker process loads the labeller instead of compiling it.
  Besides the counts, the stats hold ``wall_seconds`` of the task, the worker's ``pid`` and ``warm`` (False for a
  process's first shard, which includes start-up and compiling).
  """
  start = time.perf_counter()
  generator = process_generator(config, cache_dir)
  warm = generator.shards_made > 0
  with persistent_compilation_cache():  # a worker loads the labeller another run (or worker) compiled
    images, rows, stats = generator.generate(index)
  clock = time.perf_counter()
  finish_shard(out_dir, index, images, rows, {'config_fingerprint': generator.fingerprint, 'seed': config.seed})
  stats['seconds']['write'] += time.perf_counter() - clock
  stats['rows'] = {k: rows[k] for k in ('gripper', 'reward', 'robust_probability', 'failure', 'policy')}
  stats.update(wall_seconds=time.perf_counter() - start, pid=os.getpid(), warm=warm)
  return stats


__all__ = ['NoObjectsError', 'ShardGenerator', 'close_process_generators', 'generate_shard', 'image_label_key',
           'label_params', 'policy_depth', 'process_generator', 'stage_names', 'usable_objects']
