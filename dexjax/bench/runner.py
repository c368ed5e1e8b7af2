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
Before anything is computed or written, `check_run_dir` makes sure a run never overwrites or adds to files it did
not write (OUT is new, empty, or a benchmark run's) and `check_models` loads the policies' GQ-CNNs.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
import re
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from dexjax.bench.attempt_log import RECORD_FIELDS, append_attempt, read_attempts
from dexjax.bench.execution import PhysicsSettings
from dexjax.bench.failure_memory import FailureMemory
from dexjax.bench.world import BENCHMARK_HULLS
from dexjax.cli import OutputError, check_output_dir, is_dexjax_png, stamp_png
from dexjax.objects.collision import HullSettings
from dexjax.bench.judges import analytic_judge, physics_judge
from dexjax.bench.picking_metrics import MotionModel, object_difficulty, summarize
from dexjax.bench.protocol import Protocol
from dexjax.config import parse_json, plain_json
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
FIGURE_FILES = ('reliability.png', 'per_object.png', 'difficulty.png', 'calibration.png')
#: Keys of ``benchmark.json`` (`BenchmarkSpec.settings_json`) and ``results.json`` (`summarize_run`) by which a
#: directory is recognised as a benchmark run's (`check_run_dir`).
SETTINGS_KEYS = ('policies', 'objects', 'protocol', 'judge', 'model', 'seed', 'config_fingerprint')
RESULTS_KEYS = ('policies', 'object_difficulty', 'config')
_TEMPORARY_FILE = re.compile(r'\..+\.tmp-.*')  # a file `dexjax.cli.atomic_write` was writing when killed


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
    supervisor_loads: the supervisor's reward makes the target carry its neighbours' resting load
      (`dexjax.bench.SupervisorPolicy.loads`; on by default).
    supervisor_fallback: the supervisor executes its best effort when no grasp passes its test instead of
      stopping the trial (`dexjax.bench.SupervisorPolicy.fallback`; on by default).
    supervisor_lift_first: among the grasps that pass, the supervisor takes those on objects that rise straight
      out of the heap first (`dexjax.bench.SupervisorPolicy.lift_first`; on by default).
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
  supervisor_loads: bool = True
  supervisor_fallback: bool = True
  supervisor_lift_first: bool = True
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
            'seed': self.seed, 'known_mass': self.known_mass, 'supervisor_loads': self.supervisor_loads,
            'supervisor_fallback': self.supervisor_fallback, 'supervisor_lift_first': self.supervisor_lift_first,
            'physics': plain_json(dataclasses.asdict(self.physics)),
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


def load_benchmark_config(objects: Sequence[str], config_path: str | None = None, camera_config: str | None = None,
                          noise: bool = True) -> GenerateConfig:
  """The bins' config as ``python -m dexjax.benchmark`` builds it: the generation config file ``config_path``
  (default: Dex-Net 4.0's values) with ``camera_config`` and the benchmark's ``objects``, validated; its sensor
  noise is the file's ``noise`` section when it has one, else the benchmark's (`benchmark_noise`); none at all
  without ``noise``. Raises ValueError (a bad file or value, named) or OSError (an unreadable file)."""
  from dexjax.config import load_yaml, validate_generate_config  # pylint: disable=g-import-not-at-top
  from dexjax.generate.config import load_generate_config  # pylint: disable=g-import-not-at-top
  config = load_generate_config(config_path, camera_config=camera_config, objects=list(objects))
  validate_generate_config(config, config_path or 'the default config')
  if noise and config_path is not None and 'noise' in (load_yaml(config_path) or {}):
    return config
  return benchmark_config(objects, config, noise=noise)


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
      if privileged:
        policy = dataclasses.replace(policy, loads=spec.supervisor_loads, fallback=spec.supervisor_fallback,
                                     lift_first=spec.supervisor_lift_first)
      planners[name] = policy if privileged else functools.partial(lambda key, obs, p: plan(key, obs, p), p=policy)
    judges = benchmark_judges(world, spec)
    _WORKER.update(key=key, world=world, planners=planners, judges=judges)
  return _WORKER


def benchmark_judges(world: Any, spec: BenchmarkSpec) -> dict[str, Any]:
  """The run's judges of ``world`` (a `PickingWorld`), in the order that draws their keys (`attempt_keys`):
  ``{'analytic': ..., 'physics': ...}``."""
  return {'analytic': analytic_judge(world, known_mass=spec.known_mass), 'physics': physics_judge(world, spec.physics)}


def release_worker() -> None:
  """Closes and forgets this process's benchmark world and planners (built by its first trial task), if any."""
  if 'world' in _WORKER:
    _WORKER['world'].close()
  _WORKER.clear()


def _trial_task(spec: BenchmarkSpec, log_path: str, cache_dir: str | None, append: bool, index: int) -> dict:
  """Runs (or resumes) the trial of task ``index``; returns its records when the driver appends them."""
  from dexjax.bench.trial import run_trial  # pylint: disable=g-import-not-at-top
  from dexjax.compile_cache import persistent_compilation_cache  # pylint: disable=g-import-not-at-top
  from dexjax.generate.run import file_system_error  # pylint: disable=g-import-not-at-top
  policy, trial = pairs(spec)[index]
  logged = [r for r in read_attempts(log_path, fields=RECORD_FIELDS) if (r['policy'], r['trial']) == (policy, trial)]
  logged.sort(key=lambda r: r['attempt'])
  try:
    with persistent_compilation_cache():
      state = _worker_state(spec, cache_dir)
      records = run_trial(state['world'], state['planners'][policy], state['judges'], policy=policy, trial=trial,
                          seed=spec.seed, advance_by=spec.judge, protocol=spec.protocol, motion=spec.motion,
                          log_path=log_path if append else None, logged=logged, memory=spec.memory)
  except OSError as e:  # disk full: the driver stops the run with one line naming the file (run_benchmark)
    recorded = file_system_error(e)
    if recorded is None:
      raise
    return {'records': [], 'attempts': len(logged), 'file_system_error': recorded}
  return {'records': [] if append else records[len(logged):], 'attempts': len(records)}


def _read_json_object(path: Path) -> dict[str, Any] | None:
  """The JSON object in ``path``; None if it is unreadable, not UTF-8 JSON or not an object."""
  try:
    data = parse_json(path.read_bytes().decode('utf-8'), str(path))
  except (OSError, ValueError):  # ConfigError (a ValueError): malformed, nested too deep, a key twice
    return None
  return data if isinstance(data, dict) else None


def _is_own(name: str, path: Path) -> bool:
  """Whether ``path`` (named ``name`` in a run directory) is a file a benchmark run wrote."""
  if name in FIGURE_FILES:
    try:
      return is_dexjax_png(path)
    except (OSError, ValueError):
      return False
  data = _read_json_object(path)
  keys = SETTINGS_KEYS if name == SETTINGS_FILE else RESULTS_KEYS
  return data is not None and all(k in data for k in keys)


def check_run_dir(out_dir: str | os.PathLike[str], settings: dict[str, Any] | None = None) -> Path:
  """Checks, before anything is computed or written, that a benchmark may write into ``out_dir``; returns it.

  ``out_dir`` must be a directory or not exist yet, under a writable directory. A new run needs it absent or
  empty; otherwise it must hold a benchmark run (its ``benchmark.json``, `SETTINGS_KEYS`), which is resumed: then
  ``results.json`` and the figures there must be the run's own (a results object; PNGs marked by dexjax),
  ``attempts.jsonl`` must be a whole attempt log, and with ``settings`` (`BenchmarkSpec.settings_json`) the run's
  settings must be these. Other files of a run directory are never written.

  Raises:
    OutputError: ``out_dir`` cannot be written, or holds files a benchmark did not write (naming one).
    ValueError: a damaged attempt log (naming the file and line), or a run with other settings (naming them).
  """
  out = check_output_dir(out_dir, option='--out')
  if not out.exists():
    return out
  entries = sorted(p.name for p in out.iterdir() if not _TEMPORARY_FILE.fullmatch(p.name))
  if entries and SETTINGS_FILE not in entries:
    shown = ', '.join(repr(n) for n in entries[:3]) + (', ...' if len(entries) > 3 else '')
    raise OutputError('--out', out, f'is not empty ({shown}) and holds no benchmark run (no {SETTINGS_FILE}); '
                                    'expected a new or empty directory, or the --out of a benchmark run to resume')
  for name in (SETTINGS_FILE, RESULTS_FILE) + FIGURE_FILES:
    if name in entries and not _is_own(name, out / name):
      raise OutputError('--out', out, f"holds a '{name}' this command did not write; expected a benchmark run's "
                                      f'own {name} (move the file away, or choose another --out)')
  read_attempts(out / LOG_FILE, fields=RECORD_FIELDS)  # a damaged log fails here, naming its file and line
  if settings is not None and SETTINGS_FILE in entries:
    old = _read_json_object(out / SETTINGS_FILE)
    changed = sorted(k for k in set(old) | set(settings) if old.get(k) != settings.get(k))
    if changed:
      raise ValueError(f'{out}: holds a benchmark run with other settings ({", ".join(changed)}); resume with the '
                       'same settings, or choose another --out')
  return out


def check_models(spec: BenchmarkSpec) -> None:
  """Loads the GQ-CNNs of the learned policies here, before any trial, so that a missing, damaged or incomplete
  ``spec.model`` fails once, naming the file, instead of failing every trial.

  Raises:
    FileNotFoundError, ValueError: nothing loadable at ``spec.model``, a damaged model, or no model of a gripper a
      policy needs (`dexjax.models.load_models`).
  """
  from dexjax.models.shipped import held_grippers, load_models  # pylint: disable=g-import-not-at-top
  from dexjax.policy.presets import required_grippers, uses_models  # pylint: disable=g-import-not-at-top
  learned = [p for p in spec.policies if uses_models(p)]
  if not learned:
    return
  models = load_models(spec.model)
  for name in learned:
    missing = [g for g in required_grippers(name) if g not in models]
    if missing:
      raise ValueError(f"--model: {spec.model}: policy {name!r} needs a GQ-CNN of {' and '.join(missing)} (has "
                       f"{held_grippers(spec.model, models)}); expected 'pretrained', a training run of these "
                       'grippers, or that gripper\'s saved model')


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
    ValueError: invalid settings, ``out_dir`` holds a run with other settings or a damaged attempt log, or the
      models cannot be loaded (`check_models`).
    OutputError: ``out_dir`` holds files a benchmark did not write (`check_run_dir`).
  """
  from dexjax.generate.parallel import run_tasks  # pylint: disable=g-import-not-at-top
  from dexjax.generate.run import raise_file_system_error  # pylint: disable=g-import-not-at-top
  spec.validate()
  settings = spec.settings_json()
  out = check_run_dir(out_dir, settings)
  check_models(spec)
  check_objects(spec, cache_dir)
  out.mkdir(parents=True, exist_ok=True)
  if not (out / SETTINGS_FILE).exists():
    _write_json(out / SETTINGS_FILE, settings)
  log = out / LOG_FILE
  records = read_attempts(log, repair=True, fields=RECORD_FIELDS)
  todo = unfinished(records, spec)
  append = backend != 'ray'
  task = functools.partial(_trial_task, spec, os.fspath(log), None if cache_dir is None else os.fspath(cache_dir),
                           append)

  def on_result(index: int, result: dict) -> None:
    for record in result['records']:
      append_attempt(log, record)
    raise_file_system_error(result)  # disk full: stop at once, one error line naming the file

  try:
    run = run_tasks(task, todo, backend=backend, workers=workers, progress=progress, on_result=on_result,
                    ray_address=ray_address, description='trials')
  finally:
    release_worker()  # a serial run built the world here: free its renderer and compiled planners
  records = read_attempts(log, fields=RECORD_FIELDS)
  results = summarize_run(records, spec, settings)
  results['failed_trials'] = {f'{pairs(spec)[i][0]}/{pairs(spec)[i][1]}': msg for i, msg in run.failures.items()}
  _write_json(out / RESULTS_FILE, results)
  if figures and records:
    results['figures'] = _save_figures(results, out)
    _write_json(out / RESULTS_FILE, results)
  return results


def _save_figures(results: dict[str, Any], out: Path) -> list[str]:
  """Draws the figures (`dexjax.bench.figures.save_figures`) into a temporary directory in ``out``, marks them as
  dexjax's (a resumed run recognises them, `check_run_dir`) and moves them into ``out``; returns their names.
  An `OSError` (disk full) names the figure it was writing."""
  import tempfile  # pylint: disable=g-import-not-at-top
  from dexjax.bench.figures import save_figures  # pylint: disable=g-import-not-at-top (matplotlib)
  with tempfile.TemporaryDirectory(dir=out, prefix='.figures.tmp-') as tmp:
    try:
      names = save_figures(results, tmp)
      for name in names:
        stamp_png(Path(tmp) / name, 'benchmark figure')
    except OSError as e:
      if e.errno is None:
        raise
      where = out / Path(e.filename).name if e.filename is not None else out
      raise OSError(e.errno, e.strerror, os.fspath(where)) from e
    for name in names:
      os.replace(Path(tmp) / name, out / name)
  return names


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


__all__ = ['BENCHMARK_NOISE_SETTINGS', 'BenchmarkSpec', 'FIGURE_FILES', 'JUDGES', 'LOG_FILE', 'RESULTS_FILE',
           'RESULTS_KEYS', 'SETTINGS_FILE', 'SETTINGS_KEYS', 'benchmark_config', 'benchmark_noise', 'check_models',
           'check_objects', 'check_run_dir', 'benchmark_judges', 'load_benchmark_config', 'pairs', 'release_worker',
           'run_benchmark', 'summarize_run', 'unfinished']
