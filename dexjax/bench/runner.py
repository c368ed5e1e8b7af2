"""The benchmark: every policy's trials on the same seeded bins, in parallel, resumable, summarised.

`run_benchmark` runs trial t of policy p for every pair (p, t) not finished in ``OUT/attempts.jsonl``, as one task
each (`dexjax.generate.run_tasks`: serially, on spawned processes, or on Ray), then summarises the log into
``OUT/results.json`` and draws the figures. Trial t's bin, camera and keys depend only on the seed and t, so every
policy meets the same bins (a paired comparison) and a killed run resumes each trial at its next attempt with the
same verdicts (`dexjax.bench.run_trial`).

Each worker process builds the `PickingWorld` and the jitted planners once and keeps them for its later tasks.
Process and serial workers append every attempt to the log themselves (`append_attempt` locks the file); Ray
workers, which may run on other machines, return their trial's records and the driver appends them when the trial
ends. ``OUT/benchmark.json`` holds the run's settings; resuming with different settings is refused, naming them.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
from collections import defaultdict
from pathlib import Path
from typing import Any

from dexjax.bench.attempt_log import append_attempt, read_attempts
from dexjax.bench.execution import PhysicsSettings
from dexjax.bench.failure_memory import FailureMemory
from dexjax.bench.world import BENCHMARK_HULLS
from dexjax.objects.collision import HullSettings
from dexjax.bench.judges import analytic_judge, physics_judge
from dexjax.bench.picking_metrics import MotionModel, object_difficulty, summarize
from dexjax.bench.protocol import Protocol
from dexjax.config import plain_json
from dexjax.generate.config import GenerateConfig
from dexjax.policy.presets import POLICY_NAMES, PRIVILEGED_POLICIES

JUDGES = ('physics', 'analytic')

#: Sensor noise of the benchmark's depth images (unless a config sets its own): correlated per-pixel noise of
#: 0.5 mm and 1 % of pixels dropped (holes, inpainted by the policies as a real cell's). The seed's sensor is a
#: Photoneo PhoXi S: local planarity 0.16 mm, global planarity 0.22 mm and temporal noise 0.03 mm at its 442 mm
#: sweet spot (its datasheet as transcribed in a public repository; not checked against the maker's sheet); a
#: triangulating sensor's depth error grows with the square of the distance, so at the seed's camera distances
#: (0.7-0.9 m) the local planarity is 0.4-0.7 mm. gqcnn's 5 mm is a training augmentation; the 1 % dropout is a
#: guess. Until 2026-12-06 the benchmark used 1 mm, a guess (docs/benchmark.md).
BENCHMARK_NOISE_SETTINGS = {'use_gp': True, 'gp_sigma': 0.0005, 'use_dropout': True, 'dropout_rate': 0.01}
SETTINGS_FILE, LOG_FILE, RESULTS_FILE = 'benchmark.json', 'attempts.jsonl', 'results.json'


@dataclasses.dataclass(frozen=True)
class BenchmarkSpec:
  """What a benchmark run compares, and how.

  Attributes:
    policies: policy names (`dexjax.policy.POLICY_NAMES`), each run on every trial.
    config: the bins' objects, bin, settling physics, camera distribution, sensor noise, grippers and reward
      (a `GenerateConfig`; the benchmark turns sensor noise on unless the caller configured it).
    protocol: trials, objects per trial and stopping rules (`Protocol`, the seed's).
    judge: ``'physics'`` or ``'analytic'``: whose verdict advances the trial (both are recorded).
    model: the GQ-CNNs of the learned policies: ``'pretrained'`` or a training run / model path.
    cem: CEM preset (``'seed'`` or ``'gqcnn'``).
    seed: the benchmark's seed (bins, cameras and every attempt's keys).
    known_mass: the analytic judge uses each object's simulated mass (see `analytic_judge`).
    physics: the physics judge's settings; its robot model (``physics.path.motion``) also times the attempts
      for picks per hour.
    memory: the policies' memory of failed grasps (`FailureMemory`; off by default, as the seed's protocol).
    grip_decomposition: the objects' convex decomposition the physics judge's gripper meets near the grasp
      (`dexjax.bench.BENCHMARK_HULLS`).
  """

  policies: tuple[str, ...]
  config: GenerateConfig
  protocol: Protocol = Protocol()
  judge: str = 'physics'
  model: str = 'pretrained'
  cem: str = 'seed'
  seed: int = 0
  known_mass: bool = False
  physics: PhysicsSettings = PhysicsSettings()
  memory: FailureMemory = FailureMemory()
  grip_decomposition: HullSettings = BENCHMARK_HULLS

  @property
  def motion(self) -> MotionModel:
    """The robot model of the physics judge's path and of picks per hour."""
    return self.physics.path.motion

  def validate(self) -> BenchmarkSpec:
    """Raises ValueError naming the field and the expected value."""
    if not self.policies:
      raise ValueError('policies: expected at least one policy')
    bad = [p for p in self.policies if p not in POLICY_NAMES]
    if bad:
      raise ValueError(f'policy: expected one of {", ".join(POLICY_NAMES)}, got {bad[0]!r}')
    if len(set(self.policies)) != len(self.policies):
      raise ValueError(f'policies: each policy once, got {list(self.policies)}')
    if self.judge not in JUDGES:
      raise ValueError(f'judge: expected one of {", ".join(JUDGES)}, got {self.judge!r}')
    self.protocol.validate()
    self.memory.validate()
    self.physics.path.validate()
    return self

  def settings_json(self) -> dict[str, Any]:
    """The run's settings as plain JSON (what resuming must match), with a short fingerprint of the config."""
    config = plain_json(dataclasses.asdict(self.config))
    digest = hashlib.sha256(json.dumps(config, sort_keys=True).encode()).hexdigest()[:16]
    model = self.model if self.model == 'pretrained' else os.fspath(Path(self.model).absolute())
    return {'policies': list(self.policies), 'objects': list(self.config.objects.sources),
            'protocol': dataclasses.asdict(self.protocol), 'judge': self.judge, 'model': model, 'cem': self.cem,
            'seed': self.seed, 'known_mass': self.known_mass, 'physics': plain_json(dataclasses.asdict(self.physics)),
            'memory': dataclasses.asdict(self.memory),
            'grip_decomposition': dataclasses.asdict(self.grip_decomposition),
            'config_fingerprint': digest}


def benchmark_noise() -> Any:
  """The benchmark's default `SensorNoise` (`BENCHMARK_NOISE_SETTINGS`)."""
  from dexjax.render.noise import SensorNoise  # pylint: disable=g-import-not-at-top
  return SensorNoise(**BENCHMARK_NOISE_SETTINGS)


def benchmark_config(objects: str | list[str] | tuple[str, ...], config: GenerateConfig | None = None,
                     noise: bool = True) -> GenerateConfig:
  """``config`` (default: Dex-Net 4.0's `GenerateConfig`) with the benchmark's ``objects`` (one source or a
  sequence of sources) and, with ``noise``, the benchmark's sensor noise (`benchmark_noise`); without, noise-free
  images."""
  from dexjax.render.noise import SensorNoise  # pylint: disable=g-import-not-at-top
  config = GenerateConfig() if config is None else config
  sources = (objects,) if isinstance(objects, str) else tuple(objects)  # a string is one source, not its letters
  return dataclasses.replace(config, objects=dataclasses.replace(config.objects, sources=sources),
                             noise=benchmark_noise() if noise else SensorNoise())


def pairs(spec: BenchmarkSpec) -> list[tuple[str, int]]:
  """Every (policy, trial) of the run, in task-index order."""
  return [(p, t) for p in spec.policies for t in range(spec.protocol.trials)]


_WORKER: dict[str, Any] = {}  # the current process's world and planners, built by its first task


def _worker_state(spec: BenchmarkSpec, cache_dir: str | None) -> dict[str, Any]:
  key = json.dumps(spec.settings_json(), sort_keys=True)
  if _WORKER.get('key') != key:
    import jax  # pylint: disable=g-import-not-at-top (workers import JAX on their first task)
    from dexjax.bench.world import PickingWorld  # pylint: disable=g-import-not-at-top
    from dexjax.models.shipped import load_models  # pylint: disable=g-import-not-at-top
    from dexjax.policy.composite import plan_grasp  # pylint: disable=g-import-not-at-top
    from dexjax.policy.presets import make_policy, uses_models  # pylint: disable=g-import-not-at-top
    release_worker()
    world = PickingWorld(spec.config, cache_dir=cache_dir, grip_decomposition=spec.grip_decomposition)
    models = load_models(spec.model) if any(uses_models(p) for p in spec.policies) else {}
    plan = jax.jit(plan_grasp)
    planners = {}
    for name in spec.policies:
      policy = make_policy(name, models if uses_models(name) else {}, cem=spec.cem, world=world)
      privileged = getattr(policy, 'privileged', False)  # the supervisor plans on the true bin (run_trial)
      planners[name] = policy if privileged else functools.partial(lambda key, obs, p: plan(key, obs, p), p=policy)
    judges = {'analytic': analytic_judge(world, known_mass=spec.known_mass),
              'physics': physics_judge(world, spec.physics)}
    _WORKER.update(key=key, world=world, planners=planners, judges=judges)
  return _WORKER


def release_worker() -> None:
  """Closes and forgets this process's benchmark world and planners (built by its first trial task), if any."""
  if 'world' in _WORKER:
    _WORKER['world'].close()
  _WORKER.clear()


def _trial_task(spec: BenchmarkSpec, log_path: str, cache_dir: str | None, append: bool, index: int) -> dict:
  """Runs (or resumes) the trial of task ``index``; returns its records when the driver appends them."""
  from dexjax.bench.trial import run_trial  # pylint: disable=g-import-not-at-top
  from dexjax.compile_cache import persistent_compilation_cache  # pylint: disable=g-import-not-at-top
  policy, trial = pairs(spec)[index]
  logged = [r for r in read_attempts(log_path) if r['policy'] == policy and r['trial'] == trial]
  logged.sort(key=lambda r: r['attempt'])
  with persistent_compilation_cache():
    state = _worker_state(spec, cache_dir)
    records = run_trial(state['world'], state['planners'][policy], state['judges'], policy=policy, trial=trial,
                        seed=spec.seed, advance_by=spec.judge, protocol=spec.protocol, motion=spec.motion,
                        log_path=log_path if append else None, logged=logged, memory=spec.memory)
  return {'records': [] if append else records[len(logged):], 'attempts': len(records)}


def _check_settings(out: Path, settings: dict[str, Any]) -> None:
  path = out / SETTINGS_FILE
  if path.exists():
    try:
      old = json.loads(path.read_text())
    except ValueError as e:
      raise ValueError(f'{path}: expected the JSON settings of a benchmark run ({e})') from e
    changed = sorted(k for k in set(old) | set(settings) if old.get(k) != settings.get(k))
    if changed:
      raise ValueError(f'{out}: holds a benchmark run with other settings ({", ".join(changed)}); resume with the '
                       'same settings, or choose another --out')
  else:
    _write_json(path, settings)


def _write_json(path: Path, data: Any) -> None:
  from dexjax.cli import atomic_write  # pylint: disable=g-import-not-at-top
  text = json.dumps(plain_json(data, nan_to_none=True), indent=1, sort_keys=True, allow_nan=False) + '\n'
  atomic_write(path, lambda f: f.write(text.encode()))


def check_objects(spec: BenchmarkSpec, cache_dir: str | os.PathLike[str] | None = None) -> list[str]:
  """Prepares (and caches) the object set, its collision hulls and (with the supervisor among the policies) its
  grasp sets here, before any worker starts; returns the usable objects' names.

  Raises:
    ValueError: a malformed source, no usable object, or more objects per trial than usable objects.
  """
  from dexjax.generate.pipeline import usable_objects  # pylint: disable=g-import-not-at-top
  from dexjax.objects.collision import cached_collision_hulls  # pylint: disable=g-import-not-at-top
  prepared, rejected = usable_objects(spec.config, cache_dir)
  for p in prepared:  # the judge's finer decomposition, computed here once instead of in every worker
    cached_collision_hulls(p.mesh, cache_dir=cache_dir, **spec.grip_decomposition.kwargs())
  if any(p in PRIVILEGED_POLICIES for p in spec.policies):  # and the supervisor's grasp sets
    from dexjax.bench.supervisor_policy import policy_grasp_sets  # pylint: disable=g-import-not-at-top
    policy_grasp_sets(spec.config, [p.model for p in prepared], cache_dir)
  if spec.protocol.objects_per_trial > len(prepared):
    skipped = f' ({len(rejected)} rejected: ' + '; '.join(f'{r.file}: {r.reason}' for r in rejected[:3]) + ')'
    raise ValueError(f'objects per trial (--per-trial): expected at most {len(prepared)}, the usable objects of '
                     f'{list(spec.config.objects.sources)}{skipped if rejected else ""}, got '
                     f'{spec.protocol.objects_per_trial}')
  return [p.name for p in prepared]


def unfinished(records: list[dict[str, Any]], spec: BenchmarkSpec) -> list[int]:
  """Task indices whose trial has not ended in ``records``."""
  ended = {(r['policy'], r['trial']) for r in records if r['stop'] is not None}
  return [i for i, pair in enumerate(pairs(spec)) if pair not in ended]


def run_benchmark(spec: BenchmarkSpec, out_dir: str | os.PathLike[str], *, workers: int = 1,
                  backend: str | None = None, ray_address: str | None = None,
                  cache_dir: str | os.PathLike[str] | None = None, progress: bool = True,
                  figures: bool = True) -> dict[str, Any]:
  """Runs (or resumes) the benchmark into ``out_dir``; returns the results (also written to results.json).

  Raises:
    ValueError: invalid settings, or ``out_dir`` holds a run with other settings.
  """
  from dexjax.generate.parallel import run_tasks  # pylint: disable=g-import-not-at-top
  spec.validate()
  check_objects(spec, cache_dir)
  out = Path(out_dir)
  out.mkdir(parents=True, exist_ok=True)
  settings = spec.settings_json()
  _check_settings(out, settings)
  log = out / LOG_FILE
  records = read_attempts(log, repair=True)
  todo = unfinished(records, spec)
  append = backend != 'ray'
  task = functools.partial(_trial_task, spec, os.fspath(log), None if cache_dir is None else os.fspath(cache_dir),
                           append)

  def on_result(index: int, result: dict) -> None:
    for record in result['records']:
      append_attempt(log, record)

  try:
    run = run_tasks(task, todo, backend=backend, workers=workers, progress=progress, on_result=on_result,
                    ray_address=ray_address, description='trials')
  finally:
    release_worker()  # a serial run built the world here: free its renderer and compiled planners
  records = read_attempts(log)
  results = summarize_run(records, spec, settings)
  results['failed_trials'] = {f'{pairs(spec)[i][0]}/{pairs(spec)[i][1]}': msg for i, msg in run.failures.items()}
  _write_json(out / RESULTS_FILE, results)
  if figures and records:
    from dexjax.bench.figures import save_figures  # pylint: disable=g-import-not-at-top (matplotlib)
    results['figures'] = save_figures(results, out)
    _write_json(out / RESULTS_FILE, results)
  return results


def summarize_run(records: list[dict[str, Any]], spec: BenchmarkSpec, settings: dict[str, Any]) -> dict[str, Any]:
  """results.json's content: per-policy metrics (`summarize`) with the mean seconds per attempt of each stage
  (render, plan, each judge, settle), how trials ended, each judge's failure reasons and whether the policy used
  privileged state; object difficulty (over the policies without privileged state, when there are any); the
  settings."""
  policies = summarize(records)
  ends: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
  for r in records:
    if r['stop'] is not None:
      ends[r['policy']][r['stop']] += 1
  reasons: dict[str, dict[str, dict[str, int]]] = {}
  for r in records:
    for judge, verdict in r['verdicts'].items():
      table = reasons.setdefault(r['policy'], {}).setdefault(judge, {})
      table[verdict['reason']] = table.get(verdict['reason'], 0) + 1
  stages: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
  for r in records:
    for stage, seconds in r.get('stage_seconds', {}).items():
      stages[r['policy']][stage].append(float(seconds))
  for name, entry in policies.items():
    entry['stage_seconds'] = {k: sum(v) / len(v) for k, v in sorted(stages[name].items())}
    entry['trial_ends'] = dict(ends[name])
    entry['failure_reasons'] = reasons.get(name, {})
    entry['trials_finished'] = sum(ends[name].values())
    entry['privileged'] = name in PRIVILEGED_POLICIES
  deployable = {k: v for k, v in policies.items() if not v['privileged']} or policies
  return {'policies': policies, 'object_difficulty': object_difficulty(deployable), 'config': settings}


__all__ = ['BENCHMARK_NOISE_SETTINGS', 'BenchmarkSpec', 'JUDGES', 'LOG_FILE', 'RESULTS_FILE', 'SETTINGS_FILE',
           'benchmark_config', 'benchmark_noise', 'check_objects', 'pairs', 'release_worker', 'run_benchmark',
           'summarize_run', 'unfinished']
