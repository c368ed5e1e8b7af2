"""The supervisor's lift test on hand-built heaps of built-in cubes (4 cm, exact answers from the boxes' geometry)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dexjax.bench.lift_clearance import LIFT_HEIGHT, LIFT_STEP, LIFT_TOLERANCE, lift_clearance, slots_clear_to_lift
from dexjax.quality.heap_reward import HeapScene, stack_models

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
