"""The gripper's path in a physics-judged pick: approach, grip, lift, transport to the receptacle, release.

The seed's protocol: the robot "attempts to grasp the object, and attempts to move the object to a receptacle on
the side of the bin"; success is "lifts and transports exactly one object to a receptacle". A `ToolPath` is the
sampled target of the simulated tool for every physics step: the position of the grasp frame's origin (the grasp
centre, or the cup's mouth) in the world and the gripper command (0 open, 1 closed / vacuum on). The orientation
stays the grasp's. Straight moves follow the minimum-jerk profile of the benchmark's robot-time model
(`dexjax.bench.MotionModel`, `move_seconds`: within the slow contact speed for the approach and the lift, the
tool speed for the transport, and the model's acceleration), so the held object feels the accelerations the
picks-per-hour figure assumes, with no jumps in acceleration (a robot's path planner limits jerk).

Phases (names in `PHASES`): ``approach`` (pre-grasp to grasp along the approach), ``grip`` (close the jaws or
build the vacuum), ``lift`` (straight up by the motion model's lift height), ``transport`` (horizontally to above
the receptacle), ``shake`` (optional, off by default: not in the seed's protocol; a horizontal circle under a
sin² envelope that starts and ends at rest, peak acceleration about ``amplitude * (2 pi frequency)**2``: 1 cm at
3 Hz gives 3.6 m/s²), ``release`` (open the jaws or vent the cup, at rest above the receptacle) and ``fall``
(at rest while what was released lands).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from dexjax.bench.picking_metrics import MotionModel, move_seconds

PHASES = ('approach', 'grip', 'lift', 'transport', 'shake', 'release', 'fall')


@dataclasses.dataclass(frozen=True)
class PathSettings:
  """Timing and size of the judged pick's motions (SI units).

  Attributes:
    motion: the robot model whose speeds and acceleration the moves follow (`MotionModel`).
    grip_seconds: closing the jaws or building the vacuum, s (and opening them again at the receptacle).
    shake_amplitude: amplitude of the optional horizontal shake, m.
    shake_frequency: frequency of the shake, Hz.
    shake_cycles: full cycles of the shake; 0 (default): no shake (the seed's protocol has none; a stress test).
    fall_seconds: at rest above the receptacle after the release while the released object lands, s.
  """

  motion: MotionModel = MotionModel()
  grip_seconds: float = 0.3
  shake_amplitude: float = 0.01
  shake_frequency: float = 3.0
  shake_cycles: int = 0
  fall_seconds: float = 0.4

  def validate(self) -> None:
    """Raises ValueError naming the field and the expected value."""
    for field in ('grip_seconds', 'shake_frequency', 'fall_seconds'):
      value = getattr(self, field)
      if not (math.isfinite(value) and value > 0):
        raise ValueError(f'PathSettings.{field}: expected a finite number > 0, got {value!r}')
    if not (math.isfinite(self.shake_amplitude) and self.shake_amplitude >= 0):
      raise ValueError(f'PathSettings.shake_amplitude: expected a number >= 0 (metres), got {self.shake_amplitude!r}')
    if not (isinstance(self.shake_cycles, int) and self.shake_cycles >= 0):
      raise ValueError(f'PathSettings.shake_cycles: expected an int >= 0, got {self.shake_cycles!r}')


@dataclasses.dataclass(frozen=True)
class ToolPath:
  """The sampled tool targets of one pick (T physics steps).

  Attributes:
    positions: (T, 3) float64 target of the grasp frame's origin, world frame, metres.
    grip: (T,) float64 gripper command in [0, 1] (jaws: fraction of the closing stroke; suction: vacuum on >= 1).
    phase: (T,) int32 index into `PHASES`.
  """

  positions: np.ndarray
  grip: np.ndarray
  phase: np.ndarray

  def has_phase(self, name: str) -> bool:
    return bool(np.any(self.phase == PHASES.index(name)))

  def phase_end(self, name: str) -> int:
    """Index of the last step of phase ``name``."""
    return int(np.flatnonzero(self.phase == PHASES.index(name))[-1])


def move_fraction(t: np.ndarray, distance: float, speed: float, acceleration: float) -> np.ndarray:
  """Fraction (in [0, 1]) of a straight move of ``distance`` covered at times ``t`` (s) of its minimum-jerk
  profile of duration `move_seconds` (10 tau³ - 15 tau⁴ + 6 tau⁵ of tau = t / duration)."""
  if distance <= 0.0:
    return np.ones_like(t)
  tau = np.clip(t / move_seconds(distance, speed, acceleration), 0.0, 1.0)
  return tau ** 3 * (10.0 - 15.0 * tau + 6.0 * tau * tau)


def _move(start: np.ndarray, end: np.ndarray, speed: float, acceleration: float, dt: float) -> np.ndarray:
  distance = float(np.linalg.norm(end - start))
  steps = max(1, math.ceil(move_seconds(distance, speed, acceleration) / dt))
  s = move_fraction(dt * np.arange(1, steps + 1), distance, speed, acceleration)
  return start + s[:, None] * (end - start)


def _shake(centre: np.ndarray, settings: PathSettings, dt: float) -> np.ndarray:
  n = max(1, math.ceil(settings.shake_cycles / settings.shake_frequency / dt))
  t = dt * np.arange(1, n + 1)
  phase = 2.0 * math.pi * settings.shake_frequency * t
  envelope = np.sin(np.pi * t / (n * dt)) ** 2  # starts and ends at rest
  circle = np.stack([np.sin(phase), np.cos(phase), np.zeros(n)], axis=1)
  return centre + settings.shake_amplitude * envelope[:, None] * circle


def tool_path(pre_grasp: np.ndarray, grasp: np.ndarray, receptacle: np.ndarray, timestep: float,
              settings: PathSettings = PathSettings()) -> ToolPath:
  """The tool targets of one pick.

  Args:
    pre_grasp: (3,) start of the approach, world frame, metres.
    grasp: (3,) the grasp frame's origin at the grasp.
    receptacle: (2,) horizontal (x, y) point above which the held object is released, at lift height.
    timestep: physics step, s.
    settings: timing and sizes.
  """
  settings.validate()
  m = settings.motion
  grasp = np.asarray(grasp, np.float64)
  parts = []

  def add(positions, grip, phase):
    grip = np.broadcast_to(np.float64(grip), len(positions)) if np.ndim(grip) == 0 else grip
    parts.append((positions, grip, np.full(len(positions), PHASES.index(phase), np.int32)))

  def hold(position, seconds, grip, phase):
    n = max(1, math.ceil(seconds / timestep))
    add(np.tile(position, (n, 1)), grip(n) if callable(grip) else grip, phase)

  add(_move(np.asarray(pre_grasp, np.float64), grasp, m.slow_speed, m.acceleration, timestep), 0.0, 'approach')
  hold(grasp, settings.grip_seconds, lambda n: np.linspace(0.0, 1.0, n + 1)[1:], 'grip')
  lifted = grasp + np.array([0.0, 0.0, m.lift_height])
  add(_move(grasp, lifted, m.slow_speed, m.acceleration, timestep), 1.0, 'lift')
  above = np.array([receptacle[0], receptacle[1], lifted[2]], np.float64)
  add(_move(lifted, above, m.tool_speed, m.acceleration, timestep), 1.0, 'transport')
  if settings.shake_cycles:
    add(_shake(above, settings, timestep), 1.0, 'shake')
  # Release at once: both pads switch to opening together (a ramp lets the pad that met the object first let go
  # first, while the other still pushes with its full force and flings the object).
  hold(above, settings.grip_seconds, 0.0, 'release')
  hold(above, settings.fall_seconds, 0.0, 'fall')
  return ToolPath(positions=np.concatenate([p for p, _, _ in parts]), grip=np.concatenate([g for _, g, _ in parts]),
                  phase=np.concatenate([ph for _, _, ph in parts]))


__all__ = ['PHASES', 'PathSettings', 'ToolPath', 'move_fraction', 'tool_path']
