"""Labelled actions of one rendered image: candidates, supervisor, collection policy tau and reward S(x, u).

`label_image` is the jittable core of dataset generation. For one depth image of a settled heap it

1. samples the candidate sets U_g(y) of both grippers from the depth image (`dexjax.sampling`: antipodal
   depth-edge pairs, suction points), restricted to points above the bottom of the bin (`pickable_mask`);
2. maps the supervisor's grasp sets of the heap's objects into the image (`dexjax.generate.supervisor`),
   only when the policy draws at least one supervisor action (a `jax.lax.cond`);
3. chooses ``actions_per_gripper`` actions per gripper with tau (`dexjax.generate.policy`); with
   ``policy_candidates`` (on-policy synthesis, `dexjax.generate.on_policy`) a gripper's candidate set is the
   grasps a learned policy scored on this image instead, its ``top_k`` highest-scored first;
4. turns each image action into the 3-D grasp it executes and labels it with the heap reward
   (`dexjax.quality.heap_reward`: collisions, exactly one object, robust probability with M = 10).

Everything has static shapes (H x W image, P slots, K supervisor grasps per object, A actions per gripper), so
one compilation serves a whole run. Rows come out in a fixed order: A parallel-jaw actions, then A suction ones.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.generate import supervisor as sup
from dexjax.generate.policy import CANDIDATE, POLICY, SUPERVISOR, PolicyParams, collection_actions, supervisor_draws
from dexjax.grasps import parallel_jaw_pose, suction_pose
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality.heap_reward import HeapScene, RewardParams, parallel_jaw_heap_reward, suction_heap_reward
from dexjax.quality.robust import Perturbations, parallel_jaw_perturbations, suction_perturbations
from dexjax.render.camera import Camera, pixel_rays
from dexjax.sampling.image_grasps import parallel_jaw_grasp_3d, suction_grasp_3d
from dexjax.sampling.image_samplers import (AntipodalImageSampler, SuctionImageSampler, sample_antipodal_image_grasps,
                                            sample_suction_image_grasps)
from dexjax.sim.heap import Bin

PARALLEL_JAW, SUCTION = 0, 1

#: Version of the labelling semantics, part of every run's config fingerprint: bump it whenever the labels of
#: one config change, so no cached dataset made by older code is reused. 2: the reward uses the heap state's
#: friction per object instead of a new friction draw per Monte-Carlo sample. 3: fingers with volume: the robust
#: quality fails with ``jaw_collision`` when the open fingers or palm overlap the object (per draw), and the
#: supervisor's grasps come from the collision-checked antipodal sampler. 4: the heap reward's jaw collision test
#: is the single-object one (`jaw_collides`, refined between the samples) against every object, so an overlap of a
#: finger or the palm with any object is found from about the 1 mm tolerance on (the plain 5 mm sample grid missed
#: overlaps of up to ~3.5 mm, which the benchmark's physics judge then met as collisions), and the bin test adds the
#: solids' corners (jaws) and rims (cup, shaft), exact against the floor, and the jaws' boxes against the walls.
#: 5: a suction grasp fails with ``tips`` when the object's centre of mass stands so high above the cup's bellows
#: that it tips over on them (k < m g h, `dexjax.quality.grasp_quality.bellows_margin`): a bowl held from inside.
#: 6: the tipping test has the centre of mass's offset from the bellows' axis and the bellows' range
#: (k a >= m g (d cos a + h sin a), `bellows_margin`): a bowl held a few mm off its axis bends them to the stop.
#: 7: a parallel-jaw grasp whose pads would close on a bin wall (the wall lies between them, `jaw_closing_box`:
#: one finger outside the bin, the palm passing over the wall) is a bin collision; version 6 found the contacts on
#: the object beyond the wall, and the physics judge's jaws closed on the wall (issue 42). 8: each object's mass is
#: drawn from the Gamma law centred on its own simulated mass with the seed's relative spread
#: (`dexjax.quality.with_object_mass`) instead of the seed's prior about 0.25 kg; images store ``object_mass``.
LABEL_VERSION = 8


@struct.dataclass
class LabelParams:
  """Everything `label_image` needs besides the image and the heap (defaults: Dex-Net 4.0).

  Attributes:
    parallel_jaw_sampler, suction_sampler: the candidate samplers.
    parallel_jaw, suction: the grippers.
    parallel_jaw_perturbations, suction_perturbations: the reward's noise models (gravity is replaced by the
      world's inside the reward; ``num_samples`` by the reward's).
    reward: `RewardParams` (M = 10, threshold 0.5, collision geometry).
    supervisor: `dexjax.generate.SupervisorParams`.
    policy: `PolicyParams` (epsilon, actions per gripper).
    bin: static, the bin.
  """

  parallel_jaw_sampler: AntipodalImageSampler = AntipodalImageSampler()
  suction_sampler: SuctionImageSampler = SuctionImageSampler()
  parallel_jaw: ParallelJawGripper = ParallelJawGripper()
  suction: SuctionGripper = SuctionGripper()
  parallel_jaw_perturbations: Perturbations = parallel_jaw_perturbations()
  suction_perturbations: Perturbations = suction_perturbations()
  reward: RewardParams = RewardParams()
  supervisor: sup.SupervisorParams = sup.SupervisorParams()
  policy: PolicyParams = PolicyParams()
  bin: Bin = struct.field(pytree_node=False, default=Bin())


@struct.dataclass
class ImageRows:
  """The 2A labelled actions of one image (A parallel-jaw rows, then A suction rows); see `ROW_SCHEMA`.

  Attributes:
    gripper: (2A,) int32, 0 parallel jaw, 1 suction.
    center: (2A, 2) float32 grasp centre pixel (u, v).
    angle: (2A,) float32 in-image angle, radians.
    grasp_depth: (2A,) float32 depth of the grasp centre along the optical axis, metres.
    approach_angle: (2A,) float32 angle between approach and optical axis, radians (0 for parallel jaws).
    grasp_pose: (2A, 4, 4) float32 gripper-to-world pose, metres.
    reward, robust_probability, failure, target_slot: the `RewardRecord` fields, (2A,).
    policy: (2A,) int32, `dexjax.generate.CANDIDATE`, `SUPERVISOR` or (on-policy candidates) `POLICY`.
    ok: (2A,) bool, the row exists (a candidate or supervisor grasp was available).
  """

  gripper: jax.Array
  center: jax.Array
  angle: jax.Array
  grasp_depth: jax.Array
  approach_angle: jax.Array
  grasp_pose: jax.Array
  reward: jax.Array
  robust_probability: jax.Array
  failure: jax.Array
  target_slot: jax.Array
  policy: jax.Array
  ok: jax.Array


def pickable_mask(depth: jax.Array, camera: Camera, bin_: Bin, clearance: float | jax.Array) -> jax.Array:
  """(H, W) bool: pixels whose point lies above the bottom of the bin (seed: suction candidates are "sampled
  uniformly from the set of points above the bottom of the bin"): world z > ``clearance`` metres and inside the
  bin's inner footprint. Uses only the depth image and the camera, as a policy at test time can."""
  points = pixel_rays(camera.intrinsics) * depth[..., None]
  world = points @ camera.rotation.T + camera.position
  hx, hy = bin_.inner_size[0] / 2.0, bin_.inner_size[1] / 2.0
  inside = (jnp.abs(world[..., 0]) < hx) & (jnp.abs(world[..., 1]) < hy)
  return jnp.isfinite(depth) & (depth > 0) & inside & (world[..., 2] > clearance)


def _take(tree, index: jax.Array):
  return jax.tree.map(lambda a: a[index], tree)


def _choose(source: jax.Array, index: jax.Array, candidates, pool):
  """Per action, the candidate or the supervisor grasp ``index`` (image grasps with a leading axis)."""
  from_candidates, from_pool = _take(candidates, index), _take(pool, jnp.clip(index, 0, None))
  return jax.tree.map(lambda c, s: jnp.where((source == SUPERVISOR).reshape((-1,) + (1,) * (c.ndim - 1)), s, c),
                      from_candidates, from_pool)


def _image_keys(key: jax.Array) -> jax.Array:
  """`label_image`'s six keys: candidates (parallel jaw, suction), rows (the same), supervisor (the same)."""
  return jax.random.split(key, 6)


def _action_reward_keys(rows_key: jax.Array, num_actions: int) -> jax.Array:
  """(A,) reward keys of one gripper's actions, from that gripper's rows key (its tau key is the other half)."""
  return jax.random.split(jax.random.split(rows_key)[1], num_actions)


def reward_keys(image_key: jax.Array, gripper: int, num_actions: int) -> jax.Array:
  """(A,) keys of the reward draws of the A actions of ``gripper`` (`PARALLEL_JAW` or `SUCTION`) in the image that
  `label_image` labels with ``image_key``: action a's robust quality used key a. With them,
  `dexjax.generate.relabel_shard` reproduces a shard's labels (rows are the actions that exist, in order)."""
  return _action_reward_keys(_image_keys(image_key)[2 + gripper], num_actions)


def _gripper_rows(key: jax.Array, code: int, camera: Camera, candidates, valid: jax.Array, pool_fn, pool_size: int,
                  label_fn, params: LabelParams, priority: jax.Array | None = None) -> ImageRows:
  """The A labelled actions of one gripper: tau's choice, its 3-D grasp, pose and reward.

  ``pool_fn()`` returns the supervisor's (image grasps (S,), eligible (S,)) and runs only when tau draws a
  supervisor action; ``label_fn(key, camera, image_grasp)`` returns (pose (4, 4), approach angle, RewardRecord).
  With ``priority`` (a learned policy's scores of the candidates), candidate rows are `POLICY` rows.
  """
  k_tau = jax.random.split(key)[0]
  wanted = supervisor_draws(k_tau, params.policy)
  empty = (jax.tree.map(lambda a: jnp.zeros((pool_size,) + a.shape[1:], a.dtype), candidates),
           jnp.zeros((pool_size,), bool))
  pool, eligible = jax.lax.cond(jnp.any(wanted), pool_fn, lambda: empty)
  source, index, ok = collection_actions(k_tau, valid, eligible, params.policy, priority)
  chosen = _choose(source, index, candidates, pool)
  keys = _action_reward_keys(key, source.shape[0])
  pose, approach_angle, record = jax.vmap(label_fn, in_axes=(0, None, 0))(keys, camera, chosen)
  a = source.shape[0]
  return ImageRows(gripper=jnp.full((a,), code, jnp.int32), center=chosen.center, angle=chosen.angle,
                   grasp_depth=chosen.depth, approach_angle=approach_angle, grasp_pose=pose, reward=record.reward,
                   robust_probability=record.robust_probability, failure=record.failure,
                   target_slot=record.target_slot,
                   policy=source if priority is None else jnp.where(source == CANDIDATE, POLICY, source), ok=ok)


def label_image(key: jax.Array, depth: jax.Array, segmask: jax.Array, camera: Camera, scene: HeapScene,
                parallel_jaw_sets: sup.GraspSet, suction_sets: sup.GraspSet, params: LabelParams = LabelParams(),
                rendered_depth: jax.Array | None = None, observed: jax.Array | None = None,
                policy_candidates: dict | None = None) -> ImageRows:
  """Samples, chooses and labels the actions of one image (see the module docstring).

  Args:
    key: PRNG key.
    depth: (H, W) float32 depth image the policy sees (with sensor noise, if any), metres; NaN invalid.
    segmask: (H, W) int32 rendered slot mask (`dexjax.render.DepthImage.mask`): used only by the supervisor,
      to keep grasps whose centre pixel shows their object.
    camera: the image's `Camera`.
    scene: the settled heap (P slots).
    parallel_jaw_sets, suction_sets: the supervisor's object-frame `GraspSet` s of each slot's object,
      (P, K) leading axes.
    params: `LabelParams`.
    rendered_depth: (H, W) noise-free rendered depth, metres, for the supervisor's visibility test of suction
      targets (default: ``depth``).
    observed: (H, W) bool pixels the sensor returned, when ``depth`` has its holes inpainted (as a policy's
      `dexjax.policy.Observation`): candidates come only from these (suction points, jaw contact edges), as
      from a policy's observation mask (default: every valid pixel of ``depth``).
    policy_candidates: ``{'parallel_jaw' and/or 'suction': (grasps (C,), valid (C,), score (C,))}``, the grasps a
      learned policy scored on this image (`dexjax.generate.on_policy.policy_candidates`, C >= A): that
      gripper's candidate set instead of the sampler's, its ``params.policy.top_k`` highest-scored first, its
      rows coded `POLICY` (default: the seed's sampled candidates for both).

  Returns:
    `ImageRows` with 2A rows: parallel jaws first.
  """
  k_pj, k_su, k_rows_pj, k_rows_su, k_sup_pj, k_sup_su = _image_keys(key)
  pick = pickable_mask(depth, camera, params.bin, params.policy.floor_clearance)
  if observed is not None:
    pick = pick & observed
  policy_candidates = policy_candidates or {}
  if 'parallel_jaw' in policy_candidates:
    pj_cands, pj_valid, pj_priority = policy_candidates['parallel_jaw']
  else:
    pj_cands, pj_valid = sample_antipodal_image_grasps(k_pj, depth, camera, params.parallel_jaw_sampler, mask=pick)
    pj_priority = None
  if 'suction' in policy_candidates:
    su_cands, su_valid, su_priority = policy_candidates['suction']
  else:
    su_cands, su_valid = sample_suction_image_grasps(k_su, depth, camera, params.suction_sampler, mask=pick)
    su_priority = None

  def pj_pool():
    return sup.parallel_jaw_supervisor_candidates(parallel_jaw_sets, scene, params.bin, camera, segmask,
                                                  params.supervisor, params.parallel_jaw, params.reward, k_sup_pj)

  def su_pool():
    return sup.suction_supervisor_candidates(suction_sets, scene, params.bin, camera, segmask, params.supervisor,
                                             params.suction, params.reward,
                                             depth if rendered_depth is None else rendered_depth, k_sup_su)

  def pj_label(k, cam, g):
    grasp = parallel_jaw_grasp_3d(cam, g)
    record = parallel_jaw_heap_reward(k, grasp, scene, params.bin, params.parallel_jaw, params.reward,
                                      params.parallel_jaw_perturbations)
    return parallel_jaw_pose(grasp), jnp.zeros((), jnp.float32), record

  def su_label(k, cam, g):
    grasp = suction_grasp_3d(cam, g)
    record = suction_heap_reward(k, grasp, scene, params.bin, params.suction, params.reward,
                                 params.suction_perturbations)
    return suction_pose(grasp), g.approach_angle, record

  pool_size = parallel_jaw_sets.valid.size
  pj = _gripper_rows(k_rows_pj, PARALLEL_JAW, camera, pj_cands, pj_valid, pj_pool, pool_size, pj_label, params,
                     pj_priority)
  su = _gripper_rows(k_rows_su, SUCTION, camera, su_cands, su_valid, su_pool, suction_sets.valid.size, su_label,
                     params, su_priority)
  return jax.tree.map(lambda a, b: jnp.concatenate([a, b]), pj, su)


__all__ = ['LABEL_VERSION', 'PARALLEL_JAW', 'SUCTION', 'ImageRows', 'LabelParams', 'label_image', 'pickable_mask',
           'reward_keys']
