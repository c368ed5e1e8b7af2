"""The supervisor's lift test on hand-built heaps of built-in cubes (4 cm, exact answers from the boxes' geometry)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dexjax.bench.lift_clearance import (LIFT_HEIGHT, LIFT_STEP, LIFT_TOLERANCE, WALL_CONTACT, WALL_TILT,
                                         lift_clearance, slots_clear_to_lift, wall_gaps, wall_hold_risk)
from dexjax.quality.heap_reward import HeapScene, stack_models
from dexjax.sim.heap import Bin

P = 6
IDENTITY = (1.0, 0.0, 0.0, 0.0)
_clearance = jax.jit(jax.vmap(lift_clearance, in_axes=(None, 0)))
_clear = jax.jit(slots_clear_to_lift)


@pytest.fixture(scope='module')
def cube(tmp_path_factory):
  from dexjax.objects import load_object_model  # pylint: disable=g-import-not-at-top
  return load_object_model('builtin:cube', cache_dir=tmp_path_factory.mktemp('lift_cache'), grid_size=48)


def _scene(cube, positions):
  mask = np.zeros(P, bool)
  mask[:len(positions)] = True
  poses = np.tile(np.array([0, 0, 0, *IDENTITY], np.float32), (P, 1))
  poses[:len(positions), :3] = positions
  return HeapScene(models=stack_models([cube]), object_ids=jnp.zeros(P, jnp.int32), mask=jnp.asarray(mask),
                   poses=jnp.asarray(poses), friction=jnp.full(P, 0.8, jnp.float32))


def test_a_cube_under_another_is_blocked_and_the_one_on_top_and_one_beside_are_clear(cube):
  scene = _scene(cube, [(0.0, 0.0, 0.02), (0.01, 0.0, 0.06), (0.1, 0.0, 0.02), (0.14, 0.0, 0.02)])
  got = np.asarray(_clearance(scene, jnp.arange(P)))
  assert got[0] == 0.0  # the cube on it is entered by a full step at the first raise
  np.testing.assert_allclose(got[1:4], LIFT_HEIGHT, atol=1e-6)  # on top; beside (touching) in both directions
  assert np.asarray(_clear(scene)).tolist() == [False, True, True, True, False, False]


@pytest.mark.parametrize('gap', [0.012, 0.021])
def test_the_clearance_under_an_overhang_is_the_gap(cube, gap):
  """A cube under another raised ``gap`` above it (held there, as by a neighbour's overhang): the exact answer is the
  largest multiple of the step up to which the raised top face stays within the tolerance of the upper cube (gaps
  at least 1 mm from a step's boundary: the grids are exact to a fraction of a millimetre)."""
  scene = _scene(cube, [(0.0, 0.0, 0.02), (0.02, 0.0, 0.06 + gap)])
  got = float(_clearance(scene, jnp.arange(P))[0])
  expected = LIFT_STEP * np.floor((gap + LIFT_TOLERANCE) / LIFT_STEP)
  assert abs(got - expected) < 1e-6, (got, expected)


def test_wall_gaps_are_the_cubes_distances_to_the_walls(cube):
  """4 cm cubes in a 0.4 m bin: the gap is 0.2 m - |centre| - 2 cm along the nearer axis (area-uniform samples
  cover every face of the cube to within a millimetre of its edges); empty slots are infinitely far."""
  positions = [(0.0, 0.0, 0.02), (0.178, 0.05, 0.02), (-0.05, -0.1805, 0.02)]
  got = np.asarray(jax.jit(wall_gaps)(_scene(cube, positions), Bin()))
  expected = [0.18, 0.002, 0.0]
  np.testing.assert_allclose(got[:3], expected, atol=1.5e-3)
  assert np.all(np.isinf(got[3:]))


def test_wall_hold_risk_is_a_tilted_cup_on_an_object_touching_a_wall():
  tilted = lambda a: jnp.asarray([np.sin(a), 0.0, -np.cos(a)], jnp.float32)  # approach into the surface
  near, far = jnp.float32(0.5 * WALL_CONTACT), jnp.float32(2 * WALL_CONTACT)
  assert bool(wall_hold_risk(tilted(WALL_TILT + 0.05), near))
  assert not bool(wall_hold_risk(tilted(WALL_TILT - 0.05), near))  # a cup near vertical beside a wall holds
  assert not bool(wall_hold_risk(tilted(0.6), far))
  assert bool(wall_hold_risk(3.0 * tilted(0.3), near))  # the direction's length does not matter
