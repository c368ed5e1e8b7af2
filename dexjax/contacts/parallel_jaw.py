"""Parallel-jaw contacts: closing the jaws on the signed distance grid, and soft-finger wrench generators.

Each jaw is a point that sweeps from its open position toward the grasp centre along the line of action
(Dex-Net 2.0, spec section 3). The contact is the first outside -> inside crossing of the signed distance,
refined to sub-voxel accuracy; a jaw whose start is already inside the object is reported as a collision
(Dex-Net's unsigned grid cannot tell, and reports the nearest surface instead).

Soft-finger model (spec sections 4.1-4.3), per contact with inward normal n, closing direction d and
friction mu: beta = max(d . n, 0) scales every column (normal-force alignment, as Dex-Net);
``num_cone_edges`` friction-cone edges f_j = n + mu (cos(2 pi j/m) t1 + sin(2 pi j/m) t2) (not normalised,
t1 = projection of the frame's x axis, as Dex-Net) with torques (p - com) x f_j; and two pure torsion
columns +/- gamma n with gamma = (2/3) mu r_f, the torsional friction of a disc of radius r_f under uniform
pressure (Dex-Net writes pi r_f^2 mu s, which is not a length; see docs/deviations.md). All torque rows are
multiplied by ``torque_scale`` (1/m) so that every row of the wrench matrix is in newtons.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.geometry.object_model import ObjectModel
from dexjax.geometry.sdf import first_crossing, surface_normal
from dexjax.geometry.transforms import aligned_tangent_basis, normalize
from dexjax.grasps import ParallelJawGrasp
from dexjax.grippers import ParallelJawGripper


@struct.dataclass
class JawContacts:
  """Where the two jaws of a closing parallel-jaw gripper touch the object.

  Attributes:
    points: (2, 3) contact points, metres.
    normals: (2, 3) inward unit surface normals (pointing into the object).
    directions: (2, 3) unit closing direction of each jaw.
    found: (2,) bool, the jaw met the surface while closing.
    collision: (2,) bool, the open jaw already overlaps the object (the grasp does not fit).
    deepest: (2,) the smallest signed distance sampled along each jaw's closing segment, metres (< 0: the jaw
      meets the surface; `dexjax.geometry.first_crossing`), or None where the contacts were not found by
      closing.
  """

  points: jax.Array
  normals: jax.Array
  directions: jax.Array
  found: jax.Array
  collision: jax.Array
  deepest: jax.Array | None = None

  @property
  def valid(self) -> jax.Array:
    """() bool, both jaws found a contact and neither started inside the object."""
    return jnp.all(self.found) & ~jnp.any(self.collision)


def jaw_lines(grasp: ParallelJawGrasp, gripper: ParallelJawGripper) -> tuple[jax.Array, jax.Array, jax.Array]:
  """The jaws' lines of action: open positions (2, 3) metres, unit closing directions (2, 3), and the
  closing length () metres (each jaw sweeps from its open position to ``min_width / 2`` from the centre)."""
  axis = normalize(grasp.axis)
  half = 0.5 * grasp.width
  starts = jnp.stack([grasp.center - half * axis, grasp.center + half * axis])
  return starts, jnp.stack([axis, -axis]), jnp.maximum(half - 0.5 * gripper.min_width, 0.0)


def close_jaws(model: ObjectModel, grasp: ParallelJawGrasp, gripper: ParallelJawGripper) -> JawContacts:
  """Closes both jaws of ``grasp`` on ``model`` and returns the contacts (object frame)."""
  starts, directions, length = jaw_lines(grasp, gripper)

  def one_jaw(start, direction):
    t, hit, inside, deepest = first_crossing(model, start, direction, length, gripper.num_line_samples)
    point = start + t * direction
    return point, -surface_normal(model, point), hit, inside, deepest

  points, normals, found, collision, deepest = jax.vmap(one_jaw)(starts, directions)
  return JawContacts(points=points, normals=normals, directions=directions, found=found & ~collision,
                     collision=collision, deepest=deepest)


def in_friction_cone(normal: jax.Array, direction: jax.Array, friction: jax.Array) -> jax.Array:
  """() bool: the line of action ``direction`` lies inside the friction cone of inward ``normal`` (no slip)."""
  beta = jnp.dot(direction, normal)
  tangential = jnp.sqrt(jnp.maximum(1.0 - beta**2, 0.0))
  return (beta > 0.0) & (friction * beta >= tangential)


def _contact_columns(point, normal, direction, center_of_mass, friction, gripper, torque_scale):
  """(6, m + 2) soft-finger wrench columns of one contact (forces N; torques N m x torque_scale)."""
  m = gripper.num_cone_edges
  beta = jnp.maximum(jnp.dot(direction, normal), 0.0)
  t1, t2 = aligned_tangent_basis(normal)  # Dex-Net's cone azimuth: t1 along x projected
  angles = 2.0 * jnp.pi * jnp.arange(m) / m
  edges = normal[None, :] + friction * (jnp.cos(angles)[:, None] * t1 + jnp.sin(angles)[:, None] * t2)
  forces = beta * edges  # (m, 3)
  torques = torque_scale * jnp.cross(point - center_of_mass, forces)
  gamma = (2.0 / 3.0) * friction * gripper.finger_radius
  torsion = torque_scale * beta * gamma * normal
  cone = jnp.concatenate([forces, torques], axis=1)  # (m, 6)
  zeros = jnp.zeros(3, forces.dtype)
  twist = jnp.stack([jnp.concatenate([zeros, torsion]), jnp.concatenate([zeros, -torsion])])
  return jnp.concatenate([cone, twist], axis=0).T


def soft_finger_wrenches(contacts: JawContacts, center_of_mass: jax.Array, friction: jax.Array,
                         gripper: ParallelJawGripper,
                         torque_scale: float | jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
  """Wrench generators of a two-finger soft-contact grasp, grouped per finger for the force limit.

  Args:
    contacts: the two jaw contacts.
    center_of_mass: (3,) point about which torques are taken, metres.
    friction: () Coulomb friction coefficient.
    gripper: gripper parameters (force limit, finger radius, cone edges).
    torque_scale: 1/m, multiplies every torque row.

  Returns:
    wrenches: (6, 2 (m + 2)) columns [finger 1: m cone edges, +torsion, -torsion | finger 2: ...].
    groups: (2, 2 (m + 2)) 0/1 rows selecting each finger's columns.
    limits: (2,) force limit per finger, newtons.
  """
  cols = jax.vmap(_contact_columns, in_axes=(0, 0, 0, None, None, None, None))(
      contacts.points, contacts.normals, contacts.directions, center_of_mass, friction, gripper, torque_scale)
  k = cols.shape[-1]
  wrenches = jnp.concatenate([cols[0], cols[1]], axis=1)
  groups = jnp.kron(jnp.eye(2, dtype=wrenches.dtype), jnp.ones((1, k), wrenches.dtype))
  limits = jnp.full((2,), gripper.force_limit, wrenches.dtype)
  return wrenches, groups, limits
