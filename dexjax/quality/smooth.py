"""A smooth robust grasp quality with gradients in the grasp pose and the gripper's parameters.

Every pass/fail test of the hard quality (`dexjax.quality.grasp_quality`) is written as a *margin* m that
passes at m >= 0 (`parallel_jaw_margins`, `suction_margins`):

* parallel jaw: each jaw starts outside the object (the signed distance at its open position, m); the
  fingers and palm clear it (`jaw_clearance` + the collision tolerance, m); each jaw meets the surface while
  closing (minus the smallest signed distance along its segment, m); each line of action is inside its
  friction cone (mu (d . n) - |d x n|, a ratio); the wrench residual r is within the tolerance (N).
* suction: the approach ray meets the surface near the grasp centre (`SealResult.contact_margin`, m); every
  lip ray hits (+inf, else minus the largest distance by which a lip ray misses the surface, m); no holes (`SealResult.hole_margin`, m); every spring within
  its strain limit (max_strain - strain, a ratio); the residual (N).

The smooth pass of one draw is the product of sigmoid(m / (temperature * scale)) over the margins, with one
scale per unit (`Smoothing`), and of sigmoid((tol - r) / (temperature * scale)) / sigmoid(tol / (temperature *
scale)) for the residual: a grasp that resists has r = 0 whatever its other margins, so this factor is 1 there
(not the 0.5 of a plain sigmoid at a 1 mN tolerance). The smooth robust quality averages it over the same reparameterised Monte-Carlo
draws as the hard one (`dexjax.quality.robust.sample_attempt`: for one key both see the same draws). As the
temperature goes to 0 each factor tends to its test's step, i.e. to the hard pass; ``temperature = 0``
computes that step exactly (0 / 1 floats).

Gradients: contact points carry the implicit-function gradient of the surface crossing (`dexjax.geometry.sdf`),
normals are the interpolated gradient of the signed distance (continuous across cells), the residual's gradient
is the envelope theorem's (`dexjax.quality.wrench`), and the gripper's float fields (force limit, cup radius,
vacuum, ...) and the perturbations' (friction mean, mass mean) are pytree leaves. Where a test is decided by
geometry that is not smooth (an edge, the last lip ray coming onto the object) the gradient is that of the piecewise
smooth function on the current side. Functions take one grasp; batch them with `jax.vmap`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.contacts.parallel_jaw import close_jaws, jaw_lines
from dexjax.contacts.suction import suction_seal
from dexjax.geometry.object_model import ObjectModel
from dexjax.geometry.sdf import sdf_value
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality.grasp_quality import (Conditions, QualityConfig, bellows_margin, parallel_jaw_residual,
                                          suction_residual)
from dexjax.quality.gripper_geometry import jaw_clearance
from dexjax.quality.robust import (Perturbations, map_draws, parallel_jaw_perturbations, robust_jaw_samples,
                                   suction_perturbations)

LENGTH, RATIO = 'length', 'ratio'


@struct.dataclass
class Smoothing:
  """How sharp the smooth quality's steps are: each test with margin m contributes
  sigmoid(m / (temperature * scale)), scale by the margin's unit.

  Attributes:
    temperature: () overall sharpness; 0 gives the hard pass exactly, small values approach it.
    length_scale: metres (contact, clearance and hole margins): at temperature 1 a margin of 0.5 mm counts
      e^1 : 1.
    ratio_scale: dimensionless (friction-cone and strain margins).
    force_scale: newtons (the wrench residual's margin).
  """

  temperature: float = 1.0
  length_scale: float = 5e-4
  ratio_scale: float = 0.02
  force_scale: float = 0.1

  def scale(self, unit: str) -> float:
    """The scale of margins in ``unit`` (`LENGTH` or `RATIO`)."""
    return {LENGTH: self.length_scale, RATIO: self.ratio_scale}[unit]


@struct.dataclass
class ParallelJawMargins:
  """Margins (>= 0 passes) of the tests of one parallel-jaw grasp under one draw.

  Attributes:
    jaw_start: (2,) signed distance of each jaw's open position, metres (> 0: outside the object).
    clearance: () `jaw_clearance` plus the collision tolerance, metres (fingers and palm fit).
    closing: (2,) minus the smallest signed distance along each jaw's closing segment, metres (it meets the
      surface).
    cone: (2,) mu (d . n) - |d x n| of each contact (its line of action is inside the friction cone).
    residual: () wrench residual, newtons (`dexjax.quality.wrench`).
    tolerance: () the residual's tolerance, newtons.
  """

  jaw_start: jax.Array
  clearance: jax.Array
  closing: jax.Array
  cone: jax.Array
  residual: jax.Array
  tolerance: jax.Array

  UNITS = (('jaw_start', LENGTH), ('clearance', LENGTH), ('closing', LENGTH), ('cone', RATIO))


@struct.dataclass
class SuctionMargins:
  """Margins (>= 0 passes) of the tests of one suction grasp under one draw.

  Attributes:
    contact: () `SealResult.contact_margin`, metres (the approach meets the surface at the grasp centre).
    lip: () `SealResult.lip_margin`, metres: +inf if every lip ray hits the object, else minus how far the
      farthest-missing lip ray passes from the surface.
    holes: () `SealResult.hole_margin`, metres (no hole under the cup).
    strain: () the gripper's strain limit minus the largest spring strain (0 where a lip ray misses: the lip
      margin decides).
    bellows: () `dexjax.quality.grasp_quality.bellows_margin`, metres (the object does not tip over on the
      bellows).
    residual: () wrench residual, newtons (`dexjax.quality.wrench`).
    tolerance: () the residual's tolerance, newtons.
  """

  contact: jax.Array
  lip: jax.Array
  holes: jax.Array
  strain: jax.Array
  bellows: jax.Array
  residual: jax.Array
  tolerance: jax.Array

  UNITS = (('contact', LENGTH), ('lip', LENGTH), ('holes', LENGTH), ('strain', RATIO), ('bellows', LENGTH))


def soft_step(margin: jax.Array, scale: jax.Array) -> jax.Array:
  """sigmoid(margin / scale), elementwise; the step ``margin >= 0`` (as a float) where ``scale`` is 0."""
  positive = scale > 0
  return jnp.where(positive, jax.nn.sigmoid(margin / jnp.where(positive, scale, 1.0)),
                   (margin >= 0).astype(jnp.float32))


def soft_pass(margins: ParallelJawMargins | SuctionMargins, smoothing: Smoothing = Smoothing()) -> jax.Array:
  """() smooth pass in [0, 1]: the product over every margin of `soft_step` at temperature x its unit's scale,
  and the residual's factor soft_step(tol - r) / soft_step(tol) (1 for a grasp that resists)."""
  factors = [soft_step(getattr(margins, name), smoothing.temperature * smoothing.scale(unit))
             for name, unit in margins.UNITS]
  force = smoothing.temperature * smoothing.force_scale
  resistance = (soft_step(margins.tolerance - margins.residual, force)
                / soft_step(jnp.asarray(margins.tolerance, jnp.float32), force))
  return jnp.prod(jnp.concatenate([jnp.ravel(f) for f in factors])) * resistance


def hard_pass(margins: ParallelJawMargins | SuctionMargins) -> jax.Array:
  """() bool: every margin is >= 0 and the residual within its tolerance (the hard quality's pass, up to
  ties at exactly 0)."""
  tests = [jnp.ravel(getattr(margins, name) >= 0) for name, _ in margins.UNITS]
  return jnp.all(jnp.concatenate(tests)) & (margins.residual <= margins.tolerance)


def _safe_sqrt(x: jax.Array) -> jax.Array:
  positive = x > 0
  return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


def _cone_margin(normal: jax.Array, direction: jax.Array, friction: jax.Array) -> jax.Array:
  """mu beta - sqrt(1 - beta^2), beta = d . n: >= 0 iff the line of action is in the friction cone (as
  `dexjax.contacts.parallel_jaw.in_friction_cone`), with a finite gradient at beta = +-1."""
  beta = jnp.dot(direction, normal)
  return friction * beta - _safe_sqrt(1.0 - beta**2)


def parallel_jaw_margins(model: ObjectModel, grasp: ParallelJawGrasp, gripper: ParallelJawGripper,
                         conditions: Conditions, config: QualityConfig = QualityConfig(),
                         jaw_samples: jax.Array | None = None) -> ParallelJawMargins:
  """The margins of `dexjax.quality.parallel_jaw_quality`'s tests for one grasp and one draw (object frame);
  ``jaw_samples`` as there."""
  starts, _, _ = jaw_lines(grasp, gripper)
  contacts = close_jaws(model, grasp, gripper)
  cone = jax.vmap(_cone_margin, in_axes=(0, 0, None))(contacts.normals, contacts.directions, conditions.friction)
  residual = parallel_jaw_residual(model, contacts, gripper, conditions, config)
  clearance = jaw_clearance(model, grasp, gripper, config.geometry, config.collision_tolerance, jaw_samples)
  return ParallelJawMargins(jaw_start=jax.vmap(lambda p: sdf_value(model, p))(starts),
                            clearance=clearance + config.collision_tolerance,
                            closing=-contacts.deepest, cone=cone, residual=residual,
                            tolerance=jnp.asarray(config.tolerance, jnp.float32))


def suction_margins(model: ObjectModel, grasp: SuctionGrasp, gripper: SuctionGripper, conditions: Conditions,
                    config: QualityConfig = QualityConfig()) -> SuctionMargins:
  """The margins of `dexjax.quality.suction_quality`'s tests for one grasp and one draw (object frame)."""
  seal = suction_seal(model, grasp, gripper)
  residual = suction_residual(model, seal, gripper, conditions, config)
  # Where a lip ray misses there are no spring lengths: the strain test is left to the lip margin (0 here).
  strain = jnp.where(seal.lip_hits, gripper.max_strain - seal.max_strain, 0.0)
  return SuctionMargins(contact=seal.contact_margin, lip=seal.lip_margin, holes=seal.hole_margin, strain=strain,
                        bellows=bellows_margin(model, seal, gripper, conditions, config), residual=residual,
                        tolerance=jnp.asarray(config.tolerance, jnp.float32))


def smooth_parallel_jaw_quality(model: ObjectModel, grasp: ParallelJawGrasp, gripper: ParallelJawGripper,
                                conditions: Conditions, config: QualityConfig = QualityConfig(),
                                smoothing: Smoothing = Smoothing(), jaw_samples: jax.Array | None = None
                                ) -> jax.Array:
  """() smooth pass in [0, 1] of one parallel-jaw grasp under one draw: `soft_pass` of its margins."""
  return soft_pass(parallel_jaw_margins(model, grasp, gripper, conditions, config, jaw_samples), smoothing)


def smooth_suction_quality(model: ObjectModel, grasp: SuctionGrasp, gripper: SuctionGripper,
                           conditions: Conditions, config: QualityConfig = QualityConfig(),
                           smoothing: Smoothing = Smoothing()) -> jax.Array:
  """() smooth pass in [0, 1] of one suction grasp under one draw: `soft_pass` of its margins."""
  return soft_pass(suction_margins(model, grasp, gripper, conditions, config), smoothing)


def smooth_robust_parallel_jaw_quality(key: jax.Array, model: ObjectModel, grasp: ParallelJawGrasp,
                                       gripper: ParallelJawGripper = ParallelJawGripper(),
                                       perturbations: Perturbations | None = None,
                                       config: QualityConfig = QualityConfig(),
                                       smoothing: Smoothing = Smoothing()) -> jax.Array:
  """() the smooth robust probability of a parallel-jaw grasp: the mean smooth pass over the draws that
  `dexjax.quality.robust_parallel_jaw_quality` makes from ``key`` (its collision samples too: the nearest
  ones at the nominal pose, chosen without gradient)."""
  perturbations = parallel_jaw_perturbations() if perturbations is None else perturbations
  samples = robust_jaw_samples(model, jax.lax.stop_gradient(grasp), gripper, config)
  evaluate = lambda g, c: smooth_parallel_jaw_quality(model, g, gripper, c, config, smoothing, samples)
  return jnp.mean(map_draws(key, grasp, perturbations, evaluate))


def smooth_robust_suction_quality(key: jax.Array, model: ObjectModel, grasp: SuctionGrasp,
                                  gripper: SuctionGripper = SuctionGripper(),
                                  perturbations: Perturbations | None = None,
                                  config: QualityConfig = QualityConfig(),
                                  smoothing: Smoothing = Smoothing()) -> jax.Array:
  """() the smooth robust probability of a suction grasp: the mean smooth pass over the draws that
  `dexjax.quality.robust_suction_quality` makes from ``key``."""
  perturbations = suction_perturbations() if perturbations is None else perturbations
  evaluate = lambda g, c: smooth_suction_quality(model, g, gripper, c, config, smoothing)
  return jnp.mean(map_draws(key, grasp, perturbations, evaluate))


__all__ = ['LENGTH', 'RATIO', 'ParallelJawMargins', 'Smoothing', 'SuctionMargins', 'hard_pass',
           'parallel_jaw_margins', 'smooth_parallel_jaw_quality', 'smooth_robust_parallel_jaw_quality',
           'smooth_robust_suction_quality', 'smooth_suction_quality', 'soft_pass', 'soft_step', 'suction_margins']
