"""Known answers of deterministic and robust quality, and jit / vmap / plain equivalence."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from dexjax.contacts.parallel_jaw import close_jaws
from dexjax.contacts.suction import suction_seal
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality import (FAILURE_REASONS, Conditions, nominal_conditions, parallel_jaw_perturbations,
                            parallel_jaw_quality, robust_parallel_jaw_quality, robust_suction_quality,
                            suction_perturbations, suction_quality)
from dexjax.quality.grasp_quality import bellows_margin, parallel_jaw_residual, suction_residual

PJ = ParallelJawGripper()
CUP = SuctionGripper()
DOWN = jnp.array([0.0, 0.0, -1.0])


def _pj(center, axis, approach=(0.0, 0.0, -1.0)):
  return ParallelJawGrasp(center=jnp.asarray(center, jnp.float32), axis=jnp.asarray(axis, jnp.float32) /
                          jnp.linalg.norm(jnp.asarray(axis, jnp.float32)),
                          approach=jnp.asarray(approach, jnp.float32), width=jnp.float32(0.05))


def _suction(center):
  return SuctionGrasp(center=jnp.asarray(center, jnp.float32), approach=DOWN)


_pj_quality = jax.jit(parallel_jaw_quality)
_suction_quality = jax.jit(suction_quality)
_robust_pj = jax.jit(robust_parallel_jaw_quality)
_robust_suction = jax.jit(robust_suction_quality)

CENTRED = _pj([0.0, 0.0, 0.0], [1.0, 0.0, 0.0])
# Jaws closing diagonally across the cube's vertical edge at (+2, +2) cm: each jaw meets a face at 45 degrees
# to its line of action, outside the friction cone (arctan 0.8 = 38.7 degrees).
CORNER = _pj([0.017, 0.017, 0.0], [1.0, -1.0, 0.0])


def test_centred_parallel_jaw_grasp_on_cube_resists_and_corner_grasp_does_not(cube):
  c = nominal_conditions(parallel_jaw_perturbations(), DOWN)
  good = _pj_quality(cube, CENTRED, PJ, c)
  assert bool(good.resists) and float(good.residual) < 1e-4
  bad = _pj_quality(cube, CORNER, PJ, c)
  assert not bool(bad.resists) and FAILURE_REASONS[int(bad.failure)] == "slip"
  key = jax.random.key(0)
  assert float(_robust_pj(key, cube, CENTRED, PJ).probability) >= 0.8
  assert float(_robust_pj(key, cube, CORNER, PJ).probability) <= 0.2


def test_wrench_test_runs_only_when_the_earlier_tests_pass(cube, box):
  """A draw that failed an earlier test (slip, no seal) reports residual +inf and its failure code; the wrench
  residual itself, as the smooth quality asks for it, is still finite there, and where the earlier tests pass
  the hard quality's residual is the wrench residual."""
  jaw, cup = nominal_conditions(parallel_jaw_perturbations(), DOWN), nominal_conditions(suction_perturbations(), DOWN)
  hard = {"jaw": lambda g: _pj_quality(cube, g, PJ, jaw), "cup": lambda g: _suction_quality(box, g, CUP, cup)}
  wrench_only = {"jaw": lambda g: parallel_jaw_residual(cube, close_jaws(cube, g, PJ), PJ, jaw),
                 "cup": lambda g: suction_residual(box, suction_seal(box, g, CUP), CUP, cup)}
  for gripper, grasp, failure in (("jaw", CORNER, "slip"), ("jaw", CENTRED, "none"),
                                  ("cup", _suction([0.037, 0.0, 0.02]), "no_seal"),
                                  ("cup", _suction([0.0, 0.0, 0.02]), "none")):
    out, residual = hard[gripper](grasp), float(wrench_only[gripper](grasp))
    assert FAILURE_REASONS[int(out.failure)] == failure and np.isfinite(residual)
    if failure == "none":  # The same problem (up to the rounding of a separately compiled contact search).
      np.testing.assert_allclose(float(out.residual), residual, atol=1e-5)
    else:
      assert float(out.residual) == np.inf


def test_parallel_jaw_resistance_depends_on_mass_through_the_force_limit(cube):
  # Gravity along the jaw axis must be held by one finger's normal force alone (<= 20 N): 2 kg is fine,
  # 2.5 kg (24.5 N) is not; gravity across the axis is held by friction 2 mu F = 32 N (3.2 kg).
  along = Conditions(mass=jnp.float32(1.9), friction=jnp.float32(0.8), gravity=jnp.array([1.0, 0.0, 0.0]),
                     disturbance=jnp.zeros(6))
  assert bool(_pj_quality(cube, CENTRED, PJ, along).resists)
  assert not bool(_pj_quality(cube, CENTRED, PJ, along.replace(mass=jnp.float32(2.2))).resists)
  across = along.replace(gravity=jnp.array([0.0, 0.0, -1.0]), mass=jnp.float32(3.1))
  assert bool(_pj_quality(cube, CENTRED, PJ, across).resists)
  assert not bool(_pj_quality(cube, CENTRED, PJ, across.replace(mass=jnp.float32(3.4))).resists)


def test_suction_object_above_the_cup_tips_over_on_the_bellows(box):
  # The cup under the box's bottom face pushing up (approach +z): the centre of mass stands h = 2 cm + half the
  # 1 cm cone above the bellows' pivot, an inverted pendulum stable iff k > m g h: m < 0.05 / (9.81 x 0.025)
  # = 0.204 kg. Hanging from the top face, the same box never tips.
  below = SuctionGrasp(center=jnp.array([0.0, 0.0, -0.02]), approach=jnp.array([0.0, 0.0, 1.0]))
  c = Conditions(mass=jnp.float32(0.19), friction=jnp.float32(0.8), gravity=DOWN, disturbance=jnp.zeros(6))
  assert FAILURE_REASONS[int(_suction_quality(box, below, CUP, c).failure)] == "none"
  heavier = c.replace(mass=jnp.float32(0.22))
  assert FAILURE_REASONS[int(_suction_quality(box, below, CUP, heavier).failure)] == "tips"
  assert FAILURE_REASONS[int(_suction_quality(box, below, CUP.replace(bellows_stiffness=0.06), heavier).failure)
                         ] == "none"
  assert FAILURE_REASONS[int(_suction_quality(box, _suction([0.0, 0.0, 0.02]), CUP,
                                              c.replace(mass=jnp.float32(0.5))).failure)] == "none"


def test_suction_object_off_the_cups_axis_bends_the_bellows_to_their_stop(box):
  """Labels version 6: held from below 5 mm off its centre, the box's centre of mass stands h = 2.5 cm above the
  bellows' pivot and d = 5 mm beside it; the bellows (k = 0.05 N m/rad, range a = 0.5 rad) hold it within their
  range iff m <= k a / (g (d cos a + h sin a)) = 0.1557 kg, where the rule without the offset (k > m g h) allowed
  0.204 kg. A longer-ranged bellows holds the heavier box."""
  a, k, h, d = 0.5, 0.05, 0.025, 0.005
  limit = k * a / (9.81 * (d * np.cos(a) + h * np.sin(a)))
  assert 0.155 < limit < 0.156
  below = SuctionGrasp(center=jnp.array([d, 0.0, -0.02]), approach=jnp.array([0.0, 0.0, 1.0]))
  c = Conditions(mass=jnp.float32(0.985 * limit), friction=jnp.float32(0.8), gravity=DOWN, disturbance=jnp.zeros(6))
  heavier = c.replace(mass=jnp.float32(1.015 * limit))
  assert FAILURE_REASONS[int(_suction_quality(box, below, CUP, c).failure)] == "none"
  assert FAILURE_REASONS[int(_suction_quality(box, below, CUP, heavier).failure)] == "tips"
  assert FAILURE_REASONS[int(_suction_quality(box, below, CUP.replace(bellows_max_angle=0.6), heavier).failure)
                         ] == "none"
  np.testing.assert_allclose(
      float(bellows_margin(box, suction_seal(box, below, CUP), CUP, heavier)),
      k * a / (9.81 * float(heavier.mass)) - (d * np.cos(a) + h * np.sin(a)), atol=2e-5)


def test_suction_centre_of_top_face_resists_edge_and_hole_do_not(box, box_with_hole):
  c = nominal_conditions(suction_perturbations(), DOWN)
  top = _suction_quality(box, _suction([0.0, 0.0, 0.02]), CUP, c)
  assert bool(top.resists)
  edge = _suction_quality(box, _suction([0.037, 0.0, 0.02]), CUP, c)
  assert FAILURE_REASONS[int(edge.failure)] == "no_seal"
  hole = _suction_quality(box_with_hole, _suction([0.0, 0.0, 0.02]), CUP, c)
  assert not bool(hole.resists)
  key = jax.random.key(1)
  many = suction_perturbations(num_samples=40)
  # Centred on the top face: fails only for heavy draws under strongly tilted gravity (the lateral pull at the
  # COM, 2 cm below the cup, exceeds the cup's elastic torque), about one draw in five.
  assert float(_robust_suction(key, box, _suction([0.0, 0.0, 0.02]), CUP, many).probability) >= 0.6
  assert float(_robust_suction(key, box, _suction([0.037, 0.0, 0.02]), CUP).probability) == 0.0
  assert float(_robust_suction(key, box_with_hole, _suction([0.0, 0.0, 0.02]), CUP).probability) == 0.0


def test_suction_nominal_payload_is_vacuum_over_g(box):
  grasp = _suction([0.0, 0.0, 0.02])
  payload = CUP.vacuum_force / 9.81
  c = nominal_conditions(suction_perturbations(), DOWN)
  assert bool(_suction_quality(box, grasp, CUP, c.replace(mass=jnp.float32(0.98 * payload))).resists)
  assert not bool(_suction_quality(box, grasp, CUP, c.replace(mass=jnp.float32(1.02 * payload))).resists)


def test_robust_suction_probability_falls_as_mass_rises_past_payload(box):
  grasp = _suction([0.0, 0.0, 0.02])
  probs = []
  for mean in (0.1, 0.3, 0.6, 0.9, 1.2):
    p = suction_perturbations(num_samples=100, mass_mean=mean, mass_variance=0.01)
    probs.append(float(_robust_suction(jax.random.key(2), box, grasp, CUP, p)
                       .probability))
  assert all(a >= b for a, b in zip(probs, probs[1:])), probs
  assert probs[0] >= 0.9 and probs[-1] <= 0.05, probs


def test_robust_quality_is_a_function_of_the_key(cube):
  k = jax.random.key(5)
  a = _robust_pj(k, cube, CENTRED, PJ)
  b = _robust_pj(k, cube, CENTRED, PJ)
  np.testing.assert_array_equal(np.asarray(a.outcomes.residual), np.asarray(b.outcomes.residual))
  c = _robust_pj(jax.random.key(6), cube, CENTRED, PJ)
  assert not np.array_equal(np.asarray(a.outcomes.residual), np.asarray(c.outcomes.residual))


def test_jit_vmap_and_plain_calls_agree(cube, box):
  grasps = jax.tree.map(lambda *x: jnp.stack(x), CENTRED, CORNER, _pj([0.0, 0.01, 0.005], [1.0, 0.1, 0.0]))
  keys = jax.random.split(jax.random.key(3), 3)
  plain = [robust_parallel_jaw_quality(keys[i], cube, jax.tree.map(lambda x: x[i], grasps), PJ) for i in range(3)]
  batched = jax.jit(jax.vmap(robust_parallel_jaw_quality, in_axes=(0, None, 0, None)))(keys, cube, grasps, PJ)
  for i in range(3):
    np.testing.assert_array_equal(np.asarray(plain[i].outcomes.failure), np.asarray(batched.outcomes.failure[i]))
    np.testing.assert_allclose(np.asarray(plain[i].outcomes.residual), np.asarray(batched.outcomes.residual[i]),
                               rtol=1e-4, atol=2e-5)  # float rounding of ~0 residuals
    assert float(plain[i].probability) == float(batched.probability[i])
  s = jax.tree.map(lambda *x: jnp.stack(x), _suction([0.0, 0.0, 0.02]), _suction([0.03, 0.01, 0.02]))
  plain = [robust_suction_quality(keys[i], box, jax.tree.map(lambda x: x[i], s), CUP).probability for i in range(2)]
  batched = jax.jit(jax.vmap(robust_suction_quality, in_axes=(0, None, 0, None)))(keys[:2], box, s, CUP).probability
  np.testing.assert_array_equal(np.asarray(plain), np.asarray(batched))


def test_quality_is_differentiable_in_the_grasp_centre(cube):
  """The residual of an unresisted grasp has a gradient in the grasp centre that matches finite differences."""
  c = Conditions(mass=jnp.float32(2.5), friction=jnp.float32(0.8), gravity=jnp.array([1.0, 0.0, 0.0]),
                 disturbance=jnp.zeros(6))
  residual = jax.jit(lambda center: parallel_jaw_quality(cube, CENTRED.replace(center=center), PJ, c).residual)
  x = jnp.array([0.0, 0.002, 0.001])
  g = np.asarray(jax.jit(jax.grad(residual))(x))
  assert np.all(np.isfinite(g))
  h = 1e-4
  fd = np.array([(float(residual(x + h * e)) - float(residual(x - h * e))) / (2 * h) for e in np.eye(3)])
  assert abs(fd[1]) > 10.0 and abs(fd[2]) > 10.0  # off-centre grasps leave a torque the residual measures
  np.testing.assert_allclose(g, fd, rtol=0.05, atol=0.5)
  assert math.isfinite(float(residual(jnp.zeros(3))))



_DEVICE_SCRIPT = """
import sys
import jax
import numpy as np
from dexjax.grippers import ParallelJawGripper
from dexjax.objects import load_object_model
from dexjax.quality import evaluate_grasps, parallel_jaw_perturbations
from dexjax.sampling import sample_antipodal_grasps

model, gripper = load_object_model('builtin:box'), ParallelJawGripper()
grasps, _ = jax.jit(sample_antipodal_grasps, static_argnums=2)(jax.random.key(3), model, 100, gripper)
result = evaluate_grasps(jax.random.key(4), model, grasps, gripper, parallel_jaw_perturbations())
np.savez(sys.argv[1], devices=len(jax.local_devices()), probability=result.probability,
         nominal_failure=result.nominal_failure)
"""


def test_evaluate_grasps_over_two_cpu_devices_gives_the_same_bits(tmp_path):
  """`evaluate_grasps` splits the batch (100 grasps, padded to 128) over two CPU devices (a child process with
  two host devices): the probabilities and nominal outcomes are this process's one-device results, bit for
  bit (the wrench solver's pooled batching rule runs inside each device's share)."""
  import os
  import subprocess
  import sys

  path = tmp_path / 'two.npz'
  env = dict(os.environ, XLA_FLAGS='--xla_force_host_platform_device_count=2', JAX_PLATFORMS='cpu')
  child = subprocess.Popen([sys.executable, '-c', _DEVICE_SCRIPT, str(path)], env=env)
  namespace = {}
  exec(_DEVICE_SCRIPT.replace('np.savez(sys.argv[1],', 'out = dict('), namespace)  # One device, meanwhile.
  assert child.wait(timeout=600) == 0
  one, two = namespace['out'], np.load(path)
  assert int(one['devices']) == 1 and int(two['devices']) == 2
  for key in ('probability', 'nominal_failure'):
    assert one[key].shape == (100,)
    np.testing.assert_array_equal(one[key], two[key])
  assert 0.0 < one['probability'].mean() < 1.0  # Not a trivial batch: grasps that hold and grasps that fail.
