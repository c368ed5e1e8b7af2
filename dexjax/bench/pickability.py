"""Can each object of a set be picked when it lies alone in the bin?

An object neither gripper can pick as it lies is a defect of a benchmark's set (a level-1 box no policy lifts
measures the set, not the policies). For every object of a `PickingWorld`, ``drops`` trials each drop it alone
into the bin (`PickingWorld.fill` with its index: it comes to rest in one of its stable poses, drawn as the heap's
drops are), and the supervisor (`dexjax.bench.SupervisorPolicy`: the true state, both grippers, its best effort
when no grasp passes) tries to pick it for up to ``attempts`` attempts, each judged by both judges, the physics
judge advancing the trial (`dexjax.bench.run_trial`: a failed attempt leaves the object where physics put it).

Per object: the drops in which it was picked, those picked at the first attempt, those whose first grasp the
labels' reward accepts (the analytic judge), those with no grasp at all, the grippers that picked it and the
physics judge's failure reasons. An object picked in none of its drops is reported as not pickable.
"""

from __future__ import annotations

import collections
import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

from dexjax.bench.judges import Judge
from dexjax.bench.protocol import Protocol
from dexjax.bench.trial import NO_GRASP, run_trial, trial_fill, trial_key
from dexjax.bench.world import PickingWorld


@dataclasses.dataclass(frozen=True)
class ObjectPickability:
  """How one object fared alone in the bin (counts over its drops).

  Attributes:
    name: the object's name; level: its difficulty level (None outside the procedural levels).
    mass: its simulated mass, kg.
    drops: trials, each a fresh drop of the object alone.
    picked: drops in which the physics judge saw it lifted and delivered within the attempts.
    first_attempt: drops picked at the first attempt.
    labels_pass: drops whose first grasp the labels' reward accepts (the analytic judge).
    no_grasp: drops in which the policy found no grasp at the first attempt.
    attempts: attempts over all drops.
    grippers: successful picks per gripper name.
    failures: the physics judge's failure reasons over all failed attempts (``no_grasp`` included).
  """

  name: str
  level: int | None
  mass: float
  drops: int
  picked: int
  first_attempt: int
  labels_pass: int
  no_grasp: int
  attempts: int
  grippers: Mapping[str, int]
  failures: Mapping[str, int]

  @property
  def pickable(self) -> bool:
    """Picked in at least one drop."""
    return self.picked > 0

  def to_json(self) -> dict[str, Any]:
    return {**dataclasses.asdict(self), 'grippers': dict(self.grippers), 'failures': dict(self.failures),
            'pickable': self.pickable}


def _summary(world: PickingWorld, object_id: int, trials: list[list[dict[str, Any]]]) -> ObjectPickability:
  firsts = [records[0] for records in trials if records]
  executed = [r for records in trials for r in records]
  grippers = collections.Counter(r['gripper'] for r in executed if r['success'])
  failures = collections.Counter(r['reason'] for r in executed if not r['success'])
  mass = float(world.bodies[object_id].mass)
  return ObjectPickability(
      name=world.names[object_id], level=world.levels[object_id], mass=mass, drops=len(trials),
      picked=sum(any(r['success'] for r in records) for records in trials),
      first_attempt=sum(bool(r['success']) for r in firsts),
      labels_pass=sum(bool(r['analytic']) for r in firsts),
      no_grasp=sum(r['reason'] == NO_GRASP for r in firsts), attempts=len(executed),
      grippers=dict(sorted(grippers.items())), failures=dict(sorted(failures.items())))


def object_pickability(world: PickingWorld, planner: Any, judges: Mapping[str, Judge], object_id: int, *,
                       drops: int = 3, attempts: int = 3, seed: int = 0, policy: str = 'supervisor'
                       ) -> ObjectPickability:
  """Drops object ``object_id`` of ``world`` alone into the bin ``drops`` times and lets ``planner`` try to
  pick it, at most ``attempts`` times per drop (see the module doc).

  Args:
    world: the objects, physics and renderer (``world.names[object_id]`` is the object).
    planner: the policy (`dexjax.bench.run_trial`'s planner; the supervisor for the set's check).
    judges: ``{'analytic': ..., 'physics': ...}``; the physics judge advances the trials.
    object_id: the object's index in ``world.names``.
    drops: trials per object; attempts: attempts per trial (both >= 1).
    seed: trial ``object_id * drops + d`` of this seed draws drop d's pose, camera and keys.
    policy: the policy's name (recorded).

  Raises:
    ValueError: ``drops`` or ``attempts`` below 1, or ``object_id`` not an object of ``world``.
  """
  protocol = Protocol(objects_per_trial=1, trials=drops, max_attempts=attempts,
                      max_consecutive_failures=attempts).validate()
  if not 0 <= object_id < len(world.names):
    raise ValueError(f'object_id: expected an index in [0, {len(world.names)}), got {object_id}')
  trials = []
  for d in range(drops):
    trial = object_id * drops + d
    start = trial_fill(world, trial_key(seed, trial), 1, object_ids=[object_id])
    # An object that left the bin as it fell gets no attempt: run_trial stops at once on the empty bin.
    trials.append(run_trial(world, planner, judges, policy=policy, trial=trial, seed=seed, advance_by='physics',
                            protocol=protocol, start=start))
  return _summary(world, object_id, trials)


def set_pickability(world: PickingWorld, planner: Any, judges: Mapping[str, Judge], *, drops: int = 3,
                    attempts: int = 3, seed: int = 0,
                    progress: Callable[[ObjectPickability], None] | None = None) -> list[ObjectPickability]:
  """`object_pickability` of every object of ``world``, in order (``progress`` is called after each)."""
  rows = []
  for i in range(len(world.names)):
    rows.append(object_pickability(world, planner, judges, i, drops=drops, attempts=attempts, seed=seed))
    if progress is not None:
      progress(rows[-1])
  return rows


def pickability_summary(rows: list[ObjectPickability]) -> dict[str, Any]:
  """Counts over a set: objects, pickable ones, the names of those picked in no drop, and the fractions of drops
  picked, picked at the first attempt and whose first grasp the labels accept."""
  drops = sum(r.drops for r in rows)
  frac = lambda field: round(sum(getattr(r, field) for r in rows) / drops, 4) if drops else None
  return {'objects': len(rows), 'pickable': sum(r.pickable for r in rows),
          'not_pickable': [r.name for r in rows if not r.pickable], 'drops': drops, 'picked': frac('picked'),
          'first_attempt': frac('first_attempt'), 'labels_pass': frac('labels_pass')}


__all__ = ['ObjectPickability', 'object_pickability', 'pickability_summary', 'set_pickability']
