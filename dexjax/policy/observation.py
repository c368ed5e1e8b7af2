"""What a policy sees: one depth image (metres), where grasps may be centred, and the camera.

`Observation` is the input of every policy in `dexjax.policy` (single item; `vmap` over a stacked batch).
Depths are camera-frame z in metres; every pixel of ``depth`` must be valid (finite, > 0): real sensor images
are made so by `dexjax.policy.prepare_observation` (holes inpainted and left out of the mask), rendered ones
have no holes. ``mask`` restricts where grasp centres may lie (the objects: a user's segmask, or what lies above
the bin floor); grasp crops still read the whole image around the centre.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from dexjax.render.camera import Camera


@struct.dataclass
class Observation:
  """One depth observation.

  Attributes:
    depth: (H, W) float32 depth, metres, valid everywhere (inpainted where the sensor had no return).
    mask: (H, W) bool, pixels where a grasp may be centred.
    camera: the `Camera`; its intrinsics are sized H x W. Grasps and poses are expressed in the camera frame,
      so only the intrinsics matter to a policy (the pose, if known, maps actions to the world).
  """

  depth: jax.Array
  mask: jax.Array
  camera: Camera

  @property
  def shape(self) -> tuple[int, int]:
    """(H, W), pixels."""
    return self.depth.shape[-2:]


def observation(depth: jax.Array, camera: Camera, mask: jax.Array | None = None) -> Observation:
  """An `Observation` of an already valid depth image (H, W) metres; ``mask`` defaults to every pixel."""
  depth = jnp.asarray(depth, jnp.float32)
  mask = jnp.ones(depth.shape, bool) if mask is None else jnp.asarray(mask, bool)
  return Observation(depth=depth, mask=mask, camera=camera)


__all__ = ['Observation', 'observation']
