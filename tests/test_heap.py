"""Heap state distribution (seed, "State Distribution") and heap objects: statistics against exact references."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats
import trimesh

import dexjax.sim as sim
from dexjax.objects import builtin_mesh
from dexjax.sim.scene import quat_to_matrix

NUM_DRAWS = 20_000


@pytest.fixture(scope="module")
def draws():
  """20k heaps from 50 available objects (jit + vmap)."""
  keys = jax.random.split(jax.random.key(0), NUM_DRAWS)
  states = jax.jit(jax.vmap(lambda k: sim.sample_heap_state(k, 50)))(keys)
  return jax.tree.map(np.asarray, states)


def test_truncated_poisson_pmf_matches_scipy():
  k = np.arange(3, 11)
  ref = scipy.stats.poisson.pmf(k, 5.0)
  np.testing.assert_allclose(sim.truncated_poisson_pmf(5.0, 3, 10), ref / ref.sum(), rtol=1e-12)


def test_count_distribution(draws):
  counts = draws.mask.sum(axis=1)
  assert counts.min() >= 3 and counts.max() <= 10
  pmf = sim.truncated_poisson_pmf(5.0, 3, 10)
  observed = np.bincount(counts, minlength=11)[3:11]
  _, p = scipy.stats.chisquare(observed, pmf * NUM_DRAWS)
  assert p > 1e-3, (observed, pmf * NUM_DRAWS)
  k = np.arange(3, 11)
  mean, var = (pmf * k).sum(), (pmf * k**2).sum() - (pmf * k).sum()**2
  assert abs(counts.mean() - mean) < 4 * np.sqrt(var / NUM_DRAWS)
  assert abs(counts.var() - var) < 0.05 * var
  # Conditioning, not clipping: clipping would put P(X <= 3) = 0.265 on m = 3; conditioning gives 0.162.
  assert abs(observed[0] / NUM_DRAWS - pmf[0]) < 0.01


def test_clipped_count_option():
  dist = sim.HeapDistribution(count_truncation="clip")
  keys = jax.random.split(jax.random.key(5), NUM_DRAWS)
  counts = np.asarray(jax.jit(jax.vmap(lambda k: sim.sample_object_count(k, 50, dist)))(keys))
  pmf = scipy.stats.poisson.pmf(np.arange(3, 11), 5.0)
  pmf[0], pmf[-1] = scipy.stats.poisson.cdf(3, 5.0), scipy.stats.poisson.sf(9, 5.0)  # tails piled on 3 and 10
  _, p = scipy.stats.chisquare(np.bincount(counts, minlength=11)[3:11], pmf * NUM_DRAWS)
  assert p > 1e-3
  with pytest.raises(ValueError, match="count_truncation"):
    sim.sample_object_count(keys[0], 50, sim.HeapDistribution(count_truncation="reject"))


def test_uniform_count_option_covers_every_count_of_an_emptied_bin():
  """count_law='uniform': each count of [1, 25] equally likely (chi-square), padded to 25 slots, the bound capped
  by the available objects; an unknown law is named."""
  dist = sim.HeapDistribution(count_law="uniform", min_count=1, max_count=25)
  keys = jax.random.split(jax.random.key(6), NUM_DRAWS)
  counts = np.asarray(jax.jit(jax.vmap(lambda k: sim.sample_object_count(k, 50, dist)))(keys))
  observed = np.bincount(counts, minlength=26)
  assert observed[0] == 0 and observed[1:].min() > 0
  _, p = scipy.stats.chisquare(observed[1:])
  assert p > 1e-3, observed
  states = jax.vmap(lambda k: sim.sample_heap_state(k, 50, dist))(keys[:200])
  assert states.mask.shape == (200, 25) and int(states.num_objects.max()) > 20
  capped = np.asarray(jax.vmap(lambda k: sim.sample_object_count(k, 12, dist))(keys[:2000]))
  assert capped.min() == 1 and capped.max() == 12
  with pytest.raises(ValueError, match="count_law"):
    sim.sample_object_count(keys[0], 50, sim.HeapDistribution(count_law="binomial"))


def test_ids_without_replacement_and_padding(draws):
  for ids, mask in zip(draws.object_ids[:2000], draws.mask[:2000]):
    m = mask.sum()
    assert mask[:m].all() and not mask[m:].any()  # objects fill the first m slots
    assert len(set(ids[:m].tolist())) == m and ids[:m].min() >= 0 and ids[:m].max() < 50
    assert (ids[m:] == -1).all()
  # Every id is equally likely.
  hist = np.bincount(draws.object_ids[draws.mask], minlength=50)
  _, p = scipy.stats.chisquare(hist)
  assert p > 1e-3


def test_few_available_objects_caps_the_count():
  keys = jax.random.split(jax.random.key(1), 2000)
  states = jax.jit(jax.vmap(lambda k: sim.sample_heap_state(k, 4)))(keys)
  counts = np.asarray(states.mask.sum(axis=1))
  assert set(counts.tolist()) == {3, 4}
  for ids, mask in zip(np.asarray(states.object_ids)[:200], np.asarray(states.mask)[:200]):
    assert sorted(ids[mask].tolist()) == sorted(set(ids[mask].tolist()))
  with pytest.raises(ValueError, match="num_available"):
    sim.sample_heap_state(jax.random.key(0), 2)
  with pytest.raises(ValueError, match="num_available"):
    sim.sample_heap_state(jax.random.key(0), jnp.int32(5))


def test_orientations_uniform_on_so3(draws):
  q = draws.quaternions[draws.mask]
  np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-5)
  rot = quat_to_matrix(q)
  n = len(q)
  # Each rotated axis is uniform on the sphere: mean 0, E[x x^T] = I / 3.
  for axis in range(3):
    v = rot[:, :, axis]
    assert np.abs(v.mean(axis=0)).max() < 5 / np.sqrt(3 * n)
    np.testing.assert_allclose(v.T @ v / n, np.eye(3) / 3, atol=0.02)
  # Haar measure: E[tr R] = 0, E[tr R^2] = 1; rotation angle density (1 - cos t) / pi.
  tr = np.trace(rot, axis1=1, axis2=2)
  assert abs(tr.mean()) < 5 / np.sqrt(n)
  assert abs((tr**2).mean() - 1.0) < 0.05
  angle = np.arccos(np.clip((tr - 1) / 2, -1, 1))
  cdf = lambda t: (t - np.sin(t)) / np.pi
  assert scipy.stats.kstest(angle, cdf).pvalue > 1e-3


def test_positions_uniform_in_drop_square(draws):
  p = draws.positions[draws.mask]
  assert np.all(np.abs(p[:, :2]) <= 0.125) and np.all(p[:, 2] == np.float32(0.15))
  for c in range(2):
    assert scipy.stats.kstest(p[:, c], scipy.stats.uniform(-0.125, 0.25).cdf).pvalue > 1e-3
  pad = ~draws.mask
  assert np.all(draws.positions[pad] == 0) and np.all(draws.quaternions[pad] == [1, 0, 0, 0])


def test_friction_truncated_gaussian(draws):
  mu = draws.friction[draws.mask]
  assert mu.min() >= 0 and mu.max() <= 1
  ref = scipy.stats.truncnorm((0 - 0.8) / 0.1, (1 - 0.8) / 0.1, loc=0.8, scale=0.1)
  assert scipy.stats.kstest(mu, ref.cdf).pvalue > 1e-3
  assert np.all(draws.friction[~draws.mask] == 0)


def test_same_key_same_state_and_custom_distribution():
  dist = sim.HeapDistribution(count_mean=2.0, min_count=2, max_count=4, drop_half_width=0.05,
                              drop_center=(0.1, -0.1), drop_height=0.3)
  a = sim.sample_heap_state(jax.random.key(7), 10, dist)
  b = jax.jit(sim.sample_heap_state, static_argnums=1)(jax.random.key(7), 10, dist)
  for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):  # jit may fuse float ops differently: ulps
    np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-6, atol=1e-7)
  c = sim.sample_heap_state(jax.random.key(7), 10, dist)
  for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(c)):
    np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
  assert a.mask.shape == (4,) and 2 <= int(a.num_objects) <= 4
  p = np.asarray(a.positions)[np.asarray(a.mask)]
  assert np.all(np.abs(p[:, 0] - 0.1) <= 0.05) and np.all(np.abs(p[:, 1] + 0.1) <= 0.05)
  assert np.allclose(p[:, 2], 0.3)


def test_heap_object_mass_properties():
  mesh = builtin_mesh("box")  # 8 x 6 x 4 cm
  obj = sim.heap_object(mesh, name="box")
  volume = 0.08 * 0.06 * 0.04
  assert obj.mass == pytest.approx(500.0 * volume)
  expected = obj.mass / 12 * np.array([0.06**2 + 0.04**2, 0.08**2 + 0.04**2, 0.08**2 + 0.06**2])
  np.testing.assert_allclose(np.diag(obj.inertia), expected, rtol=1e-9)
  np.testing.assert_allclose(obj.center_of_mass, 0.0, atol=1e-12)
  assert len(obj.hulls) == 1 and obj.hulls[0].shape == (8, 3)
  heavy = sim.heap_object(mesh, density=1e6)  # 192 kg -> clipped to 2 kg, inertia scaled alike
  assert heavy.mass == 2.0
  np.testing.assert_allclose(heavy.inertia, obj.inertia * 2.0 / obj.mass, rtol=1e-9)
  # The L-shape's centre of mass is off its bounding-box centre, and comes from the mesh, not the hulls.
  l_obj = sim.heap_object(builtin_mesh("l_shape"))
  assert l_obj.center_of_mass[0] > 0.005 and l_obj.center_of_mass[2] < -0.005


def test_heap_object_uses_the_objects_own_density():
  from types import SimpleNamespace
  from dexjax.objects import procedural_mesh
  mesh = procedural_mesh(1, 0)  # A procedural box: its own density from its material
  density = mesh.metadata["density"]
  assert sim.object_density(mesh) == density and density != sim.DEFAULT_DENSITY
  obj = sim.heap_object(mesh)
  assert obj.mass == pytest.approx(density * mesh.volume, rel=1e-12)
  extents = np.sort(mesh.extents)
  expected = obj.mass / 12 * np.sort([extents[0]**2 + extents[1]**2, extents[0]**2 + extents[2]**2,
                                      extents[1]**2 + extents[2]**2])
  np.testing.assert_allclose(np.sort(np.linalg.eigvalsh(obj.inertia)), expected, rtol=1e-9)  # Uniform density.
  assert sim.heap_object(mesh, density=500.0).mass == pytest.approx(500.0 * mesh.volume)  # An explicit one wins.
  # An own density is not clipped (the generator bounds procedural masses); the default rule still is.
  light = builtin_mesh("box")  # 192 cm^3
  assert sim.object_density(light) is None
  assert sim.heap_object(light, density=20.0).mass == 0.01
  light.metadata["density"] = 20.0
  assert sim.heap_object(light).mass == pytest.approx(20.0 * 192e-6)
  assert sim.heap_object(light, mass_range=(0.01, 2.0)).mass == 0.01
  # heap_objects: each object its own rule, in order.
  prepared = [SimpleNamespace(name=n, mesh=m, hulls=(np.asarray(m.convex_hull.vertices),))
              for n, m in (("p", mesh), ("box", builtin_mesh("box")))]
  masses = [o.mass for o in sim.heap_objects(prepared)]
  assert masses == pytest.approx([density * mesh.volume, 500.0 * 192e-6])


def test_heap_object_rejects_bad_input():
  mesh = builtin_mesh("cube")
  with pytest.raises(ValueError, match=r"hulls\[0\].*4 non-coplanar"):
    sim.heap_object(mesh, [np.zeros((3, 3))])
  flat = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0.5, 0.5, 0]], float)
  with pytest.raises(ValueError, match="non-coplanar"):
    sim.heap_object(mesh, [flat])
  with pytest.raises(ValueError, match=r"\(V, 3\)"):
    sim.heap_object(mesh, [np.zeros((5, 2))])
  with pytest.raises(ValueError, match="density"):
    sim.heap_object(mesh, density=-1.0)
  with pytest.raises(ValueError, match="mass_range"):
    sim.heap_object(mesh, mass_range=(1.0, 0.5))
  with pytest.raises(ValueError, match="inertia"):
    sim.HeapObject(name="x", hulls=(np.asarray(trimesh.creation.box().vertices),), mass=1.0,
                   center_of_mass=np.zeros(3), inertia=-np.eye(3))


def test_settings_validation_names_the_field():
  with pytest.raises(ValueError, match=r"Bin.wall_height"):
    sim.SettleSettings(bin=sim.Bin(wall_height=0.0)).validate()
  with pytest.raises(ValueError, match=r"SettleSettings.max_steps"):
    sim.SettleSettings(max_steps=0).validate()
  with pytest.raises(ValueError, match=r"SettleSettings.timestep"):
    sim.SettleSettings(timestep=float("nan")).validate()
