"""3-D grasp samplers on a single `ObjectModel` (object frame), with a fixed candidate budget and a mask.

* `sample_antipodal_grasps`: Dex-Net 2.0's antipodal sampler (spec section 7.1) made jittable: pick a surface
  sample, draw a closing direction inside its friction cone (psi ~ U[0, 2 pi), rho ~ mu U[0, 1], as Dex-Net),
  march through the object to where that line leaves it, centre the open jaws on the two points, close them
  and keep the grasp if both contacts exist and satisfy the Nguyen antipodality test with the sampling
  friction. The approach is searched around the jaw axis as in Dex-Net's collision-checked sampling:
  ``num_approaches`` angles, evenly spaced from a uniformly random offset, are tried in turn and the first at
  which the open fingers and palm, swept back along the approach, do not collide with the object
  (`dexjax.quality.gripper_geometry.jaw_collides`, the single-object quality's test) is kept; a candidate
  without a free approach is invalid. With point jaws (``finger_thickness = 0``) the first angle is kept, as a
  uniform draw around the axis.
* `sample_suction_grasps`: Dex-Net 3.0's suction sampler: a surface point, approach = inward normal; valid
  when the approach ray meets the object first at that point (nothing of the object in front of it).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.contacts.parallel_jaw import close_jaws
from dexjax.contacts.suction import approach_contact
from dexjax.geometry.object_model import ObjectModel
from dexjax.geometry.sdf import first_crossing
from dexjax.geometry.transforms import normalize, perpendicular, tangent_basis
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp
from dexjax.grippers import ParallelJawGripper, SuctionGripper
from dexjax.quality.grasp_quality import QualityConfig
from dexjax.quality.gripper_geometry import jaw_collides


@struct.dataclass
class AntipodalSampler:
  """Parameters of the antipodal sampler (Dex-Net 2.0 code values).

  Attributes:
    friction: sampling friction coefficient mu for the cone draw and the Nguyen test (code 0.5, paper 0.6).
    min_contact_distance: reject grasps whose contacts are closer than this, metres.
    num_approaches: static, approach angles tried around the jaw axis per candidate (8: every 45 degrees).
  """

  friction: float = 0.5
  min_contact_distance: float = 0.0025
  num_approaches: int = struct.field(pytree_node=False, default=8)


def antipodal(points: jax.Array, normals: jax.Array, friction: float | jax.Array) -> jax.Array:
  """() bool Nguyen test: the segment between two contacts lies in both friction cones.

  Args:
    points: (2, 3) contact points.
    normals: (2, 3) inward unit normals.
    friction: friction coefficient.
  """
  line = normalize(points[1] - points[0])
  cos_limit = jnp.cos(jnp.arctan(friction))
  return (jnp.dot(normals[0], line) >= cos_limit) & (jnp.dot(normals[1], -line) >= cos_limit)


def sample_antipodal_grasps(key: jax.Array, model: ObjectModel, num_grasps: int,
                            gripper: ParallelJawGripper = ParallelJawGripper(),
                            sampler: AntipodalSampler = AntipodalSampler(),
                            config: QualityConfig = QualityConfig()) -> tuple[ParallelJawGrasp, jax.Array]:
  """Samples ``num_grasps`` (static) antipodal parallel-jaw grasp candidates on ``model``.

  Args:
    key: `jax.random` key.
    model: the object.
    num_grasps: static number of candidates.
    gripper: jaw opening, line samples and the finger and palm sizes of the collision test.
    sampler: sampling friction, contact distance and the number of approach angles tried.
    config: the collision tolerance and sampling (``collision_tolerance``, ``geometry``) of the approach
      test, the same as the quality's.

  Returns:
    grasps: `ParallelJawGrasp` with leading axis ``num_grasps`` (width = gripper.max_width; approach = the
      first collision-free angle tried, or the first angle when none is free).
    valid: (num_grasps,) bool mask of candidates that passed every test, including a collision-free approach.
  """
  keys = jax.random.split(key, num_grasps)
  num_points = model.surface_points.shape[0]

  def one(k):
    k_idx, k_psi, k_rho, k_app = jax.random.split(k, 4)
    i = jax.random.randint(k_idx, (), 0, num_points)
    x1, n_out = model.surface_points[i], model.surface_normals[i]
    t1, t2 = tangent_basis(n_out)
    psi = jax.random.uniform(k_psi, (), maxval=2.0 * jnp.pi)
    rho = sampler.friction * jax.random.uniform(k_rho, ())
    axis = -normalize(n_out + rho * (jnp.cos(psi) * t1 + jnp.sin(psi) * t2))
    start = x1 + 0.5 * model.voxel_size * axis
    t, exits, _, _ = first_crossing(model, start, axis, gripper.max_width, gripper.num_line_samples, exiting=True)
    x2 = start + t * axis
    offset = jax.random.uniform(k_app, (), maxval=2.0 * jnp.pi)
    grasp = ParallelJawGrasp(center=0.5 * (x1 + x2), axis=axis, approach=perpendicular(axis, offset),
                             width=jnp.asarray(gripper.max_width, jnp.float32))
    contacts = close_jaws(model, grasp, gripper)
    far_enough = jnp.linalg.norm(contacts.points[1] - contacts.points[0]) > sampler.min_contact_distance
    ok = exits & contacts.valid & far_enough & antipodal(contacts.points, contacts.normals, sampler.friction)
    if gripper.finger_thickness <= 0:  # point jaws: every approach is free (static)
      return grasp, ok
    angles = offset + 2.0 * jnp.pi * jnp.arange(sampler.num_approaches) / sampler.num_approaches
    approaches = jax.vmap(perpendicular, in_axes=(None, 0))(axis, angles)
    collides = jax.vmap(lambda a: jaw_collides(model, grasp.replace(approach=a), gripper, config.geometry,
                                               config.collision_tolerance))(approaches)
    first_free = jnp.argmin(collides)  # the first False; 0 when every approach collides
    return grasp.replace(approach=approaches[first_free]), ok & ~jnp.all(collides)

  return jax.vmap(one)(keys)


def sample_suction_grasps(key: jax.Array, model: ObjectModel, num_grasps: int,
                          gripper: SuctionGripper = SuctionGripper()) -> tuple[SuctionGrasp, jax.Array]:
  """Samples ``num_grasps`` (static) suction candidates: surface points with the inward normal as approach.

  Returns:
    grasps: `SuctionGrasp` with leading axis ``num_grasps``.
    valid: (num_grasps,) bool, the approach ray first meets the object at the target point.
  """
  idx = jax.random.randint(key, (num_grasps,), 0, model.surface_points.shape[0])
  grasps = SuctionGrasp(center=model.surface_points[idx], approach=-model.surface_normals[idx])
  valid = jax.vmap(lambda g: approach_contact(model, g, gripper)[1])(grasps)
  return grasps, valid
