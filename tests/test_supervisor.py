"""The Dex-Net 4.0 algorithmic supervisor: robust grasp sets, their on-disk cache, the mapping into a heap.

Heaps are hand-built from the built-in box (8 x 6 x 4 cm) and cube (4 cm), both centred on their frames. The
camera looks straight down from 0.6 m; its segmentation mask and depth are ray cast here in NumPy against the
exact boxes (oriented with SciPy), independently of the library's transforms and SDFs.
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dexjax.generate.supervisor import (GraspSet, SupervisorParams, cached_grasp_sets, choose_supervisor_grasp,
                                        heap_grasp_sets, parallel_jaw_grasp_set, parallel_jaw_supervisor_candidates,
                                        suction_grasp_set, suction_supervisor_candidates)
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality import (HeapScene, QualityConfig, parallel_jaw_perturbations, robust_parallel_jaw_quality,
                            robust_suction_quality, stack_models, suction_perturbations)
from dexjax.render import Camera, Intrinsics
from dexjax.sim.heap import Bin

GRID = 32
BOX, CUBE = 0, 1
HALF = {BOX: np.array([0.04, 0.03, 0.02]), CUBE: np.array([0.02, 0.02, 0.02])}
SEED = 5
PARAMS = SupervisorParams(num_grasps=6)
BIN = Bin()
H = W = 200
F, C = 300.0, 100.0
EYE = np.array([0.0, 0.0, 0.6])
# Top-down camera: image x = world x, image y = world -y, optical axis = world -z.
CAM_ROT = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]).T
CAMERA = Camera(intrinsics=Intrinsics(fx=F, fy=F, cx=C, cy=C, width=W, height=H),
                rotation=jnp.asarray(CAM_ROT, jnp.float32), position=jnp.asarray(EYE, jnp.float32))

_jaw_candidates = jax.jit(parallel_jaw_supervisor_candidates, static_argnums=2)
_cup_candidates = jax.jit(suction_supervisor_candidates, static_argnums=2)


@pytest.fixture(scope="module")
def models(tmp_path_factory):
  from dexjax.objects import load_object_model
  cache = tmp_path_factory.mktemp("supervisor_objects")
  return [load_object_model(f"builtin:{name}", cache_dir=cache, grid_size=GRID) for name in ("box", "cube")]


# --- NumPy references ----------------------------------------------------------------------------------------


def _quat_z(degrees):
  return Rotation.from_euler("z", degrees, degrees=True).as_quat(scalar_first=True)


def _scene(models, entries, num_slots=3):
  """`HeapScene` of (object id, position, quaternion wxyz, occupied) entries, padded to ``num_slots``."""
  ids, occupied = np.zeros(num_slots, np.int32), np.zeros(num_slots, bool)
  poses = np.tile(np.array([0.0, 0.0, -1.0, 1.0, 0.0, 0.0, 0.0], np.float32), (num_slots, 1))
  for slot, (index, position, quat, used) in enumerate(entries):
    ids[slot], occupied[slot], poses[slot] = index, used, np.r_[position, quat]
  return HeapScene(models=stack_models(models), object_ids=jnp.asarray(ids), mask=jnp.asarray(occupied),
                   poses=jnp.asarray(poses), friction=jnp.where(jnp.asarray(occupied), 0.8, 0.0))


def _ray_cast(scene):
  """(mask (H, W) int32, depth (H, W) metres) of the occupied boxes of ``scene`` and the floor z = 0."""
  v, u = np.mgrid[0:H, 0:W].astype(np.float64)
  rays = np.stack([(u - C) / F, (v - C) / F, np.ones_like(u)], -1) @ CAM_ROT.T  # world direction, camera z = 1
  best = np.where(rays[..., 2] < 0, -EYE[2] / rays[..., 2], np.inf)
  label = np.full((H, W), -1, np.int32)
  for slot in range(len(scene.mask)):
    if not scene.mask[slot]:
      continue
    pose = np.asarray(scene.poses[slot], np.float64)
    rot = Rotation.from_quat(pose[3:], scalar_first=True).as_matrix()
    half = HALF[int(scene.object_ids[slot])]
    o, d = rot.T @ (EYE - pose[:3]), rays @ rot  # ray in the box frame
    with np.errstate(divide="ignore", invalid="ignore"):
      t1, t2 = (-half - o) / d, (half - o) / d
    near = np.max(np.minimum(t1, t2), -1)
    far = np.min(np.maximum(t1, t2), -1)
    hit = (near <= far) & (near > 0) & (near < best)
    best, label = np.where(hit, near, best), np.where(hit, slot, label)
  return label, best.astype(np.float32)


def _pixel(world):
  p = CAM_ROT.T @ (np.asarray(world, np.float64) - EYE)
  return np.array([F * p[0] / p[2] + C, F * p[1] / p[2] + C]), p[2]


def _world(scene, slot, local):
  pose = np.asarray(scene.poses[slot], np.float64)
  return Rotation.from_quat(pose[3:], scalar_first=True).as_matrix() @ np.asarray(local) + pose[:3]


def _set(grasps, quality, valid, num_slots):
  """A `GraspSet` (num_slots, K): the same K grasps in every slot."""
  f = lambda x: jnp.asarray(np.broadcast_to(np.asarray(x), (num_slots,) + np.shape(x)))
  return GraspSet(grasps=jax.tree.map(f, grasps), quality=f(np.asarray(quality, np.float32)),
                  valid=f(np.asarray(valid, bool)))


def _cups(entries):
  centers, approaches = zip(*entries)
  return SuctionGrasp(center=np.asarray(centers, np.float32), approach=np.asarray(approaches, np.float32))


def _jaws(centers, axes):
  axes = np.asarray(axes, np.float64)
  axes /= np.linalg.norm(axes, axis=1, keepdims=True)
  approach = np.cross(axes, [0.0, 1.0, 0.0])  # any perpendicular: the mapping chooses its own approach
  approach = np.where(np.linalg.norm(approach, axis=1, keepdims=True) < 1e-6, [1.0, 0.0, 0.0], approach)
  approach /= np.linalg.norm(approach, axis=1, keepdims=True)
  return ParallelJawGrasp(center=np.asarray(centers, np.float32), axis=axes.astype(np.float32),
                          approach=approach.astype(np.float32), width=np.full(len(axes), 0.05, np.float32))


# --- Grasp sets and cache ------------------------------------------------------------------------------------


@pytest.mark.slow  # compiles the samplers and the two robust qualities, shared with the cache test: ~30 s here
def test_grasp_set_quality_is_the_direct_robust_quality_with_25_draws(models):
  """Set grasp i's quality is `robust_*_quality` with key fold_in(split(key)[1], i) and the supervisor's
  perturbations (M = 25), for the parallel-jaw and the suction set; invalid grasps have quality 0."""
  key = jax.random.key(11)
  # Arguments as `cached_grasp_sets` passes them: the sets and the cache test share the compiled sampler and
  # robust quality with the direct references below (same functions, same argument structure).
  jaw = parallel_jaw_grasp_set(key, models[CUBE], ParallelJawGripper(), PARAMS, parallel_jaw_perturbations(25),
                               QualityConfig())
  cup = suction_grasp_set(key, models[BOX], SuctionGripper(), PARAMS, suction_perturbations(25), QualityConfig())
  k_quality = jax.random.split(key)[1]
  cases = ((jaw, jax.jit(robust_parallel_jaw_quality), models[CUBE], ParallelJawGripper(),
            parallel_jaw_perturbations(num_samples=25)),
           (cup, jax.jit(robust_suction_quality), models[BOX], SuctionGripper(), suction_perturbations(num_samples=25)))
  for grasp_set, direct, model, gripper, pert in cases:
    assert grasp_set.quality.shape == (6,) and grasp_set.quality.dtype == jnp.float32
    valid = np.asarray(grasp_set.valid)
    assert valid.sum() >= 2
    expected = []
    for i in range(6):
      grasp = jax.tree.map(lambda a, i=i: a[i], grasp_set.grasps)
      result = direct(jax.random.fold_in(k_quality, i), model, grasp, gripper, pert, QualityConfig())
      assert result.outcomes.resists.shape == (25,)
      expected.append(float(result.probability))
    np.testing.assert_allclose(np.asarray(grasp_set.quality), np.where(valid, expected, 0.0), atol=1e-6)
    assert len(set(np.round(np.asarray(expected)[valid], 6))) >= 2  # not a constant: the draws tell grasps apart
  assert not np.asarray(jaw.valid).all()  # so the zeros of invalid grasps were checked
  # Parallel-jaw approaches are the fixed perpendicular of the axis.
  np.testing.assert_allclose(np.sum(np.asarray(jaw.grasps.axis * jaw.grasps.approach), -1), 0.0, atol=1e-6)


def test_cached_grasp_sets_load_from_disk_and_key_on_content_seed_and_parameters(models, tmp_path):
  first = cached_grasp_sets(models, SEED, params=PARAMS, cache_dir=tmp_path)
  files = sorted(os.listdir(tmp_path))
  assert len(files) == 2 and all(f.startswith("supervisor-") and f.endswith(".npz") for f in files)
  assert first[0].quality.shape == (2, 6) and first[1].grasps.center.shape == (2, 6, 3)
  # Same inputs, other list order: loaded (no new file), bit-identical per object.
  again = cached_grasp_sets(models[::-1], SEED, params=PARAMS, cache_dir=tmp_path)
  assert sorted(os.listdir(tmp_path)) == files
  for a, b in zip(jax.tree.leaves(first), jax.tree.leaves(again)):
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b)[::-1])
  # The call reads the file: an edited entry comes back as stored.
  path = tmp_path / files[0]
  with np.load(path) as data:
    arrays = dict(data)
  arrays["jaw.quality"] = np.full_like(arrays["jaw.quality"], 0.125)
  np.savez(path, **arrays)
  edited = cached_grasp_sets(models, SEED, params=PARAMS, cache_dir=tmp_path)
  assert sum(bool(np.all(np.asarray(edited[0].quality[n]) == 0.125)) for n in range(2)) == 1
  # Another seed and another sampler friction are other entries.
  cached_grasp_sets(models[:1], SEED + 1, params=PARAMS, cache_dir=tmp_path)
  assert len(os.listdir(tmp_path)) == 3
  other = PARAMS.replace(sampler=PARAMS.sampler.replace(friction=0.6))
  cached_grasp_sets(models[:1], SEED, params=other, cache_dir=tmp_path)
  assert len(os.listdir(tmp_path)) == 4
  # Heap-mapping settings do not change the sets: same entry.
  cached_grasp_sets(models[:1], SEED, params=PARAMS.replace(threshold=0.5, boundary=10.0), cache_dir=tmp_path)
  assert len(os.listdir(tmp_path)) == 4
  heap = heap_grasp_sets(first[1], jnp.array([1, 0, 1], jnp.int32))
  np.testing.assert_array_equal(np.asarray(heap.quality[2]), np.asarray(first[1].quality[1]))


# --- Mapping into the heap -----------------------------------------------------------------------------------

TOP, CENTRE = (0.0, 0.0, -1.0), (0.0, 0.0, 0.02)


def _box_scene(models):
  """Slot 0: the box lying flat, turned 30 degrees about z; slot 1: the same pose, not occupied."""
  entry = (BOX, (0.01, -0.005, 0.02), _quat_z(30.0))
  return _scene(models, [(*entry, True), (*entry, False)], num_slots=2)


def _cup_set():
  grasps = _cups([(CENTRE, TOP), ((0.025, 0.015, 0.02), TOP), ((0.0, 0.0, -0.02), (0.0, 0.0, 1.0)), (CENTRE, TOP),
                  ((0.04, 0.0, 0.0), (-1.0, 0.0, 0.0)), (CENTRE, TOP)])
  return _set(grasps, [0.9, 0.9, 0.9, 0.7, 0.9, 0.9], [True, True, True, True, True, False], 2)


def test_suction_top_face_grasps_map_to_their_pixels_and_only_they_are_eligible(models):
  """Top-face grasps: eligible, at the NumPy projection; bottom, side, not robust, invalid and unoccupied: not."""
  scene = _box_scene(models)
  mask, depth = _ray_cast(scene)
  grasps, eligible = _cup_candidates(_cup_set(), scene, BIN, CAMERA, jnp.asarray(mask), PARAMS)
  assert grasps.center.shape == (12, 2)
  assert np.asarray(eligible).tolist() == [True, True] + [False] * 10
  for k, local in ((0, CENTRE), (1, (0.025, 0.015, 0.02))):
    uv, z = _pixel(_world(scene, 0, local))
    np.testing.assert_allclose(np.asarray(grasps.center[k]), uv, atol=2e-3)
    assert float(grasps.depth[k]) == pytest.approx(z, abs=1e-5)
    assert float(grasps.approach_angle[k]) == pytest.approx(0.0, abs=1e-3)
    assert float(depth[int(round(uv[1])), int(round(uv[0]))]) == pytest.approx(z, abs=1e-4)
  # The bottom face faces away from the camera (approach angle pi), the side face is at pi / 2.
  assert float(grasps.approach_angle[2]) == pytest.approx(np.pi, abs=1e-3)
  assert float(grasps.approach_angle[4]) == pytest.approx(np.pi / 2, abs=1e-3)
  # With the rendered depth the targets are still visible; with depth 2 cm off they are not.
  _, with_depth = _cup_candidates(_cup_set(), scene, BIN, CAMERA, jnp.asarray(mask), PARAMS, depth=jnp.asarray(depth))
  assert np.asarray(with_depth)[:2].tolist() == [True, True]
  _, wrong = _cup_candidates(_cup_set(), scene, BIN, CAMERA, jnp.asarray(mask), PARAMS,
                             depth=jnp.asarray(depth + 0.02))
  assert not np.any(np.asarray(wrong))


def test_grasps_hidden_in_the_mask_or_near_the_border_are_not_eligible(models):
  scene = _box_scene(models)
  mask, _ = _ray_cast(scene)
  # The box's pixels relabelled as slot 1 (not occupied) or invalid: nothing is eligible.
  for relabel in (1, -2):
    _, eligible = _cup_candidates(_cup_set(), scene, BIN, CAMERA, jnp.asarray(np.where(mask == 0, relabel, mask)),
                                  PARAMS)
    assert not np.any(np.asarray(eligible))
  # A boundary that puts the grasp centres (u ~ 105 px) within it of the border.
  uv, _ = _pixel(_world(scene, 0, CENTRE))
  _, eligible = _cup_candidates(_cup_set(), scene, BIN, CAMERA, jnp.asarray(mask),
                                PARAMS.replace(boundary=float(W - uv[0] + 2)))
  assert not np.asarray(eligible)[0]


def test_suction_cup_colliding_with_a_neighbour_is_not_eligible(models):
  """A cube floating beside the cup's path (5 mm from its axis, 1-5 cm above the target) leaves the target
  visible but collides with the 1 cm cup swept back along the approach."""
  entry = (BOX, (0.0, 0.0, 0.02), _quat_z(0.0), True)
  clear = _scene(models, [entry, (CUBE, (0.09, 0.0, 0.07), _quat_z(0.0), True)], num_slots=2)
  blocked = _scene(models, [entry, (CUBE, (0.025, 0.0, 0.07), _quat_z(0.0), True)], num_slots=2)
  for scene, expected in ((clear, True), (blocked, False)):
    mask, _ = _ray_cast(scene)
    uv, _ = _pixel(_world(scene, 0, CENTRE))
    assert mask[int(round(uv[1])), int(round(uv[0]))] == 0  # the target is visible in both
    _, eligible = _cup_candidates(_cup_set(), scene, BIN, CAMERA, jnp.asarray(mask), PARAMS)
    assert bool(eligible[0]) == expected


def _jaw_set_pk(num_slots):
  tilt = lambda deg: (np.cos(np.radians(deg)), 0.0, np.sin(np.radians(deg)))
  grasps = _jaws([(0.0, 0.0, 0.0)] * 5, [(1.0, 0.0, 0.0), (0.0, 0.0, 1.0), tilt(5.0), tilt(20.0), (0.0, 1.0, 0.0)])
  return _set(grasps, [0.9] * 5, [True] * 5, num_slots)


def test_parallel_jaw_mapping_tilt_angle_and_executed_grasp(models):
  """Jaws across a flat cube: horizontal axes (and 5 degrees off) are eligible; a vertical axis (horizontal
  approach) and 20 degrees off are not; angle and centre match the NumPy projection."""
  scene = _scene(models, [(CUBE, (0.02, 0.01, 0.02), _quat_z(25.0), True)], num_slots=2)
  mask, _ = _ray_cast(scene)
  grasps, eligible = _jaw_candidates(_jaw_set_pk(2), scene, BIN, CAMERA, jnp.asarray(mask), PARAMS)
  assert np.asarray(eligible).tolist() == [True, False, True, False, True] + [False] * 5
  centre = _world(scene, 0, (0.0, 0.0, 0.0))
  for k, axis in ((0, (1.0, 0.0, 0.0)), (4, (0.0, 1.0, 0.0))):
    uv, z = _pixel(centre)
    np.testing.assert_allclose(np.asarray(grasps.center[k]), uv, atol=2e-3)
    assert float(grasps.depth[k]) == pytest.approx(z, abs=1e-5)
    # The jaw axis in the image: direction between the projections of the two jaw positions.
    du = _pixel(centre + 0.01 * _world(scene, 0, axis) - 0.01 * _world(scene, 0, (0.0, 0.0, 0.0)))[0] - uv
    expected = np.arctan2(du[1], du[0])
    assert np.cos(2.0 * (float(grasps.angle[k]) - expected)) == pytest.approx(1.0, abs=1e-5)
    assert float(grasps.width[k]) == pytest.approx(0.05)


def test_parallel_jaw_finger_colliding_with_a_neighbour_is_not_eligible(models):
  """A second cube 4.3 cm along x fills the +x finger's place for jaws closing along x, not along y."""
  scene = _scene(models, [(CUBE, (0.0, 0.0, 0.02), _quat_z(0.0), True), (CUBE, (0.043, 0.0, 0.02), _quat_z(0.0), True)],
                 num_slots=2)
  mask, _ = _ray_cast(scene)
  _, eligible = _jaw_candidates(_jaw_set_pk(2), scene, BIN, CAMERA, jnp.asarray(mask), PARAMS)
  eligible = np.asarray(eligible)
  assert not eligible[0] and eligible[4]  # slot 0: x blocked, y free
  assert not eligible[5] and eligible[9]  # slot 1: its -x finger enters the first cube


def test_choose_supervisor_grasp_is_uniform_over_eligible():
  eligible = jnp.array([False, True, False, True, True, False, False, False])
  index, ok = jax.vmap(choose_supervisor_grasp, in_axes=(0, None))(  # eager: a few batched ops, no compile
      jax.random.split(jax.random.key(0), 3000), eligible)
  assert np.all(np.asarray(ok))
  counts = np.bincount(np.asarray(index), minlength=8)
  assert counts[~np.asarray(eligible)].sum() == 0
  np.testing.assert_allclose(counts[[1, 3, 4]] / 3000, 1 / 3, atol=0.04)  # ~ 5 sigma
  index, ok = choose_supervisor_grasp(jax.random.key(1), jnp.zeros(8, bool))
  assert not bool(ok) and int(index) == 0
