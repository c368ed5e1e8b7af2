"""Settling heaps: resting, inside the bin or flagged, no interpenetration, determinism, both backends agree."""

from __future__ import annotations

import itertools
import os

import jax
import mujoco
import numpy as np
import pytest

import dexjax.sim as sim
from dexjax.objects import builtin_mesh

PENETRATION_TOL = 0.003  # metres: MuJoCo's soft contacts rest a fraction of a millimetre deep


def _box_corners(lo, hi) -> np.ndarray:
  return np.array(list(itertools.product(*zip(lo, hi))), float)


def _l_shape_hulls(mesh) -> tuple[np.ndarray, np.ndarray]:
  """The built-in L as its two boxes: the foot (8 x 4 x 2 cm, along x) and the upright (2 x 4 x 8 cm at +x)."""
  lo, hi = mesh.bounds
  foot = _box_corners(lo, [lo[0] + 0.08, hi[1], lo[2] + 0.02])
  upright = _box_corners([hi[0] - 0.02, lo[1], lo[2]], hi)
  return foot, upright


def _objects() -> list[sim.HeapObject]:
  objects = []
  for name in ("cube", "box", "cylinder", "sphere", "l_shape", "box_with_hole"):
    mesh = builtin_mesh(name)
    hulls = _l_shape_hulls(mesh) if name == "l_shape" else None  # others: their convex hull
    objects.append(sim.heap_object(mesh, hulls, name=name))
  return objects


@pytest.fixture(scope="module")
def objects():
  return _objects() * 2  # 12 available objects (heaps hold up to 10)


def _sample(seed: int, num_heaps: int, num_available: int):
  keys = jax.random.split(jax.random.key(seed), num_heaps)
  return jax.jit(jax.vmap(lambda k: sim.sample_heap_state(k, num_available)))(keys)


@pytest.fixture(scope="module")
def states(objects):
  return _sample(0, 16, len(objects))


@pytest.fixture(scope="module")
def settled(objects, states):
  return sim.settle(objects, states, backend="rollout")


def _min_contact_distance(objects, state, poses) -> float:
  """Smallest signed contact distance (negative: penetration) of a heap at ``poses`` (P, 7), C engine."""
  model = sim.build_heap_model(objects, state)
  data = mujoco.MjData(model)
  data.qpos[:] = poses[sim.heap_slots(state)].reshape(-1)
  mujoco.mj_forward(model, data)
  return float(data.contact.dist[:data.ncon].min()) if data.ncon else np.inf


def test_l_shape_hulls_cover_the_mesh():
  mesh = builtin_mesh("l_shape")
  foot, upright = _l_shape_hulls(mesh)
  inside = lambda h, p: np.all((p >= h.min(0) - 1e-9) & (p <= h.max(0) + 1e-9), axis=1)
  assert np.all(inside(foot, mesh.vertices) | inside(upright, mesh.vertices))
  assert foot.shape == upright.shape == (8, 3)


def test_heaps_rest_inside_the_bin_or_are_flagged(objects, states, settled):
  r = settled
  s = sim.SettleSettings()
  assert r.backend == "rollout" and r.poses.shape == (16, 10, 7) and r.velocities.shape == (16, 10, 6)
  np.testing.assert_array_equal(r.mask, np.asarray(states.mask))
  assert np.all(r.steps >= 1) and np.all(r.steps <= s.max_steps)
  assert not r.diverged.any()
  speed = np.linalg.norm(r.velocities[..., :3], axis=-1)
  spin = np.linalg.norm(r.velocities[..., 3:], axis=-1)
  resting = (speed < s.linear_speed_tol) & (spin < s.angular_speed_tol)
  np.testing.assert_array_equal(r.never_settled, r.mask & ~resting)  # every object rests or is flagged
  np.testing.assert_array_equal(r.settled, ~r.never_settled.any(axis=1))
  assert np.all(r.steps[~r.settled] == s.max_steps)
  # Left the bin: exactly the objects whose centre of mass is outside the 0.4 x 0.4 m inner box or below z = 0.
  c = r.centers
  outside = (np.abs(c[..., 0]) > 0.2) | (np.abs(c[..., 1]) > 0.2) | (c[..., 2] < 0)
  np.testing.assert_array_equal(r.left_bin, r.mask & outside)
  assert r.left_bin.sum() <= 1  # drops are >= 7.5 cm inside the walls
  assert r.settled.mean() >= 0.6, r.settled  # rolling spheres and cylinders may stay flagged
  # Resting objects lie on something: no centre of mass floats above a 3-high stack of the largest objects.
  assert np.all(c[r.mask & ~r.never_settled][:, 2] < 0.25)
  # Padded slots are identity poses.
  assert np.all(r.poses[~r.mask] == [0, 0, 0, 1, 0, 0, 0])


def test_no_interpenetration(objects, states, settled):
  for b in range(16):
    state = sim.select_heap(states, b)
    assert _min_contact_distance(objects, state, settled.poses[b]) > -PENETRATION_TOL
    # The drop poses themselves are collision-free (intersecting drops are raised).
    assert _min_contact_distance(objects, state, settled.initial_poses[b]) == np.inf


def test_same_seed_same_heap_bitwise(objects, settled):
  again = _sample(0, 16, len(objects))
  # Different thread count and chunking: each heap is simulated alone and the warm start is carried over.
  settings = sim.SettleSettings(nthread=1, chunk_steps=7)
  r = sim.settle(objects, again, backend="rollout", settings=settings)
  for field in ("poses", "centers", "velocities", "steps", "left_bin", "never_settled", "settled"):
    np.testing.assert_array_equal(getattr(r, field), getattr(settled, field), err_msg=field)


def test_first_rest_screening_gives_the_resting_test_s_answer():
  """The settling loop screens steps with a necessary condition before the exact resting test; the first resting
  step must be the plain test's on trajectories hovering at the thresholds, including objects spinning about an
  off-origin centre of mass (a fast frame origin, a resting centre)."""
  from dexjax.sim.settling import _first_rest, resting, rotate  # pylint: disable=import-outside-toplevel
  settings = sim.SettleSettings()
  rng = np.random.default_rng(0)
  found = 0
  for trial in range(300):
    n, m = 50, int(rng.integers(1, 6))
    coms = rng.normal(0, 0.03, (m, 3))
    quat = rng.normal(size=(n, m, 4))
    quat /= np.linalg.norm(quat, axis=-1, keepdims=True)
    qpos = np.concatenate([rng.normal(0, 0.1, (n, m, 3)), quat], axis=-1)
    omega = rng.normal(0, 0.06 * (trial % 3 + 1) / 2, (n, m, 3))
    # the origin's velocity cancels the spin's at the centre of mass, up to a small remainder
    spin = rotate(quat, np.cross(omega, coms))
    v = -spin + rng.normal(0, 0.003 * (trial % 4 + 1) / 2, (n, m, 3))
    qvel = np.concatenate([v, omega], axis=-1)
    rest = np.all(resting(qpos, qvel, coms, settings), axis=1)
    expected = int(np.argmax(rest)) if rest.any() else -1
    assert _first_rest(qpos, qvel, coms, settings) == expected, trial
    found += expected >= 0
  assert 30 < found < 270  # both answers occur often


def test_sleeping_objects_move_heaps_by_micrometres_and_keep_them_valid(objects, states, settled):
  """The default lets resting objects sleep (the C engine skips them until a moving body touches them); without it
  every object is simulated to the end. Both give valid heaps, nearly the same; sleeping changes the trajectories
  (so the flag is in effect), not the chunking invariance above."""
  assert sim.build_heap_model(objects, sim.select_heap(states, 0)).opt.enableflags & mujoco.mjtEnableBit.mjENBL_SLEEP
  awake_settings = sim.SettleSettings(sleep=False)
  assert not sim.build_heap_model(objects, sim.select_heap(states, 0), awake_settings).opt.enableflags
  awake = sim.settle(objects, states, backend="rollout", settings=awake_settings)
  assert not np.array_equal(awake.poses, settled.poses)
  for r in (awake, settled):
    assert not r.diverged.any() and r.left_bin.sum() <= 1 and r.settled.mean() >= 0.6
  assert abs(int(awake.never_settled.sum()) - int(settled.never_settled.sum())) <= 2
  shift = np.linalg.norm(awake.centers - settled.centers, axis=-1)[settled.mask & ~settled.never_settled
                                                                     & ~awake.never_settled]
  assert np.median(shift) < 1e-4, np.median(shift)  # metres: a tenth of a millimetre
  np.testing.assert_allclose(awake.steps, settled.steps, atol=0.1 * sim.SettleSettings().max_steps)


def test_object_dropped_outside_is_flagged(objects):
  cube, box = 0, 1
  state = sim.HeapState(
      object_ids=np.array([cube, box, cube + 6, -1], np.int32), mask=np.array([True, True, True, False]),
      positions=np.array([[0.0, 0.0, 0.15], [0.05, 0.1, 0.15], [0.3, 0.0, 0.15], [0, 0, 0]], np.float32),
      quaternions=np.tile(np.array([1, 0, 0, 0], np.float32), (4, 1)),
      friction=np.array([0.8, 0.8, 0.8, 0.0], np.float32))
  r = sim.settle(objects, state)  # a single heap (B = 1), backend 'auto'
  assert r.backend == "rollout" and r.poses.shape == (1, 4, 7)
  np.testing.assert_array_equal(r.left_bin[0], [False, False, True, False])
  assert r.settled[0]  # the outside cube rests on the ground plane beside the bin
  np.testing.assert_allclose(r.centers[0, 2, 2], 0.02, atol=PENETRATION_TOL)
  np.testing.assert_allclose(r.centers[0, 0, 2], 0.02, atol=PENETRATION_TOL)


def test_thin_discs_do_not_tunnel_through_the_floor():
  """6 mm discs (a thin user mesh; the procedural L1 disc family of earlier versions) dropped at random orientations
  all rest on the floor."""
  import trimesh
  disc = sim.heap_object(trimesh.creation.cylinder(radius=0.021, height=0.006, sections=32), name="disc")
  states = _sample(3, 8, 10)
  r = sim.settle([disc] * 10, states, backend="rollout")
  assert not r.left_bin.any() and r.settled.all()
  z = r.centers[..., 2][r.mask]
  assert z.min() > 0.003 - PENETRATION_TOL and z.max() < 0.05  # flat on the floor or on each other, not below


def test_never_settled_flags_and_errors(objects, states):
  few = jax.tree.map(lambda x: np.asarray(x)[:3], states)
  r = sim.settle(objects, few, backend="rollout", settings=sim.SettleSettings(max_steps=20))
  assert np.all(r.steps == 20) and not r.settled.any()
  np.testing.assert_array_equal(r.never_settled, r.mask)  # still falling: flagged, not dropped
  assert np.all(r.poses[r.mask][:, 2] > 0.05)
  with pytest.raises(ValueError, match="backend"):
    sim.settle(objects, few, backend="bullet")
  with pytest.raises(ValueError, match=r"object_ids.*\[0, 5\)"):
    sim.settle(objects[:5], few)


def test_auto_backend_is_rollout_on_cpu():
  assert jax.default_backend() != "cpu" or sim.default_backend() == "rollout"


def test_mjx_timeout_is_reported_not_hung(objects, states):
  few = jax.tree.map(lambda x: np.asarray(x)[:1], states)
  with pytest.raises(sim.SettleTimeout, match="mjx_timeout"):
    sim.settle(objects, few, backend="mjx", settings=sim.SettleSettings(mjx_timeout=0.5, mjx_subprocess=True))


@pytest.mark.slow
def test_mjx_and_rollout_agree():
  """Tiny MJX batch (3 primitive objects, 4 heaps) in the pinned child process; compiles for ~30-60 s."""
  objects = [sim.heap_object(builtin_mesh(n), name=n) for n in ("cube", "box", "box_with_hole")]
  dist = sim.HeapDistribution(min_count=3, max_count=3)
  states = jax.vmap(lambda k: sim.sample_heap_state(k, 3, dist))(jax.random.split(jax.random.key(3), 4))
  settings = sim.SettleSettings(mjx_timeout=float(os.environ.get("DEXJAX_TEST_MJX_TIMEOUT", 600)))
  m = sim.settle(objects, states, backend="mjx", settings=settings)
  c = sim.settle(objects, states, backend="rollout", settings=settings)
  assert m.backend == "mjx" and m.poses.shape == c.poses.shape == (4, 3, 7)
  for r in (m, c):
    assert r.settled.all() and not r.left_bin.any() and not r.diverged.any()
    assert np.all(np.linalg.norm(r.velocities[..., :3], axis=-1) < settings.linear_speed_tol)
  for b in range(4):
    assert _min_contact_distance(objects, sim.select_heap(states, b), m.poses[b]) > -PENETRATION_TOL
  # Same statistics of the resting heaps. Each object rests on one of its faces (centre 2, 3 or 4 cm high, more
  # when stacked), and which face is chaotic, so compare means with a 3-standard-error tolerance of the
  # difference of two 12-object samples, and both at least the lowest possible resting height.
  hm, hc = m.centers[..., 2].ravel(), c.centers[..., 2].ravel()
  tol = 3 * np.sqrt(hm.var(ddof=1) / hm.size + hc.var(ddof=1) / hc.size) + 1e-3
  assert abs(hm.mean() - hc.mean()) < tol, (hm, hc, tol)
  assert hm.min() > 0.02 - PENETRATION_TOL and hc.min() > 0.02 - PENETRATION_TOL
  # Both stop at comparable times (same stopping rule, float32 vs float64 trajectories diverge chaotically).
  assert abs(np.median(m.steps) - np.median(c.steps)) < 150, (m.steps, c.steps)


def test_with_convex_decomposition_hulls():
  """Heaps built from `dexjax.objects.collision.collision_hulls` (V-HACD convex decompositions)."""
  from dexjax.objects import collision
  objects = []
  for name in ("l_shape", "box_with_hole", "cube"):
    mesh = builtin_mesh(name)
    hulls = collision.collision_hulls(mesh, max_hulls=8, max_vertices=64)
    assert 1 <= len(hulls) <= 8 and all(len(h) <= 64 for h in hulls)
    objects.append(sim.heap_object(mesh, hulls, name=name))
  state = _sample(4, 4, 3)
  r = sim.settle(objects, state, backend="rollout")
  assert not r.diverged.any() and not r.left_bin.any()
  for b in range(4):
    assert _min_contact_distance(objects, sim.select_heap(state, b), r.poses[b]) > -PENETRATION_TOL


def test_resettling_from_rest_keeps_the_heap_and_a_removed_support_lets_objects_fall(objects, states, settled):
  """``start_poses``: a settled heap started again from its poses stays put; with its lowest supporting object
  removed, what rested on it falls to a new rest."""
  b = int(np.flatnonzero(settled.settled & (states.mask.sum(1) >= 5))[0])
  state = sim.select_heap(states, b)
  again = sim.settle(objects, state, backend="rollout", start_poses=settled.poses[b])
  mask = settled.mask[b]
  assert again.settled[0] and again.steps[0] < 50
  np.testing.assert_allclose(again.centers[0][mask], settled.centers[b][mask], atol=2e-3)
  np.testing.assert_allclose(again.initial_poses[0][mask], settled.poses[b][mask], atol=1e-9)
  # A cube stacked on a cube: with the bottom one removed, the top one falls to where the bottom one rested.
  stack = sim.select_heap(states, 0).replace(
      object_ids=np.array([0, 6] + [0] * 8, np.int32), mask=np.array([True, True] + [False] * 8),
      positions=np.array([[0.0, 0.0, 0.1], [0.0, 0.0, 0.25]] + [[0.0, 0.0, 0.0]] * 8, np.float32),
      quaternions=np.tile(np.array([1.0, 0.0, 0.0, 0.0], np.float32), (10, 1)))
  stacked = sim.settle(objects, stack, backend="rollout")
  bottom_z, top_z = stacked.centers[0, 0, 2], stacked.centers[0, 1, 2]
  assert stacked.settled[0] and top_z > 1.8 * bottom_z
  fallen = sim.settle(objects, stack.replace(mask=np.array([False, True] + [False] * 8)), backend="rollout",
                      start_poses=stacked.poses[0])
  assert fallen.settled[0] and not fallen.mask[0, 0]
  np.testing.assert_allclose(fallen.centers[0, 1], stacked.centers[0, 0], atol=5e-3)
  with pytest.raises(ValueError, match=r"start_poses: expected shape \(1, 10, 7\)"):
    sim.settle(objects, state, backend="rollout", start_poses=settled.poses[b][:3])
  with pytest.raises(ValueError, match="'rollout' backend only"):
    sim.settle(objects, state, backend="mjx", start_poses=settled.poses[b])
