"""The gripper's path in a physics-judged pick: approach, grip, lift, transport, shake, hold.

A `ToolPath` is the sampled target of the simulated tool for every physics step: the position of the grasp
frame's origin (the grasp centre, or the cup's mouth) in the world and the gripper command (0 open, 1 closed /
vacuum on). The orientation stays the grasp's. Straight moves follow the same trapezoidal speed profile as the
benchmark's robot-time model (`dexjax.bench.MotionModel`: the slow contact speed for the approach and the lift,
the tool speed for the transport, the same acceleration), so the accelerations the held object feels are those
of the robot the picks-per-hour figure assumes. The shake is a horizontal circle under a sin² envelope that starts and ends at
rest; its peak acceleration is about ``amplitude * (2 pi frequency)**2`` (defaults: 1 cm at 3 Hz, 3.6 m/s²,
besides the transport's 5 m/s²).

Phases (names in `PHASES`): ``approach`` (pre-grasp to grasp along the approach), ``grip`` (close the jaws or
build the vacuum), ``lift`` (straight up), ``transport`` (horizontally to above the bin's centre), ``shake``
and ``hold`` (at rest: whatever is still held at the end is lifted).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from dexjax.bench.picking_metrics import MotionModel, move_seconds

PHASES = ('approach', 'grip', 'lift', 'transport', 'shake', 'hold')


@dataclasses.dataclass(frozen=True)
class PathSettings:
  """Timing and size of the judged pick's motions (SI units).

  Attributes:
    motion: the robot model whose speeds and acceleration the moves follow (`MotionModel`).
    grip_seconds: closing the jaws or building the vacuum, s.
    shake_amplitude: amplitude of the horizontal shake, m.
    shake_frequency: frequency of the shake, Hz.
    shake_cycles: full cycles of the shake.
    hold_seconds: rest at the end before the verdict, s.
  """

  motion: MotionModel = MotionModel()
  grip_seconds: float = 0.3
  shake_amplitude: float = 0.01
  shake_frequency: float = 3.0
  shake_cycles: int = 2
  hold_seconds: float = 0.2

  def validate(self) -> None:
    """Raises ValueError naming the field and the expected value."""
    for field in ('grip_seconds', 'shake_frequency', 'hold_seconds'):
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

  def phase_end(self, name: str) -> int:
    """Index of the last step of phase ``name``."""
    return int(np.flatnonzero(self.phase == PHASES.index(name))[-1])


def trapezoid_fraction(t: np.ndarray, distance: float, speed: float, acceleration: float) -> np.ndarray:
  """Fraction (in [0, 1]) of a straight move of ``distance`` covered at times ``t`` (s) of its
  `move_seconds` trapezoidal (or triangular) speed profile."""
  if distance <= 0.0:
    return np.ones_like(t)
  total = move_seconds(distance, speed, acceleration)
  ramp_time = min(speed / acceleration, 0.5 * total)
  top = acceleration * ramp_time
  t = np.clip(t, 0.0, total)
  up = 0.5 * acceleration * np.minimum(t, ramp_time) ** 2
  cruise = top * np.clip(t - ramp_time, 0.0, total - 2 * ramp_time)
  down_t = np.clip(t - (total - ramp_time), 0.0, ramp_time)
  down = top * down_t - 0.5 * acceleration * down_t ** 2
  return np.clip((up + cruise + down) / distance, 0.0, 1.0)


def _move(start: np.ndarray, end: np.ndarray, speed: float, acceleration: float, dt: float) -> np.ndarray:
  distance = float(np.linalg.norm(end - start))
  steps = max(1, math.ceil(move_seconds(distance, speed, acceleration) / dt))
  s = trapezoid_fraction(dt * np.arange(1, steps + 1), distance, speed, acceleration)
  return start + s[:, None] * (end - start)


def tool_path(pre_grasp: np.ndarray, grasp: np.ndarray, transport_to: np.ndarray, timestep: float,
              settings: PathSettings = PathSettings()) -> ToolPath:
  """The tool targets of one pick.

  Args:
    pre_grasp: (3,) start of the approach, world frame, metres.
    grasp: (3,) the grasp frame's origin at the grasp.
    transport_to: (2,) horizontal (x, y) point the held object is carried to at lift height.
    timestep: physics step, s.
    settings: timing and sizes.
  """
  settings.validate()
  m = settings.motion
  grasp = np.asarray(grasp, np.float64)
  parts = []

  def add(positions, grip, phase):
    parts.append((positions, np.broadcast_to(np.float64(grip), len(positions)) if np.ndim(grip) == 0 else grip,
                  np.full(len(positions), PHASES.index(phase), np.int32)))

  add(_move(np.asarray(pre_grasp, np.float64), grasp, m.slow_speed, m.acceleration, timestep), 0.0, 'approach')
  n = max(1, math.ceil(settings.grip_seconds / timestep))
  add(np.tile(grasp, (n, 1)), np.linspace(0.0, 1.0, n + 1)[1:], 'grip')
  lifted = grasp + np.array([0.0, 0.0, m.lift_height])
  add(_move(grasp, lifted, m.slow_speed, m.acceleration, timestep), 1.0, 'lift')
  carried = np.array([transport_to[0], transport_to[1], lifted[2]], np.float64)
  add(_move(lifted, carried, m.tool_speed, m.acceleration, timestep), 1.0, 'transport')
  n = max(1, math.ceil(settings.shake_cycles / settings.shake_frequency / timestep)) if settings.shake_cycles else 1
  t = timestep * np.arange(1, n + 1)
  phase = 2.0 * math.pi * settings.shake_frequency * t
  envelope = np.sin(np.pi * t / (n * timestep)) ** 2  # starts and ends at rest
  wobble = settings.shake_amplitude * envelope[:, None] * np.stack([np.sin(phase), np.cos(phase), np.zeros(n)],
                                                                   axis=1)
  add(carried + wobble, 1.0, 'shake')
  n = max(1, math.ceil(settings.hold_seconds / timestep))
  add(np.tile(carried, (n, 1)), 1.0, 'hold')
  return ToolPath(positions=np.concatenate([p for p, _, _ in parts]), grip=np.concatenate([g for _, g, _ in parts]),
                  phase=np.concatenate([ph for _, _, ph in parts]))


__all__ = ['PHASES', 'PathSettings', 'ToolPath', 'tool_path', 'trapezoid_fraction']
