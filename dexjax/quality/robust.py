"""Robust (Monte-Carlo) grasp quality: the Dex-Net 4.0 reward model.

The robust quality of a grasp is the probability that it resists gravity plus a random disturbance wrench,
estimated over ``num_samples`` i.i.d. draws of (seed, "Reward Distribution" and "Data Collection Policy"):

* object mass ~ Gamma with mean 0.25 kg and variance 0.05 kg^2 (shape 1.25, scale 0.2 kg);
* gripper position ~ centre + N(0, sigma^2 I): sigma = 2.5 mm (parallel jaw), 0.1 mm (suction); an optional
  rotation noise (off by default: the seed perturbs position only);
* friction ~ N(0.8, 0.01) (variance, i.e. std 0.1) truncated to [0, 1] (a true truncated normal); variance 0
  fixes it at the mean (the heap reward: friction is part of the heap state, `with_known_friction`);
* gravity direction uniform on the sphere (parallel jaw) or uniform within pi/6 of the approach axis (suction;
  the exact distribution rejection sampling would give), or about a fixed axis (world gravity in a heap);
* disturbance wrench ~ N(0, 0.01^2 I) (newtons and newton metres); the robust qualities take an optional fixed
  ``load`` besides (a heap's neighbours pressing on the object: the supervisor's state, not the seed's).

Draws are a pure function of the key, so one key gives one answer; batch grasps with `jax.vmap`.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.geometry.object_model import ObjectModel
from dexjax.geometry.transforms import normalize, sample_cone, so3_exp
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality.grasp_quality import (Conditions, GraspOutcome, QualityConfig, parallel_jaw_quality,
                                          suction_quality)
from dexjax.quality.gripper_geometry import NEAREST_SAMPLES, nearest_jaw_samples

#: Dex-Net 4.0 sample counts and probability thresholds.
REWARD_SAMPLES, SUPERVISOR_SAMPLES = 10, 25
REWARD_THRESHOLD, SUPERVISOR_THRESHOLD = 0.5, 0.75


@struct.dataclass
class Perturbations:
  """The distribution of uncertain quantities (defaults: Dex-Net 4.0; position noise set per gripper).

  Attributes:
    mass_mean: kg.
    mass_variance: kg^2; 0 fixes the mass at ``mass_mean`` (`with_known_mass`; `with_object_mass` centres the law
      on an object's own mass).
    friction_mean: mean of the (pre-truncation) normal.
    friction_variance: variance of the (pre-truncation) normal; 0 fixes the friction at ``friction_mean``
      (clipped to ``friction_range``).
    friction_range: (low, high) truncation interval.
    position_sigma: std of each coordinate of the gripper position noise, metres.
    rotation_sigma: std of each coordinate of the gripper rotation-vector noise, radians.
    disturbance_sigma: std of each of the 6 disturbance-wrench coordinates (N; N m).
    gravity_cone_angle: gravity is uniform within this angle (rad) of ``gravity_axis``; pi = whole sphere.
    gravity_axis: (3,) axis of the gravity cone in the object frame, or None for the grasp's approach.
    num_samples: static number of Monte-Carlo draws M.
  """

  mass_mean: float = 0.25
  mass_variance: float = 0.05
  friction_mean: float = 0.8
  friction_variance: float = 0.01
  friction_range: tuple[float, float] = (0.0, 1.0)
  position_sigma: float = 0.0025
  rotation_sigma: float = 0.0
  disturbance_sigma: float = 0.01
  gravity_cone_angle: float = math.pi
  gravity_axis: jax.Array | None = None
  num_samples: int = struct.field(pytree_node=False, default=REWARD_SAMPLES)


def parallel_jaw_perturbations(num_samples: int = REWARD_SAMPLES, **overrides) -> Perturbations:
  """Dex-Net 4.0 parallel-jaw perturbations: 2.5 mm position noise, gravity uniform on the sphere."""
  return Perturbations(position_sigma=0.0025, gravity_cone_angle=math.pi, num_samples=num_samples,
                       **overrides)


def suction_perturbations(num_samples: int = REWARD_SAMPLES, **overrides) -> Perturbations:
  """Dex-Net 4.0 suction perturbations: 0.1 mm position noise, gravity within pi/6 of the approach axis."""
  return Perturbations(position_sigma=0.0001, gravity_cone_angle=math.pi / 6.0, num_samples=num_samples,
                       **overrides)


def with_known_friction(perturbations: Perturbations, friction: float | jax.Array) -> Perturbations:
  """``perturbations`` with the Coulomb friction fixed at ``friction`` (a () value, e.g. the heap state's for
  the grasped object) instead of drawn: the other draws (mass, pose, gravity, disturbance) are unchanged."""
  return perturbations.replace(friction_mean=friction, friction_variance=0.0)


def with_known_mass(perturbations: Perturbations, mass: float | jax.Array) -> Perturbations:
  """``perturbations`` with the object's mass fixed at ``mass`` (kg) instead of drawn from the Gamma distribution
  (e.g. a simulated object's true mass); the other draws are unchanged."""
  return perturbations.replace(mass_mean=mass, mass_variance=0.0)


def with_object_mass(perturbations: Perturbations, mass: float | jax.Array) -> Perturbations:
  """``perturbations`` with the Gamma mass law centred on the object's own mass: mean ``mass`` (kg) and the
  perturbations' relative spread, variance = ``mass_variance / mass_mean**2 * mass**2`` (the seed's law,
  0.05 kg^2 about 0.25 kg, is a coefficient of variation of 0.89: for a 0.05 kg object, variance 0.002 kg^2).
  The labels of a simulated heap know each object's nominal mass and keep the seed's uncertainty about it (labels
  version 8); the other draws are unchanged."""
  ratio = perturbations.mass_variance / perturbations.mass_mean**2
  return perturbations.replace(mass_mean=mass, mass_variance=ratio * mass * mass)


@struct.dataclass
class RobustQuality:
  """Monte-Carlo estimate for one grasp.

  Attributes:
    probability: () fraction of draws in which the grasp resists.
    outcomes: `GraspOutcome` with a leading axis of ``num_samples`` (the individual draws).
  """

  probability: jax.Array
  outcomes: GraspOutcome


def sample_conditions(key: jax.Array, perturbations: Perturbations, approach: jax.Array) -> Conditions:
  """One draw of mass, friction, gravity direction and disturbance wrench."""
  k_mass, k_mu, k_grav, k_dist = jax.random.split(key, 4)
  p = perturbations
  var = jnp.asarray(p.mass_variance, jnp.float32)
  safe_var = jnp.where(var > 0.0, var, 1.0)
  shape = p.mass_mean**2 / safe_var
  mass = jnp.where(var > 0.0, jax.random.gamma(k_mass, shape) * (safe_var / p.mass_mean),
                   p.mass_mean)  # variance 0: a known mass
  low, high = p.friction_range
  std = jnp.sqrt(jnp.asarray(p.friction_variance, jnp.float32))
  safe = jnp.where(std > 0.0, std, 1.0)
  drawn = p.friction_mean + safe * jax.random.truncated_normal(k_mu, (low - p.friction_mean) / safe,
                                                               (high - p.friction_mean) / safe)
  friction = jnp.where(std > 0.0, drawn, jnp.clip(p.friction_mean, low, high))  # variance 0: a known friction
  axis = approach if p.gravity_axis is None else p.gravity_axis
  gravity = sample_cone(k_grav, axis, p.gravity_cone_angle)
  disturbance = p.disturbance_sigma * jax.random.normal(k_dist, (6,))
  return Conditions(mass=mass, friction=friction, gravity=gravity, disturbance=disturbance)


def nominal_conditions(perturbations: Perturbations, approach: jax.Array) -> Conditions:
  """The unperturbed conditions: mean mass and friction, gravity along the cone axis (default: the approach,
  the object hanging below the gripper), no disturbance."""
  p = perturbations
  axis = approach if p.gravity_axis is None else p.gravity_axis
  return Conditions(mass=jnp.asarray(p.mass_mean, jnp.float32), friction=jnp.asarray(p.friction_mean, jnp.float32),
                    gravity=normalize(jnp.asarray(axis, jnp.float32)), disturbance=jnp.zeros(6, jnp.float32))


def _perturb_pose(key, perturbations: Perturbations, center, directions):
  """Gripper position noise and a common rotation of the grasp's direction vectors (k, 3)."""
  k_pos, k_rot = jax.random.split(key)
  center = center + perturbations.position_sigma * jax.random.normal(k_pos, (3,))
  rot = so3_exp(perturbations.rotation_sigma * jax.random.normal(k_rot, (3,)))
  return center, directions @ rot.T


def perturb_parallel_jaw_grasp(key: jax.Array, grasp: ParallelJawGrasp,
                               perturbations: Perturbations) -> ParallelJawGrasp:
  """One draw of the gripper-pose noise applied to a parallel-jaw grasp."""
  center, dirs = _perturb_pose(key, perturbations, grasp.center, jnp.stack([grasp.axis, grasp.approach]))
  return grasp.replace(center=center, axis=dirs[0], approach=dirs[1])


def perturb_suction_grasp(key: jax.Array, grasp: SuctionGrasp, perturbations: Perturbations) -> SuctionGrasp:
  """One draw of the gripper-pose noise applied to a suction grasp."""
  center, dirs = _perturb_pose(key, perturbations, grasp.center, grasp.approach[None])
  return grasp.replace(center=center, approach=dirs[0])


def sample_attempt(key: jax.Array, grasp: ParallelJawGrasp | SuctionGrasp,
                   perturbations: Perturbations) -> tuple[ParallelJawGrasp | SuctionGrasp, Conditions]:
  """One Monte-Carlo draw of the robust quality: the perturbed grasp and the `Conditions` it is tested under.
  Every draw is reparameterised (noise drawn independently of the grasp, then added to or rotated onto it),
  so the draw is differentiable in the grasp for a fixed key."""
  k_pose, k_cond = jax.random.split(key)
  conditions = sample_conditions(k_cond, perturbations, normalize(grasp.approach))
  perturb = perturb_suction_grasp if isinstance(grasp, SuctionGrasp) else perturb_parallel_jaw_grasp
  return perturb(k_pose, grasp, perturbations), conditions


def map_draws(key: jax.Array, grasp: ParallelJawGrasp | SuctionGrasp, perturbations: Perturbations,
              evaluate: Callable[[ParallelJawGrasp | SuctionGrasp, Conditions], Any]) -> Any:
  """``evaluate(perturbed grasp, conditions)`` on each of the ``num_samples`` draws that the robust quality
  makes from ``key`` (`sample_attempt` of ``split(key, num_samples)``), stacked on a leading axis: the one
  place that fixes which draws a key means, for the hard quality and its smooth surrogate alike."""
  keys = jax.random.split(key, perturbations.num_samples)
  return jax.vmap(lambda k: evaluate(*sample_attempt(k, grasp, perturbations)))(keys)


def robust_jaw_samples(model: ObjectModel, grasp: ParallelJawGrasp, gripper: ParallelJawGripper,
                       config: QualityConfig = QualityConfig()) -> jax.Array | None:
  """The collision samples every draw of a robust parallel-jaw quality tests: the ``NEAREST_SAMPLES`` (64)
  `jaw_collision_points` nearest the object at the nominal pose of ``grasp`` (`nearest_jaw_samples`), or None
  for point jaws (nothing to test; static)."""
  if gripper.finger_thickness <= 0:
    return None
  return nearest_jaw_samples(model, grasp, gripper, config.geometry, NEAREST_SAMPLES)


def _with_load(evaluate, load):
  """``evaluate`` with a fixed ``load`` (6,) added to every draw's disturbance (None: unchanged)."""
  if load is None:
    return evaluate
  load = jnp.asarray(load, jnp.float32)
  return lambda g, c: evaluate(g, c.replace(disturbance=c.disturbance + load))


def _robust(key, grasp, perturbations, evaluate) -> RobustQuality:
  outcomes = map_draws(key, grasp, perturbations, evaluate)
  return RobustQuality(probability=jnp.mean(outcomes.resists.astype(jnp.float32)), outcomes=outcomes)


def robust_parallel_jaw_quality(key: jax.Array, model: ObjectModel, grasp: ParallelJawGrasp,
                                gripper: ParallelJawGripper = ParallelJawGripper(),
                                perturbations: Perturbations | None = None,
                                config: QualityConfig = QualityConfig(),
                                load: jax.Array | None = None) -> RobustQuality:
  """Probability that a parallel-jaw grasp resists gravity plus a random disturbance (Dex-Net 4.0).

  Every draw runs the whole `parallel_jaw_quality`, including ``jaw_collision`` at the draw's perturbed pose
  (the pose noise moves the fingers): the gripper's collision samples are ranked once by their distance to
  the object at the nominal pose, and the ``NEAREST_SAMPLES`` (64) nearest are tested at every draw's pose
  (`nearest_jaw_samples`; with point jaws nothing is tested).

  ``load``: None (the seed), or (6,) a fixed wrench on the object in every draw besides gravity and the random
  disturbance: force (N) and torque (N m, about the centre of mass), object frame (e.g. what its neighbours in a
  heap press it with, `dexjax.sim.resting_loads`; not a distribution parameter, so not in `Perturbations`).
  """
  perturbations = parallel_jaw_perturbations() if perturbations is None else perturbations
  samples = robust_jaw_samples(model, grasp, gripper, config)
  evaluate = lambda g, c: parallel_jaw_quality(model, g, gripper, c, config, samples)
  return _robust(key, grasp, perturbations, _with_load(evaluate, load))


def robust_suction_quality(key: jax.Array, model: ObjectModel, grasp: SuctionGrasp,
                           gripper: SuctionGripper = SuctionGripper(), perturbations: Perturbations | None = None,
                           config: QualityConfig = QualityConfig(), load: jax.Array | None = None) -> RobustQuality:
  """Probability that a suction grasp seals and resists gravity plus a random disturbance (Dex-Net 4.0); ``load``
  as `robust_parallel_jaw_quality`'s."""
  perturbations = suction_perturbations() if perturbations is None else perturbations
  evaluate = lambda g, c: suction_quality(model, g, gripper, c, config)
  return _robust(key, grasp, perturbations, _with_load(evaluate, load))
