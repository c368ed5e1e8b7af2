"""Grasp pytrees in an object (or world) frame, metres, and their 6-DoF gripper poses.

Conventions (as the README's grasp JSON): ``approach`` is the unit direction in which the gripper moves
toward the object (for suction, into the surface); ``axis`` is the unit direction in which the jaws close.
The pose frame follows gqcnn: x = approach, y = jaw axis (suction: a fixed perpendicular), z = x cross y.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.geometry.transforms import normalize, tangent_basis


@struct.dataclass
class ParallelJawGrasp:
  """A parallel-jaw grasp.

  Attributes:
    center: (3,) point midway between the open jaws, metres.
    axis: (3,) unit closing direction of the jaws.
    approach: (3,) unit approach direction (perpendicular to ``axis``).
    width: () opening of the jaws at the start of closing, metres.
  """

  center: jax.Array
  axis: jax.Array
  approach: jax.Array
  width: jax.Array


@struct.dataclass
class SuctionGrasp:
  """A suction grasp: the cup moves along ``approach`` until it meets the surface at ``center``.

  Attributes:
    center: (3,) target point on the surface, metres.
    approach: (3,) unit approach direction (into the surface).
  """

  center: jax.Array
  approach: jax.Array


def parallel_jaw_pose(grasp: ParallelJawGrasp) -> jax.Array:
  """(4, 4) homogeneous gripper pose: x = approach, y = jaw axis (re-orthogonalised), z = x cross y."""
  x = normalize(grasp.approach)
  y = normalize(grasp.axis - jnp.dot(grasp.axis, x) * x)
  return _pose(grasp.center, x, y)


def suction_pose(grasp: SuctionGrasp) -> jax.Array:
  """(4, 4) homogeneous gripper pose: x = approach, y = a fixed perpendicular of x, z = x cross y."""
  x = normalize(grasp.approach)
  y, _ = tangent_basis(x)
  return _pose(grasp.center, x, y)


def _pose(center: jax.Array, x: jax.Array, y: jax.Array) -> jax.Array:
  rot = jnp.stack([x, y, jnp.cross(x, y)], axis=1)
  top = jnp.concatenate([rot, center[:, None]], axis=1)
  return jnp.concatenate([top, jnp.array([[0.0, 0.0, 0.0, 1.0]], top.dtype)], axis=0)
