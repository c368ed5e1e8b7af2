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

from dexjax.grippers import STANDARD_GRAVITY, SUCTION_PAYLOAD_KG, SUCTION_SAFETY_FACTOR
from dexjax.quality.robust import REWARD_THRESHOLD

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


#: Peak speed and peak acceleration of a minimum-jerk move of distance D and duration T, in units of D / T and
#: D / T²: s(tau) = 10 tau³ - 15 tau⁴ + 6 tau⁵ has s' <= 15/8 (at tau = 1/2) and |s''| <= 10 / sqrt(3).
MIN_JERK_PEAK_SPEED = 15.0 / 8.0
MIN_JERK_PEAK_ACCELERATION = 10.0 / math.sqrt(3.0)


def move_seconds(distance: float, speed: float, acceleration: float) -> float:
  """Time (s) of a straight point-to-point move of ``distance`` (m) starting and ending at rest along the
  minimum-jerk profile (Flash and Hogan 1985; smooth, as the robot's jerk-limited path planner) whose peak speed
  is at most ``speed`` (m/s) and peak acceleration at most ``acceleration`` (m/s²)."""
  if distance <= 0.0:
    return 0.0
  return max(MIN_JERK_PEAK_SPEED * distance / speed, math.sqrt(MIN_JERK_PEAK_ACCELERATION * distance / acceleration))


def rated_acceleration(payload: float = SUCTION_PAYLOAD_KG, safety: float = SUCTION_SAFETY_FACTOR,
                       friction: float = 0.8) -> float:
  """The largest tool acceleration (m/s²) at which a suction cup of ``payload`` kg (vacuum force payload x g) still
  holds the heaviest object it is rated for (payload / ``safety``) at its centre, within the labels' suction-ring
  limits (`dexjax.contacts.ring_limit_excess`), carried rigidly:

  * vertically (Schmalz's load case I, F = m (g + a)): the lip load V - m (g + a) stays >= 0, a <= g (S - 1);
  * horizontally (load case II, with the ring model's friction box): the shear m a stays within
    mu (V - m g) / sqrt(3), a <= mu g (S - 1) / sqrt(3).

  The seed's cup (0.9 kg, S = 1.5) with the seed's mean friction 0.8 gives min(4.9, 2.27) = 2.27 m/s².
  """
  vertical = STANDARD_GRAVITY * (safety - 1.0)
  return min(vertical, friction * vertical / math.sqrt(3.0))


@dataclasses.dataclass(frozen=True)
class MotionModel:
  """The robot time of one pick attempt, after planning: the seed's ABB YuMi (maximum tool speed 1.5 m/s).

  The tool moves from a home pose ``approach_height`` above the bin floor to the grasp, closes the gripper (or
  builds the vacuum), lifts ``lift_height``, transports ``transport_distance`` to the receptacle beside the bin,
  releases and returns home; each straight move follows `move_seconds` (minimum jerk) within ``tool_speed``
  and ``acceleration``. The final approach and the lift move at ``slow_speed`` (a cautious contact phase). A failed
  attempt costs the same path (the robot completes its motion; the seed counts every attempt).

  Attributes:
    tool_speed: top tool speed, m/s (the seed: the YuMi's maximum tool speed, 1.5).
    acceleration: peak tool acceleration, m/s² (`rated_acceleration`, 2.27): the fastest a cell may move the
      heaviest object the seed's cup is rated for (its 0.9 kg payload over the safety factor 1.5 that suction makers
      size cups with) without leaving the labels' own suction-ring limits. The YuMi itself accelerates its tool up
      to 11 m/s² (ABB's IRB 14000 data sheet; not re-checked here: no network); a cell moves a held object no
      faster than its gripper's rating allows (RAPID's ``AccSet`` lowers the acceleration for such loads).
    slow_speed: top speed of the final approach and the lift, m/s (a guess: a cautious contact phase; no source).
    approach_height: height of the home pose above the grasp, m (a guess).
    approach_distance: length of the slow final approach along the grasp axis, m (the pre-grasp standoff).
    lift_height: lift after grasping, m (clears the 10 cm bin walls with any object of the sets).
    transport_distance: bin centre to the receptacle beside the bin, m (the Dex-Net lab's YuMi driver, yumipy's
      ``YuMiConstants``, drops objects about 0.47 m from the bin's centre; 0.4 m keeps it within reach here).
    actuation_seconds: gripper close / vacuum on, and again to release, s each (a guess).
  """

  tool_speed: float = 1.5
  acceleration: float = rated_acceleration()
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
            + self.actuation_seconds
            + fast(math.hypot(self.transport_distance, self.approach_height - self.lift_height)))


CONFIDENT = REWARD_THRESHOLD
"""A predicted probability above this is a grasp the policy expects to succeed: the reward's threshold."""


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


def cleared_fraction(records: Sequence[Mapping[str, Any]]) -> float:
  """The mean over trials of the fraction of the bin's objects picked (successes / objects at the start); NaN
  without trials. Records need ``trial``, ``success`` and ``objects_at_start``."""
  trials: dict[Any, list[Mapping[str, Any]]] = defaultdict(list)
  for r in records:
    trials[r['trial']].append(r)
  fractions = [sum(bool(r['success']) for r in rows) / rows[0]['objects_at_start'] for rows in trials.values()
               if rows[0].get('objects_at_start')]
  return sum(fractions) / len(fractions) if fractions else math.nan


def summarize(records: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
  """Per-policy results of attempt records: ``{policy: {reliability, mpph, attempts, successes,
  judge_agreement, judged_by_both, judge_agreement_confident, judged_confident, seconds_per_attempt, plan_seconds,
  cleared, repeated_attempts, per_level: {level: counts}, per_object: {object: counts}}}`` (counts: attempts,
  successes, reliability, sem_95, wilson_95). ``judge_agreement_confident``: the judges' agreement on the attempts
  whose predicted probability ``q`` is above `CONFIDENT` (the grasps the policy expects to succeed; the
  supervisor's best efforts are scored at most 0.5). ``cleared``: `cleared_fraction`; ``repeated_attempts``:
  attempts that repeat an earlier failure of their trial (`dexjax.bench.repeated_attempts`); ``at_choice``: the
  precision of the chosen grasps and the calibration of ``q`` per judge (`dexjax.bench.choice_summary`)."""
  from dexjax.bench.choice_calibration import choice_summary  # pylint: disable=g-import-not-at-top (cycle)
  from dexjax.bench.failure_memory import repeated_attempts  # pylint: disable=g-import-not-at-top (NumPy)
  records = list(records)
  repeats = repeated_attempts(records)
  by_policy: dict[str, list[Mapping[str, Any]]] = defaultdict(list)
  repeated: dict[str, int] = defaultdict(int)
  for r, repeat in zip(records, repeats):
    by_policy[r['policy']].append(r)
    repeated[r['policy']] += repeat
  out = {}
  for policy, rows in sorted(by_policy.items()):
    entry = _counts(rows)
    plan = sum(float(r['plan_seconds']) for r in rows)
    total = plan + sum(float(r['motion_seconds']) for r in rows)
    entry['mpph'] = 3600.0 * entry['successes'] / total if total > 0 else math.nan
    entry['seconds_per_attempt'] = total / len(rows)
    entry['plan_seconds'] = plan / len(rows)
    entry['judge_agreement'], entry['judged_by_both'] = _agreement(rows)
    entry['judge_agreement_confident'], entry['judged_confident'] = _agreement(
        [r for r in rows if r.get('q') is not None and r['q'] > CONFIDENT])
    entry['cleared'] = cleared_fraction(rows)
    entry['at_choice'] = choice_summary(rows)
    entry['repeated_attempts'] = repeated[policy]
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


__all__ = ['CONFIDENT', 'MIN_JERK_PEAK_ACCELERATION', 'MIN_JERK_PEAK_SPEED', 'MotionModel', 'Z_95', 'cleared_fraction',
           'move_seconds', 'object_difficulty', 'rated_acceleration', 'reliability', 'sem_interval', 'summarize',
           'wilson_interval']
