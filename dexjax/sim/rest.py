"""The rest test shared by both settling engines: when does an object of a heap rest?

An object rests when its centre-of-mass speed is below ``SettleSettings.linear_speed_tol`` and its angular speed
below ``SettleSettings.angular_speed_tol`` (seed: 0.005 m/s and 0.1 rad/s). `resting` computes that from MuJoCo
free-joint states, whose frame is the object frame (not the centre of mass), with ``xp`` = `numpy` (the
`rollout` engine, `dexjax.sim.settling`) or `jax.numpy` (inside the compiled MJX loop, `dexjax.sim.mjx_backend`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dexjax.sim.scene import SettleSettings


def cross(a: Any, b: Any, xp: Any = np) -> Any:
  """``xp.cross`` of (..., 3) vectors by components: the same products and differences (bitwise equal), without
  NumPy's per-call axis handling, which dominated the settling loop's small arrays."""
  a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
  b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
  return xp.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def rotate(quaternion: Any, vector: Any, xp: Any = np) -> Any:
  """Rotates vectors (..., 3) by unit quaternions (..., 4) (w, x, y, z); ``xp`` is `numpy` or `jax.numpy`."""
  w, r = quaternion[..., :1], quaternion[..., 1:]
  t = 2.0 * cross(r, vector, xp)
  return vector + w * t + cross(r, t, xp)


def object_speeds(qpos: Any, qvel: Any, centers_of_mass: Any, xp: Any = np) -> tuple[Any, Any]:
  """Centre-of-mass and angular speeds of free bodies whose frame is the object frame.

  Args:
    qpos: (..., m, 7) free-joint positions: frame origin (world, metres) and quaternion (w, x, y, z).
    qvel: (..., m, 6) free-joint velocities: origin velocity (world, m/s), angular velocity (body, rad/s).
    centers_of_mass: (m, 3) centres of mass in the object frames, metres.
    xp: `numpy` or `jax.numpy`.

  Returns:
    (linear (..., m) m/s, angular (..., m) rad/s).
  """
  omega = qvel[..., 3:]
  v_com = qvel[..., :3] + rotate(qpos[..., 3:], cross(omega, centers_of_mass, xp), xp)
  return xp.linalg.norm(v_com, axis=-1), xp.linalg.norm(omega, axis=-1)


def resting(qpos: Any, qvel: Any, centers_of_mass: Any, settings: SettleSettings, xp: Any = np) -> Any:
  """(..., m) bool: each object's speeds are below the settling thresholds (shapes as `object_speeds`)."""
  lin, ang = object_speeds(qpos, qvel, centers_of_mass, xp)
  return (lin < settings.linear_speed_tol) & (ang < settings.angular_speed_tol)


__all__ = ['cross', 'object_speeds', 'resting', 'rotate']
