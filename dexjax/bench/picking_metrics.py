"""The benchmark's figures of merit (seed, "Characterization of Grasping Benchmark"): reliability, mean picks per
hour, per-object reliability with 95 % intervals (Fig. S2) and object difficulty across policies (Fig. S3).

Everything here is plain Python on the per-attempt records of `dexjax.bench` (dicts as written to
``attempts.jsonl``): a record needs ``policy``, ``level``, ``object`` (the name of the object the grasp aimed at,
or None), ``success`` (the verdict that advanced the trial), ``plan_seconds`` and ``motion_seconds``; and, for the
judges' agreement, ``analytic`` and ``physics`` (booleans, or None where a judge did not run).

Reliability is successes / attempts. Mean picks per hour (MPPH) is successes per hour of robot time, the time of
an attempt being its measured planning time plus the motion time of `MotionModel` (the seed's robot); it equals
reliability x attempts per hour. The seed's error bars are the standard error of the mean (`sem_interval`);
`wilson_interval` is the better-behaved interval for few attempts or reliabilities near 0 or 1, reported beside it.
"""

from __future__ import annotations

import dataclasses
import math
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

Z_95 = 1.959963984540054
"""The standard normal quantile of a two-sided 95 % interval."""


def reliability(successes: int, attempts: int) -> float:
  """successes / attempts; NaN for no attempts."""
  return successes / attempts if attempts else math.nan


def sem_interval(successes: int, attempts: int, z: float = Z_95) -> tuple[float, float]:
  """The seed's interval: p ± z · sqrt(p (1 - p) / n) (standard error of the mean), clipped to [0, 1]."""
  if not attempts:
    return (math.nan, math.nan)
  p = successes / attempts
  half = z * math.sqrt(p * (1.0 - p) / attempts)
  return (max(0.0, p - half), min(1.0, p + half))


def wilson_interval(successes: int, attempts: int, z: float = Z_95) -> tuple[float, float]:
  """Wilson's score interval for a binomial proportion (z = 1.96: 95 %)."""
  if not attempts:
    return (math.nan, math.nan)
  n, p, z2 = attempts, successes / attempts, z * z
  centre = (p + z2 / (2 * n)) / (1 + z2 / n)
  half = z / (1 + z2 / n) * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n))
  return (max(0.0, centre - half), min(1.0, centre + half))


def move_seconds(distance: float, speed: float, acceleration: float) -> float:
  """Time (s) of a straight point-to-point move of ``distance`` (m) starting and ending at rest, with a
  trapezoidal speed profile of top speed ``speed`` (m/s) and ``acceleration`` (m/s²) (triangular when short)."""
  if distance <= 0.0:
    return 0.0
  ramp = speed * speed / acceleration  # distance spent accelerating and braking at full speed
  if distance <= ramp:
    return 2.0 * math.sqrt(distance / acceleration)
  return 2.0 * speed / acceleration + (distance - ramp) / speed


@dataclasses.dataclass(frozen=True)
class MotionModel:
  """The robot time of one pick attempt, after planning: the seed's ABB YuMi (maximum tool speed 1.5 m/s).

  The tool moves from a home pose ``approach_height`` above the bin floor to the grasp, closes the gripper (or
  builds the vacuum), lifts ``lift_height``, transports ``transport_distance`` to the receptacle beside the bin,
  releases and returns home; each straight move follows `move_seconds` with ``tool_speed`` and
  ``acceleration``. The final approach and the lift move at ``slow_speed`` (a cautious contact phase). A failed
  attempt costs the same path (the robot completes its motion; the seed counts every attempt).

  Attributes:
    tool_speed: top tool speed, m/s (the YuMi's 1.5).
    acceleration: tool acceleration, m/s² (assumed: full speed in 0.3 s).
    slow_speed: top speed of the final approach and the lift, m/s.
    approach_height: height of the home pose above the grasp, m.
    approach_distance: length of the slow final approach along the grasp axis, m.
    lift_height: lift after grasping, m (the benchmark's lift).
    transport_distance: grasp to receptacle, m (bin centre to a receptacle at its side).
    actuation_seconds: gripper close / vacuum on, and again to release, s each.
  """

  tool_speed: float = 1.5
  acceleration: float = 5.0
  slow_speed: float = 0.25
  approach_height: float = 0.3
  approach_distance: float = 0.05
  lift_height: float = 0.2
  transport_distance: float = 0.4
  actuation_seconds: float = 0.3

  def attempt_seconds(self) -> float:
    """Robot time (s) of one attempt: home -> pre-grasp -> grasp -> lift -> receptacle -> release -> home."""
    fast = lambda d: move_seconds(d, self.tool_speed, self.acceleration)
    slow = lambda d: move_seconds(d, self.slow_speed, self.acceleration)
    return (fast(self.approach_height - self.approach_distance) + slow(self.approach_distance)
            + self.actuation_seconds + slow(self.lift_height) + fast(self.transport_distance)
            + self.actuation_seconds + fast(math.hypot(self.transport_distance, self.approach_height - self.lift_height)))


def _agreement(records: Sequence[Mapping[str, Any]]) -> tuple[float, int]:
  """(fraction of attempts both judges gave the same verdict, attempts judged by both)."""
  both = [r for r in records if r.get('analytic') is not None and r.get('physics') is not None]
  same = sum(bool(r['analytic']) == bool(r['physics']) for r in both)
  return (same / len(both) if both else math.nan), len(both)


def _counts(records: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
  attempts, successes = len(records), sum(bool(r['success']) for r in records)
  lo, hi = sem_interval(successes, attempts)
  wlo, whi = wilson_interval(successes, attempts)
  return {'attempts': attempts, 'successes': successes, 'reliability': reliability(successes, attempts),
          'sem_95': [lo, hi], 'wilson_95': [wlo, whi]}


def summarize(records: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
  """Per-policy results of attempt records: ``{policy: {reliability, mpph, attempts, successes,
  judge_agreement, judged_by_both, seconds_per_attempt, plan_seconds, per_level: {level: counts},
  per_object: {object: counts}}}`` (counts: attempts, successes, reliability, sem_95, wilson_95)."""
  by_policy: dict[str, list[Mapping[str, Any]]] = defaultdict(list)
  for r in records:
    by_policy[r['policy']].append(r)
  out = {}
  for policy, rows in sorted(by_policy.items()):
    entry = _counts(rows)
    plan = sum(float(r['plan_seconds']) for r in rows)
    total = plan + sum(float(r['motion_seconds']) for r in rows)
    entry['mpph'] = 3600.0 * entry['successes'] / total if total > 0 else math.nan
    entry['seconds_per_attempt'] = total / len(rows)
    entry['plan_seconds'] = plan / len(rows)
    entry['judge_agreement'], entry['judged_by_both'] = _agreement(rows)
    entry['per_level'] = {str(level): _counts([r for r in rows if r['level'] == level])
                          for level in sorted({r['level'] for r in rows}, key=str)}
    entry['per_object'] = {name: _counts([r for r in rows if r['object'] == name])
                           for name in sorted({r['object'] for r in rows if r['object'] is not None})}
    out[policy] = entry
  return out


def object_difficulty(summary: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, float]]:
  """Fig. S3: each object's reliability averaged over the policies that attempted it, with the standard error
  of that mean (0 for one policy): ``{object: {'reliability', 'sem', 'policies'}}``, hardest first."""
  values: dict[str, list[float]] = defaultdict(list)
  for entry in summary.values():
    for name, counts in entry['per_object'].items():
      values[name].append(counts['reliability'])
  out = {}
  for name, vs in values.items():
    mean = sum(vs) / len(vs)
    sem = math.sqrt(sum((v - mean) ** 2 for v in vs) / (len(vs) - 1) / len(vs)) if len(vs) > 1 else 0.0
    out[name] = {'reliability': mean, 'sem': sem, 'policies': len(vs)}
  return dict(sorted(out.items(), key=lambda kv: (kv[1]['reliability'], kv[0])))


__all__ = ['MotionModel', 'Z_95', 'move_seconds', 'object_difficulty', 'reliability', 'sem_interval', 'summarize',
           'wilson_interval']
