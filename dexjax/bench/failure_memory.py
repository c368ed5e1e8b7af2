"""Failures that change nothing: a policy's memory of its failed grasps, and the count of repeated attempts.

A failed suction attempt often leaves the bin as it was, and a deterministic policy then plans the same grasp
again until the trial ends on consecutive failures; a real robot's failed attempt nearly always moves the object.
The benchmark therefore reports how many attempts repeat an earlier failure (`repeated_attempts`), and offers
policies an optional memory (`FailureMemory`, off by default so that results compare with the seed's): for the
next ``attempts`` attempts no grasp may be centred within ``radius`` of a failed grasp's aim point (a 3-D distance,
so an object that has since moved away, or a neighbour at another height, is not excluded). The aim point is the
surface the policy saw at the grasp's centre pixel (`aim_point`): a suction grasp's contact, the top of what a
parallel-jaw grasp closes on (its centre lies below that surface by the jaws' depth, often more than the radius,
so a memory of grasp centres let the jaws repeat). The memory is applied
to where grasps may be centred (the observation's mask; for the privileged supervisor, the segmentation it picks
visible grasps from), so it works with every policy unchanged.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from dexjax.render.camera import Camera, camera_to_world, deproject
from dexjax.sampling.image_grasps import camera_point

REPEAT_RADIUS = 0.01
"""An attempt repeats an earlier failed one when it uses the same gripper and its grasp centre lies within this
distance of the failed one's, m."""


@dataclasses.dataclass(frozen=True)
class FailureMemory:
  """A policy's memory of failed grasps (off when ``radius`` is 0, the default: the seed's protocol has none).

  Attributes:
    radius: no grasp centre within this distance of a remembered failed grasp centre, m.
    attempts: a failure is remembered for this many following attempts.
  """

  radius: float = 0.0
  attempts: int = 5

  @property
  def enabled(self) -> bool:
    return self.radius > 0.0

  def validate(self) -> FailureMemory:
    """Raises ValueError naming the field and the expected value."""
    if not (math.isfinite(self.radius) and self.radius >= 0.0):
      raise ValueError(f'FailureMemory.radius (--failure-memory): expected a number >= 0 (metres), got {self.radius!r}')
    if not (isinstance(self.attempts, int) and not isinstance(self.attempts, bool) and self.attempts >= 1):
      raise ValueError(f'FailureMemory.attempts (--memory-attempts): expected an integer >= 1, got {self.attempts!r}')
    return self


def aim_point(depth: np.ndarray, camera: Camera, center: Sequence[float]) -> list[float] | None:
  """The world point (3 floats, m) of a depth image (H, W, metres) at the pixel nearest a grasp centre (u, v), or
  None when that pixel is off the image or its depth is invalid."""
  col, row = (int(np.floor(float(c) + 0.5)) for c in center)
  h, w = np.shape(depth)
  if not (0 <= row < h and 0 <= col < w):
    return None
  z = float(depth[row, col])
  if not (math.isfinite(z) and z > 0.0):
    return None
  return np.asarray(camera_to_world(camera, camera_point(camera, np.array([col, row], np.float32), np.float32(z))),
                    np.float64).tolist()


def remembered_failures(records: Sequence[Mapping[str, Any]], memory: FailureMemory) -> np.ndarray:
  """(K, 3) world aim points of the failed attempts among the last ``memory.attempts`` records of a trial (their
  grasp centres for records without one)."""
  recent = records[-memory.attempts:] if memory.enabled else []
  points = [r.get('aim_point') or r.get('world_center') for r in recent if not r['success']]
  return np.array([p for p in points if p is not None], np.float64).reshape(-1, 3)


def excluded_pixels(depth: np.ndarray, camera: Camera, centres: np.ndarray, radius: float) -> np.ndarray:
  """(H, W) bool: pixels of a depth image (metres) whose world point lies within ``radius`` of any of ``centres``
  (K, 3) (invalid pixels never)."""
  if not len(centres):
    return np.zeros(np.shape(depth), bool)
  points = np.asarray(deproject(camera, np.asarray(depth, np.float32)), np.float64)
  near = np.zeros(points.shape[:2], bool)
  for c in centres:
    with np.errstate(invalid='ignore'):
      near |= np.sum((points - c) ** 2, axis=-1) <= radius * radius
  return near


def repeated_attempts(records: Iterable[Mapping[str, Any]], radius: float = REPEAT_RADIUS) -> list[bool]:
  """Per record (in order), whether it repeats an earlier failed attempt of the same policy and trial: the same
  gripper with its grasp centre within ``radius`` (m) of the failed one's."""
  failed: dict[tuple[Any, Any], list[tuple[str, np.ndarray]]] = {}
  out = []
  for r in records:
    centre = r.get('world_center')
    earlier = failed.setdefault((r['policy'], r['trial']), [])
    repeat = centre is not None and any(g == r['gripper'] and np.linalg.norm(c - np.asarray(centre)) <= radius
                                        for g, c in earlier)
    out.append(bool(repeat))
    if centre is not None and not r['success']:
      earlier.append((r['gripper'], np.asarray(centre, np.float64)))
  return out


__all__ = ['FailureMemory', 'REPEAT_RADIUS', 'aim_point', 'excluded_pixels', 'remembered_failures', 'repeated_attempts']
