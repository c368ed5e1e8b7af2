"""Replaying a recorded benchmark attempt: the same bin, camera, grasp and keys, judged again.

A benchmark run is deterministic given its settings: trial t's bin and camera come from the run's seed and t
(`trial_key`, `trial_fill`, `trial_camera`), every attempt's keys from the trial's key and the attempt's number
(`attempt_keys`), and each attempt's record holds the bin it left behind (``state``) and the policy's grasp. So
attempt k of trial t starts from the state recorded with attempt k - 1 (the trial's fill for k = 0), and judging
its recorded grasp there again must give the recorded verdicts. That is what a researcher needs to trace a failure
(the judge's settings, the bin and the grasp of one attempt, to instrument or vary) and what checks that a run on
this machine reproduces: `replay_attempt`, and ``python -m dexjax.replay``.

* `spec_from_settings`: the run's `BenchmarkSpec` from its ``benchmark.json`` and the bins' config, checked to give
  back exactly those settings (a run made with another config, or by another version, is refused by name).
* `recorded_attempt`: the bin before attempt k, the trial's camera, the grasp and the attempt's judging key.
* `replay_attempt`: both judges' verdicts on it (`benchmark_judges`, the run's order of keys).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp

from dexjax.bench.execution import PhysicsSettings
from dexjax.bench.failure_memory import FailureMemory
from dexjax.bench.judges import Verdict
from dexjax.bench.protocol import Protocol
from dexjax.bench.runner import BenchmarkSpec, benchmark_judges
from dexjax.bench.trial import attempt_keys, trial_camera, trial_fill, trial_key
from dexjax.bench.world import BinState, PickingWorld
from dexjax.generate.config import GenerateConfig
from dexjax.objects.collision import HullSettings
from dexjax.policy.actions import GraspAction
from dexjax.policy.scorers import GRIPPERS
from dexjax.render.camera import Camera


def _dataclass_from_json(cls: type, data: Mapping[str, Any], where: str) -> Any:
  """``cls`` (a dataclass whose nested dataclass fields have dataclass defaults) from its `dataclasses.asdict`."""
  if not isinstance(data, Mapping):
    raise ValueError(f'{where}: expected an object of settings, got {type(data).__name__}')
  fields = {f.name: f for f in dataclasses.fields(cls)}
  unknown = sorted(set(data) - set(fields))
  if unknown:
    raise ValueError(f'{where}.{unknown[0]}: not a setting of this version of dexjax (expected one of '
                     f'{", ".join(sorted(fields))})')
  values = {}
  for name, value in data.items():
    default = fields[name].default
    if dataclasses.is_dataclass(default) and isinstance(value, Mapping):
      value = _dataclass_from_json(type(default), value, f'{where}.{name}')
    values[name] = value
  return cls(**values)


def spec_from_settings(settings: Mapping[str, Any], config: GenerateConfig) -> BenchmarkSpec:
  """The `BenchmarkSpec` of a run whose ``benchmark.json`` holds ``settings``, with ``config`` the bins' config
  (`load_benchmark_config` with the run's objects and the config files and noise it was made with).

  Raises ValueError naming the first setting that does not come back the same (``config_fingerprint``: ``config``
  is not the one the run was made with).
  """
  try:
    spec = BenchmarkSpec(
        policies=tuple(settings['policies']), config=config,
        protocol=_dataclass_from_json(Protocol, settings['protocol'], 'protocol'), judge=settings['judge'],
        model=settings['model'], cem=settings['cem'], seed=settings['seed'], known_mass=settings['known_mass'],
        supervisor_loads=settings['supervisor_loads'], supervisor_fallback=settings['supervisor_fallback'],
        supervisor_lift_first=settings['supervisor_lift_first'],
        physics=_dataclass_from_json(PhysicsSettings, settings['physics'], 'physics'),
        memory=_dataclass_from_json(FailureMemory, settings['memory'], 'memory'),
        grip_decomposition=_dataclass_from_json(HullSettings, settings['grip_decomposition'], 'grip_decomposition'))
  except KeyError as e:
    raise ValueError(f'{e.args[0]}: missing from the run\'s settings (benchmark.json)') from None
  except TypeError as e:
    raise ValueError(f'benchmark.json: settings of another shape than this version of dexjax writes ({e})') from None
  again = json.loads(json.dumps(spec.settings_json()))
  for key, value in settings.items():
    if again.get(key) != value:
      hint = (' (the run was made with another --config, --camera-config or --no-noise, or other objects)'
              if key == 'config_fingerprint' else '')
      raise ValueError(f'{key}: the run has {json.dumps(value)}, these settings give {json.dumps(again.get(key))}'
                       f'{hint}')
  return spec


def recorded_action(record: Mapping[str, Any], jaw_width: float) -> GraspAction | None:
  """The concrete `GraspAction` an attempt's record holds (None for a "no grasp" attempt). Records written before
  the jaws' opening was recorded (``width``) get ``jaw_width`` (m; the image samplers' opening)."""
  if record.get('gripper') is None:
    return None
  gripper = GRIPPERS.index(record['gripper'])
  width = record.get('width')
  if width is None:
    width = jaw_width if record['gripper'] == 'parallel_jaw' else 0.0
  return GraspAction(gripper=jnp.int32(gripper), center=jnp.asarray(record['center'], jnp.float32),
                     angle=jnp.float32(record['angle']), depth=jnp.float32(record['depth']),
                     approach_angle=jnp.float32(record['approach_angle']), width=jnp.float32(width),
                     pose=jnp.eye(4, dtype=jnp.float32), probability=jnp.float32(record['q']), valid=jnp.bool_(True))


@dataclasses.dataclass(frozen=True)
class RecordedAttempt:
  """What attempt ``record['attempt']`` of a trial was judged on.

  Attributes:
    record: the attempt's record (``attempts.jsonl``).
    state: the bin before the attempt.
    camera: the trial's camera (the image the grasp was planned on).
    action: the policy's grasp (None: the policy found none).
    judge_key: the attempt's judging key (`attempt_keys`).
  """

  record: Mapping[str, Any]
  state: BinState
  camera: Camera
  action: GraspAction | None
  judge_key: jax.Array


def recorded_attempt(world: PickingWorld, spec: BenchmarkSpec, records: Sequence[Mapping[str, Any]], policy: str,
                     trial: int, attempt: int) -> RecordedAttempt:
  """Attempt ``attempt`` of ``policy``'s trial ``trial`` in a run's ``records`` (its attempt log), with the bin it
  started from. Raises ValueError naming the policy, trial or attempt the log does not hold."""
  mine = {r['attempt']: r for r in records if r['policy'] == policy and r['trial'] == trial}
  if not mine:
    held = sorted({(r['policy'], r['trial']) for r in records})
    raise ValueError(f'--policy {policy} --trial {trial}: not in the run\'s attempt log (it holds '
                     f'{", ".join(f"{p} trial {t}" for p, t in held) or "no attempt"})')
  if attempt not in mine:
    raise ValueError(f'--attempt: expected 0-{max(mine)} (the attempts of {policy}\'s trial {trial}), got {attempt}')
  key = trial_key(spec.seed, trial)
  if attempt == 0:
    state = trial_fill(world, key, spec.protocol.objects_per_trial)
  else:
    state = BinState.from_json(mine[attempt - 1]['state'])
  return RecordedAttempt(record=mine[attempt], state=state, camera=trial_camera(world, key),
                         action=recorded_action(mine[attempt], world.params.parallel_jaw.max_width),
                         judge_key=attempt_keys(key, attempt)[2])


def replay_attempt(world: PickingWorld, spec: BenchmarkSpec, attempt: RecordedAttempt,
                   judges: Mapping[str, Any] | None = None) -> dict[str, Verdict]:
  """Each judge's verdict on the recorded attempt, judged again (name -> `Verdict`). ``judges``: name -> judge
  (`dexjax.bench.judges`); default the run's (`benchmark_judges`), whose keys are those of the run."""
  judges = benchmark_judges(world, spec) if judges is None else judges
  if attempt.action is None:
    return {}
  return {name: judge(jax.random.fold_in(attempt.judge_key, index), attempt.action, attempt.camera,
                      attempt.state)[0]
          for index, (name, judge) in enumerate(judges.items())}


__all__ = ['RecordedAttempt', 'recorded_action', 'recorded_attempt', 'replay_attempt', 'spec_from_settings']
