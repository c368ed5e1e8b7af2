"""The seed's benchmark protocol: how many trials, how many objects, and when a trial ends.

Seed ("Characterization of Grasping Benchmark", Procedure): five independent trials per policy; in each, the bin
is filled with the objects and the robot attempts to pick them one by one; "a trial is considered complete after
either all objects are removed, 75 total attempts, or 10 consecutive failures". The experiments used 25 objects
per difficulty level. One rule is added (docs/deviations.md): a policy may report that it finds no grasp (the
seed's always acted); the attempt counts as a failure and the trial ends there, instead of repeating the same
empty answer on an unchanged bin until ten failures end it.
"""

from __future__ import annotations

import dataclasses

STOP_REASONS = ('empty', 'max_attempts', 'consecutive_failures', 'no_grasp')
"""Why a trial ended: the bin is empty, the attempt budget is spent, too many failures in a row, or the policy found
no grasp (`run_trial`: the robot does not move, so the bin, and a deterministic policy's answer, would not change).
"""


@dataclasses.dataclass(frozen=True)
class Protocol:
  """Trial settings (defaults: the seed's).

  Attributes:
    objects_per_trial: objects put in the bin at the start of a trial (drawn without replacement from the set;
      all of it when the set has exactly this many).
    trials: independent trials per policy.
    max_attempts: a trial ends after this many attempts.
    max_consecutive_failures: a trial ends after this many failed attempts in a row.
  """

  objects_per_trial: int = 25
  trials: int = 5
  max_attempts: int = 75
  max_consecutive_failures: int = 10

  def validate(self) -> Protocol:
    """Raises ValueError naming the field when a setting is not a positive integer."""
    for field in dataclasses.fields(self):
      value = getattr(self, field.name)
      if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise ValueError(f'Protocol.{field.name}: expected an integer >= 1, got {value!r}')
    return self


def stop_reason(objects_left: int, attempts: int, consecutive_failures: int, protocol: Protocol) -> str | None:
  """Why the trial ends now (one of `STOP_REASONS`), or None to attempt again. An empty bin wins over the
  other two when they coincide (the last object was picked on the last allowed attempt)."""
  if objects_left == 0:
    return 'empty'
  if attempts >= protocol.max_attempts:
    return 'max_attempts'
  if consecutive_failures >= protocol.max_consecutive_failures:
    return 'consecutive_failures'
  return None


__all__ = ['Protocol', 'STOP_REASONS', 'stop_reason']
