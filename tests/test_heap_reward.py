"""The Dex-Net 4.0 heap reward on hand-built heaps of built-in boxes and cubes, with exact geometry.

Box: 8 x 6 x 4 cm, cube: 4 cm, both centred on their frames' origins; a box resting flat on the floor has its
origin at z = 2 cm. Bin: default 0.4 x 0.4 m, so its +x wall spans x in [0.2, 0.21].
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dexjax.geometry import sdf_value
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp
from dexjax.grippers import ParallelJawGripper
from dexjax.quality import (Conditions, parallel_jaw_perturbations, parallel_jaw_quality, robust_parallel_jaw_quality,
                            sample_conditions, with_known_friction, with_object_mass)
from dexjax.quality.heap_reward import (REWARD_FAILURES, HeapScene, heap_grasp_reward, slot_distances,
                                        stack_models)
from dexjax.sim.heap import Bin
from scipy.spatial.transform import Rotation

GRID = 48
P = 10
BOX, CUBE = 0, 1
IDENTITY = (1.0, 0.0, 0.0, 0.0)
KEY = jax.random.key(7)
BIN = Bin()
DOWN = (0.0, 0.0, -1.0)

_reward = jax.jit(heap_grasp_reward, static_argnums=3)
_batched_reward = jax.jit(jax.vmap(heap_grasp_reward, in_axes=(None, 0, 0, None)), static_argnums=3)
_robust_pj = jax.jit(robust_parallel_jaw_quality)


@pytest.fixture(scope="module")
def models(tmp_path_factory):
  from dexjax.objects import load_object_model
  cache = tmp_path_factory.mktemp("heap_reward_cache")
  return [load_object_model(f"builtin:{name}", cache_dir=cache, grid_size=GRID) for name in ("box", "cube")]


def _scene(models, entries, friction=0.8):
  """A `HeapScene` of (object id, position, quaternion wxyz) entries, padded to P slots; ``friction`` is every
  object's Coulomb friction in the heap state."""
  ids = np.zeros(P, np.int32)
  mask = np.zeros(P, bool)
  poses = np.tile(np.array([0, 0, 0, *IDENTITY], np.float32), (P, 1))
  for slot, (index, position, quat) in enumerate(entries):
    ids[slot], mask[slot] = index, True
    poses[slot] = np.r_[position, np.asarray(quat) / np.linalg.norm(quat)]
  return HeapScene(models=stack_models(models), object_ids=jnp.asarray(ids), mask=jnp.asarray(mask),
                   poses=jnp.asarray(poses), friction=jnp.where(jnp.asarray(mask), jnp.float32(friction), 0.0))


def _jaws(center, axis=(1.0, 0.0, 0.0), approach=DOWN, width=0.05):
  f = lambda v: jnp.asarray(v, jnp.float32)
  return ParallelJawGrasp(center=f(center), axis=f(axis), approach=f(approach), width=jnp.float32(width))


def _cup(center, approach=DOWN):
  return SuctionGrasp(center=jnp.asarray(center, jnp.float32), approach=jnp.asarray(approach, jnp.float32))


def _failure(record):
  return REWARD_FAILURES[int(record.failure)]


def _jaw_cases(models):
  """(name, scene, grasp, expected failure, expected target) of the parallel-jaw heaps (shared shapes)."""
  far = (CUBE, (-0.12, 0.12, 0.02), IDENTITY)
  return [
      # Jaws (x) across an isolated cube: fingers at |x| in [2.5, 3.5] cm clear it, tips 1 cm above the floor.
      ("isolated", _scene(models, [(CUBE, (0.0, 0.0, 0.02), IDENTITY), far]), _jaws((0.0, 0.0, 0.02)),
       "none", 0),
      # Two cubes touching along y = 0; the pads (2 cm across y) close on both.
      ("two_touching", _scene(models, [(CUBE, (0.0, 0.02, 0.02), IDENTITY), (CUBE, (0.0, -0.02, 0.02), IDENTITY)]),
       _jaws((0.0, 0.0, 0.02)), "multiple_objects", None),
      # A neighbour at x in [2.3, 6.3] cm fills the +x finger's place (x in [2.5, 3.5] cm).
      ("neighbour", _scene(models, [(CUBE, (0.0, 0.0, 0.02), IDENTITY), (CUBE, (0.043, 0.0, 0.02), IDENTITY)]),
       _jaws((0.0, 0.0, 0.02)), "collision_object", None),
      # A cube against the +x wall: its +x finger (x in [20.4, 21.4] cm) is inside the wall (x in [20, 21] cm).
      ("wall", _scene(models, [(CUBE, (0.179, 0.0, 0.02), IDENTITY)]), _jaws((0.179, 0.0, 0.02)),
       "collision_bin", 0),
      # The cube on another against the +x wall, the jaws opened to 7 cm across the wall: both fingers clear the
      # cubes and the wall (the +x one outside the bin, x in [22.1, 23.1] cm), the palm passes over the wall (its
      # underside 11 cm above the floor, the wall's top at 10 cm), but the +x pad would close on the wall.
      ("across_wall", _scene(models, [(CUBE, (0.179, 0.0, 0.06), IDENTITY), (CUBE, (0.179, 0.0, 0.02), IDENTITY)]),
       _jaws((0.186, 0.0, 0.06), width=0.07),
       "collision_bin", 0),
      # Opened to 7 cm beside the wall (the +x finger's outer face at x = 20 cm, the wall's face): nothing lies
      # between the pads but the cube.
      ("beside_wall", _scene(models, [(CUBE, (0.16, 0.0, 0.02), IDENTITY)]), _jaws((0.155, 0.0, 0.02), width=0.07),
       "none", 0),
  ]


def test_stacked_sdf_matches_object_model_query(models):
  """`slot_distances` reads the same distances as `sdf_value` after the inverse pose transform."""
  q = np.array([0.9, 0.3, -0.2, 0.1])
  q /= np.linalg.norm(q)
  t = np.array([0.05, -0.02, 0.1])
  scene = _scene(models, [(CUBE, t, q), (BOX, t, q)])
  local = np.random.default_rng(0).uniform(-0.05, 0.05, (64, 3)).astype(np.float32)
  world = local @ Rotation.from_quat(np.asarray(q, float), scalar_first=True).as_matrix().T + t
  dist = np.asarray(jax.jit(slot_distances)(scene, jnp.asarray(world, jnp.float32)))
  for slot, model in enumerate(models[::-1]):
    expected = np.asarray(jax.vmap(lambda p, m=model: sdf_value(m, p))(jnp.asarray(local)))
    np.testing.assert_allclose(dist[slot], expected, atol=2e-6)
  assert np.all(np.isinf(dist[2:]))


def test_centred_suction_on_flat_box_succeeds_and_empty_floor_has_no_object(models):
  scene = _scene(models, [(BOX, (0.0, 0.0, 0.02), IDENTITY), (CUBE, (0.12, 0.12, 0.02), IDENTITY)])
  good = _reward(KEY, _cup((0.0, 0.0, 0.04)), scene, BIN)
  assert int(good.reward) == 1 and _failure(good) == "none"
  assert int(good.target_slot) == 0 and int(good.num_contacts) == 1
  assert float(good.robust_probability) > 0.5
  floor = _reward(KEY, _cup((-0.1, -0.1, 0.0)), scene, BIN)
  assert int(floor.reward) == 0 and _failure(floor) == "no_object" and int(floor.target_slot) == -1
  # The cup lowered 1 cm into the box's top face: its body (behind the 3 mm lip slab) is inside the box.
  sunk = _reward(KEY, _cup((0.0, 0.0, 0.03)), scene, BIN)
  assert _failure(sunk) == "collision_object"


@pytest.mark.parametrize("case", range(6))
def test_parallel_jaw_heap_failures(models, case):
  name, scene, grasp, expected, target = _jaw_cases(models)[case]
  record = _reward(KEY, grasp, scene, BIN)
  assert _failure(record) == expected, name
  assert int(record.reward) == (expected == "none")
  if target is not None:
    assert int(record.target_slot) == target
  if name == "two_touching":
    assert int(record.num_contacts) == 2


def test_jit_vmap_batch_agrees_with_single_calls(models):
  cases = _jaw_cases(models)
  scenes = jax.tree.map(lambda *xs: jnp.stack(xs), *[c[1] for c in cases])
  grasps = jax.tree.map(lambda *xs: jnp.stack(xs), *[c[2] for c in cases])
  batch = _batched_reward(KEY, grasps, scenes, BIN)
  assert [REWARD_FAILURES[int(f)] for f in batch.failure] == [c[3] for c in cases]
  for i, (_, scene, grasp, _, _) in enumerate(cases):
    single = _reward(KEY, grasp, scene, BIN)
    for field in ("reward", "target_slot", "num_contacts", "failure"):
      assert int(getattr(batch, field)[i]) == int(getattr(single, field)), field
    np.testing.assert_allclose(float(batch.robust_probability[i]), float(single.robust_probability), atol=1e-6)


def test_robust_probability_equals_object_frame_quality_with_world_gravity(models):
  """A box in a general pose: the reward's probability is the robust quality evaluated directly in the object
  frame (grasp mapped with the independent NumPy rotation, gravity = R^T (0, 0, -1), the state's friction),
  draw for draw."""
  box, key = models[BOX], jax.random.key(1)
  q = np.array([0.8, 0.4, -0.3, 0.2])
  q /= np.linalg.norm(q)
  rot, t = Rotation.from_quat(np.asarray(q, float), scalar_first=True).as_matrix(), np.array([0.03, -0.02, 0.3])
  scene = _scene(models, [(CUBE, (-0.12, -0.12, 0.02), IDENTITY), (BOX, t, q)], friction=0.7)
  world = lambda p: rot @ np.asarray(p) + t
  # Jaws closing on the 4 cm (z) faces, off-centre in x so that gravity's direction matters.
  local = _jaws((0.025, 0.0, 0.0), axis=(0.0, 0.0, 1.0), approach=(0.0, -1.0, 0.0))
  grasp = _jaws(world(local.center), axis=rot @ np.asarray(local.axis), approach=rot @ np.asarray(local.approach))
  record = _reward(key, grasp, scene, BIN)
  assert int(record.target_slot) == 1

  def direct(gravity):
    perturbations = with_known_friction(parallel_jaw_perturbations(), 0.7).replace(
        gravity_axis=jnp.asarray(gravity, jnp.float32), gravity_cone_angle=0.0)
    return float(_robust_pj(key, box, local, ParallelJawGripper(), perturbations).probability)

  np.testing.assert_allclose(float(record.robust_probability), direct(rot.T @ np.array(DOWN)), atol=1e-6)
  # The check can fail: gravity left as the world's -z in the object frame gives another probability.
  assert abs(float(record.robust_probability) - direct(DOWN)) > 0.05
  # Suction on the box's +x face (x = 4 cm) in the same pose targets the box too (same frame code path).
  local = _cup((0.04, 0.01, 0.005), approach=(-1.0, 0.0, 0.0))
  record = _reward(key, _cup(world(local.center), approach=rot @ np.asarray(local.approach)), scene, BIN)
  assert int(record.target_slot) == 1 and int(record.num_contacts) == 1


def test_quat_to_matrix_matches_scipy_in_numpy_and_jax():
  from dexjax.geometry import quat_to_matrix
  q = np.random.default_rng(0).normal(size=(16, 4)) * 3.0  # not normalised: the function normalises
  expected = Rotation.from_quat(q, scalar_first=True).as_matrix()
  np.testing.assert_allclose(quat_to_matrix(q), expected, atol=1e-12)
  np.testing.assert_allclose(np.asarray(jax.vmap(lambda x: quat_to_matrix(x, xp=jnp))(jnp.asarray(q, jnp.float32))),
                             expected, atol=1e-5)


def _off_centre_jaws():
  """Jaws across a cube resting at the origin, moved off its centre along x and z (the weight then twists the
  object in the grip, which only friction resists)."""
  return [_jaws((dx, 0.0, 0.02 + dz), axis=(0.0, 1.0, 0.0)) for dx in (0.0, 0.006, 0.012, 0.016)
          for dz in (0.0, 0.008, 0.014)]


def test_reward_uses_the_heap_states_friction(models):
  """Friction is part of the heap state x_t: the same heap at friction 0.1 gets lower parallel-jaw rewards
  than at 0.9, draw for draw (same keys)."""
  grasps = jax.tree.map(lambda *xs: jnp.stack(xs), *_off_centre_jaws())
  entries = [(CUBE, (0.0, 0.0, 0.02), IDENTITY), (CUBE, (-0.12, 0.12, 0.02), IDENTITY)]
  scenes = {mu: jax.tree.map(lambda x: jnp.broadcast_to(x, (len(_off_centre_jaws()),) + x.shape),
                             _scene(models, entries, friction=mu)) for mu in (0.1, 0.9)}
  low, high = (_batched_reward(KEY, grasps, scenes[mu], BIN) for mu in (0.1, 0.9))
  assert np.all(np.asarray(low.target_slot) == 0) and np.all(np.asarray(high.target_slot) == 0)
  p_low, p_high = np.asarray(low.robust_probability), np.asarray(high.robust_probability)
  assert np.all(p_low <= p_high) and p_low.mean() < p_high.mean() - 0.2, (p_low, p_high)
  assert int(np.sum(low.reward)) < int(np.sum(high.reward))


def test_reward_draws_only_mass_pose_and_disturbance(models):
  """Two rewards of one state differ only through the mass, gripper-pose and eps_w draws: with those three
  switched off, every key gives the same outcome in every sample, equal to the deterministic quality at the
  state's friction, world gravity and the mean mass."""
  scene = _scene(models, [(CUBE, (0.0, 0.0, 0.02), IDENTITY)], friction=0.35)
  quiet = parallel_jaw_perturbations().replace(mass_variance=1e-9, position_sigma=0.0, disturbance_sigma=0.0)
  reward = jax.jit(lambda k, g: heap_grasp_reward(k, g, scene, BIN, perturbations=quiet).robust_probability)
  for grasp in _off_centre_jaws():
    probs = {float(reward(jax.random.key(seed), grasp)) for seed in range(4)}
    assert len(probs) == 1 and probs <= {0.0, 1.0}, probs
    nominal = parallel_jaw_quality(models[CUBE], grasp.replace(center=grasp.center - jnp.array([0.0, 0.0, 0.02])),
                                   ParallelJawGripper(),
                                   Conditions(mass=jnp.float32(0.25), friction=jnp.float32(0.35),
                                              gravity=jnp.asarray(DOWN, jnp.float32),
                                              disturbance=jnp.zeros(6, jnp.float32)))
    assert probs == {float(nominal.resists)}
  # And the state's friction is what every draw sees, while mass and disturbance still vary.
  draws = jax.vmap(lambda k: sample_conditions(k, with_known_friction(parallel_jaw_perturbations(), 0.35),
                                               jnp.asarray(DOWN)))(jax.random.split(KEY, 64))
  np.testing.assert_array_equal(np.asarray(draws.friction), np.float32(0.35))
  assert np.std(np.asarray(draws.mass)) > 0.05 and np.std(np.asarray(draws.disturbance)) > 0.005


def test_a_neighbours_load_weighs_like_extra_mass_in_the_objects_frame(models):
  """``HeapScene.loads`` (world frame) reaches every draw in the target's frame: a cube lying on its side (its
  frame turned 90 degrees about x) with a known 0.1 kg and a downward load of 0.3 kg's weight at its centre of mass
  scores draw for draw as the same cube of 0.4 kg; without the load it scores higher."""
  quarter = (np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0)
  grasps = jax.tree.map(lambda *xs: jnp.stack(xs), *_off_centre_jaws())
  n = len(_off_centre_jaws())
  base = _scene(models, [(CUBE, (0.0, 0.0, 0.02), quarter), (CUBE, (-0.12, 0.12, 0.02), IDENTITY)], friction=0.5)
  g = 9.81
  loads = jnp.zeros((P, 6), jnp.float32).at[0, 2].set(-0.3 * g)
  mass = lambda m: jnp.full(P, m, jnp.float32)
  batch = lambda scene: _batched_reward(KEY, grasps, jax.tree.map(lambda x: jnp.broadcast_to(x, (n,) + x.shape),
                                                                  scene), BIN)
  from dexjax.quality.grasp_quality import QualityConfig
  assert QualityConfig().gravity_acceleration == pytest.approx(g, abs=1e-3)
  base = base.replace(mass_known=True)
  loaded, heavy = batch(base.replace(mass=mass(0.1), loads=loads)), batch(base.replace(mass=mass(0.4), loads=loads * 0))
  light = batch(base.replace(mass=mass(0.1), loads=loads * 0))
  np.testing.assert_allclose(np.asarray(loaded.robust_probability), np.asarray(heavy.robust_probability), atol=1e-6)
  assert np.asarray(light.robust_probability).sum() > np.asarray(loaded.robust_probability).sum() + 1.0
  # The same load pushing up (a support, which `resting_loads` never reports) would lighten it instead.
  lifted = batch(base.replace(mass=mass(0.4), loads=-loads))
  np.testing.assert_allclose(np.asarray(lifted.robust_probability), np.asarray(light.robust_probability), atol=1e-6)


def test_the_labels_draw_each_objects_mass_about_its_own(models):
  """Labels version 8: a scene with masses draws each object's mass from the Gamma law of mean its own mass and the
  seed's relative spread (variance / mean^2 = 0.05 / 0.25^2 = 0.8; SciPy's Gamma as the reference); the same keys
  give the prior's draws scaled by mass / 0.25 (one shape, 1.25), so at 0.25 kg the law is the prior's, draw for
  draw; a 50 g cube scores higher than under the prior, and ``mass_known`` fixes the mass instead."""
  import scipy.stats
  prior = parallel_jaw_perturbations()
  draws = lambda p: np.asarray(jax.vmap(lambda k: sample_conditions(k, p, jnp.asarray(DOWN)).mass)(
      jax.random.split(KEY, 4000)))
  light = draws(with_object_mass(prior, 0.05))
  assert scipy.stats.kstest(light, scipy.stats.gamma(a=1.25, scale=0.8 * 0.05).cdf).pvalue > 0.01
  assert light.mean() == pytest.approx(0.05, rel=0.05) and light.var() == pytest.approx(0.8 * 0.05**2, rel=0.15)
  np.testing.assert_allclose(light, draws(prior) * 0.2, rtol=1e-5)

  grasps = jax.tree.map(lambda *xs: jnp.stack(xs), *_off_centre_jaws())
  n = len(_off_centre_jaws())
  base = _scene(models, [(CUBE, (0.0, 0.0, 0.02), IDENTITY), (CUBE, (-0.12, 0.12, 0.02), IDENTITY)], friction=0.5)
  batch = lambda scene: np.asarray(_batched_reward(
      KEY, grasps, jax.tree.map(lambda x: jnp.broadcast_to(x, (n,) + x.shape), scene), BIN).robust_probability)
  mass = lambda m: jnp.full(P, m, jnp.float32)
  seed = batch(base)
  np.testing.assert_array_equal(batch(base.replace(mass=mass(0.25))), seed)
  drawn = batch(base.replace(mass=mass(0.05)))
  assert np.all(drawn >= seed) and drawn.sum() > seed.sum() + 1.0, (drawn, seed)
  assert batch(base.replace(mass=mass(0.05), mass_known=True)).sum() >= drawn.sum()


def test_boxes_overlap_matches_a_dense_point_test():
  """The separating-axis overlap of an oriented and an axis-aligned box against a brute-force reference: a dense
  lattice of the oriented box tested for inclusion in the other (a lattice point inside proves overlap; none
  inside with a 1 mm lattice and boxes apart by more than the lattice diagonal proves none)."""
  from dexjax.quality.heap_reward import boxes_overlap
  from scipy.spatial.transform import Rotation
  rng = np.random.default_rng(4)
  agree = decided = 0
  for _ in range(60):
    rot = Rotation.random(random_state=rng).as_matrix()
    half_a, half_b = rng.uniform(0.005, 0.03, 3), rng.uniform(0.005, 0.03, 3)
    centre_a, centre_b = rng.uniform(-0.05, 0.05, 3), np.zeros(3)
    axes = [np.linspace(-h, h, max(2, int(2 * h / 0.001) + 1)) for h in half_a]
    lattice = np.stack(np.meshgrid(*axes, indexing='ij'), -1).reshape(-1, 3) @ rot.T + centre_a
    inside = np.all(np.abs(lattice - centre_b) <= half_b, axis=1).any()
    got = bool(boxes_overlap(jnp.asarray(centre_a, jnp.float32), jnp.asarray(rot, jnp.float32),
                             jnp.asarray(half_a, jnp.float32), jnp.asarray(centre_b, jnp.float32),
                             jnp.asarray(half_b, jnp.float32)))
    if inside:
      assert got
      decided += 1
    elif not got:
      decided += 1
    agree += got == inside
  assert decided >= 50 and agree >= 57  # the lattice misses only overlaps thinner than its 1 mm spacing
