"""Grasp candidates of one gripper in one observation: sampling them, and the feature vectors the Cross-Entropy
Method fits its mixture to (spec section 4.3), with their inverse.

Feature vectors (gqcnn's):

* parallel jaw: [u1, v1, u2, v2, d], the two jaw endpoints (pixels) at the grasp depth d (metres): the centre
  +- (w_px / 2) (cos angle, sin angle), w_px = fx w / d the opening in pixels. Decoding takes the midpoint as the
  centre, the endpoints' direction as the angle and d as the depth, so the CEM also optimises the depth. We clip
  the decoded depth to the sampler's range [z_c + min_depth_offset, z_c + max_depth_offset] around the surface
  depth z_c under the new centre (gqcnn does not constrain it; a network is only trained on depths in that range).
* suction: [u, v]; depth and approach are re-read from the image and its normals at the decoded pixel.

Decoded grasps are valid when their centre is inside the sampler's border, on the observation's mask, and (suction)
the surface normal there is defined and within the sampler's approach cone. Every function works on one
observation with a static number of grasps; invalid entries are masked, never dropped.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from dexjax.policy.observation import Observation
from dexjax.policy.scorers import PARALLEL_JAW, SUCTION
from dexjax.sampling.image_grasps import ImageParallelJawGrasp, ImageSuctionGrasp, angles_from_approach
from dexjax.sampling.image_samplers import (AntipodalImageSampler, SuctionImageSampler, centre_window,
                                            sample_antipodal_image_grasps, sample_suction_image_grasps,
                                            surface_normals)

Sampler = AntipodalImageSampler | SuctionImageSampler
ImageGrasp = ImageParallelJawGrasp | ImageSuctionGrasp


def sampler_gripper(sampler: Sampler) -> str:
  """The gripper whose grasps ``sampler`` draws."""
  if isinstance(sampler, AntipodalImageSampler):
    return PARALLEL_JAW
  if isinstance(sampler, SuctionImageSampler):
    return SUCTION
  raise TypeError(f'sampler: expected an AntipodalImageSampler or SuctionImageSampler, got {type(sampler).__name__}')


def sample_candidates(key: jax.Array, observation: Observation, sampler: Sampler) -> tuple[ImageGrasp, jax.Array]:
  """``sampler.num_grasps`` candidates centred on the observation's mask: (grasps with leading axis N, valid (N,))."""
  if sampler_gripper(sampler) == PARALLEL_JAW:
    grasps, valid = sample_antipodal_image_grasps(key, observation.depth, observation.camera, sampler,
                                                  observation.mask)
    # The sampler keeps contacts on the mask; the midpoint of two contacts on two objects may lie between them.
    return grasps, valid & _inside(observation, jnp.floor(grasps.center + 0.5).astype(jnp.int32), 0)
  return sample_suction_image_grasps(key, observation.depth, observation.camera, sampler, observation.mask)


def feature_size(sampler: Sampler) -> int:
  """D, the length of a grasp's feature vector: 5 (parallel jaw) or 2 (suction)."""
  return 5 if sampler_gripper(sampler) == PARALLEL_JAW else 2


def grasp_features(observation: Observation, grasps: ImageGrasp) -> jax.Array:
  """(N, D) float32 feature vectors of N grasps (see the module doc)."""
  if isinstance(grasps, ImageSuctionGrasp):
    return grasps.center
  half = 0.5 * observation.camera.intrinsics.fx * grasps.width / grasps.depth
  offset = half[:, None] * jnp.stack([jnp.cos(grasps.angle), jnp.sin(grasps.angle)], axis=-1)
  return jnp.concatenate([grasps.center - offset, grasps.center + offset, grasps.depth[:, None]], axis=-1)


def _inside(observation: Observation, pixel: jax.Array, boundary) -> jax.Array:
  """(N,) bool: integer pixels (N, 2) (u, v) at least ``boundary`` from the border (gqcnn's test) and on the mask."""
  h, w = observation.shape
  u, v = pixel[:, 0], pixel[:, 1]
  inside = (u >= boundary) & (v >= boundary) & (u <= w - boundary) & (v <= h - boundary)
  on_mask = observation.mask[jnp.clip(v, 0, h - 1), jnp.clip(u, 0, w - 1)]
  return inside & on_mask


def grasps_from_features(observation: Observation, features: jax.Array, sampler: Sampler,
                         normals: jax.Array | None = None) -> tuple[ImageGrasp, jax.Array]:
  """Decodes feature vectors (N, D) into N grasps and their validity (N,) bool (see the module doc).

  ``normals`` (H, W, 3), the observation's `surface_normals`, is used by suction (computed here if not given).
  """
  features = jnp.where(jnp.isfinite(features), features, -1e6)  # non-finite draws decode to invalid pixels
  if sampler_gripper(sampler) == PARALLEL_JAW:
    p1, p2, d = features[:, 0:2], features[:, 2:4], features[:, 4]
    center = 0.5 * (p1 + p2)
    axis = p2 - p1
    pixel = jnp.floor(center + 0.5).astype(jnp.int32)
    ok = _inside(observation, pixel, sampler.boundary)
    z_c = jax.vmap(lambda p: jnp.min(centre_window(observation.depth, p[::-1], sampler.depth_window)))(pixel)
    depth = jnp.clip(d, z_c + sampler.min_depth_offset, z_c + sampler.max_depth_offset)
    grasps = ImageParallelJawGrasp(center=center, angle=jnp.arctan2(axis[:, 1], axis[:, 0]), depth=depth,
                                   width=jnp.full(d.shape, sampler.gripper_width, jnp.float32))
    return grasps, ok & (jnp.linalg.norm(axis, axis=-1) > 0) & (z_c > 0)
  if normals is None:
    normals = surface_normals(observation.camera, observation.depth)
  h, w = observation.shape
  pixel = jnp.floor(features + 0.5).astype(jnp.int32)
  u, v = jnp.clip(pixel[:, 0], 0, w - 1), jnp.clip(pixel[:, 1], 0, h - 1)
  approach = -normals[v, u]
  finite = jnp.all(jnp.isfinite(approach), axis=-1)
  angle, psi = jax.vmap(angles_from_approach)(jnp.where(finite[:, None], approach, jnp.array([0.0, 0.0, 1.0])))
  ok = _inside(observation, pixel, sampler.boundary) & finite & (psi <= sampler.max_approach_angle)
  grasps = ImageSuctionGrasp(center=pixel.astype(jnp.float32), angle=angle, depth=observation.depth[v, u],
                             approach_angle=psi)
  return grasps, ok


__all__ = ['ImageGrasp', 'Sampler', 'feature_size', 'grasp_features', 'grasps_from_features', 'sample_candidates',
           'sampler_gripper']
