"""Run one task per index (e.g. one dataset shard each) serially, on spawned processes, or on Ray.

`run_tasks` calls ``task(index)`` for every index and collects the small picklable dicts it returns. A task that
raises does not stop the others: its exception type, message and the last lines of its traceback land in
`RunResult.failures`. Results reach the parent as they finish, through an optional ``on_result`` callback (e.g.
to accumulate `dexjax.generate.report.RowStats`) and a tqdm bar on stderr.

Backends:

* ``serial``: an in-process loop (the default for ``workers == 1``).
* ``process``: a `concurrent.futures.ProcessPoolExecutor` with the ``spawn`` start method (JAX is not fork-safe);
  the children get the parent's ``sys.path``. A child that dies (e.g. killed for memory) breaks the pool, and
  every index not finished by then is reported as failed with that error. The children die with their parent
  (`die_with_parent`): a parent killed even with SIGKILL leaves no worker behind (each holds a compiled
  labeller, ~1.6 GB); their half-written shards are temporary files, removed by the next run.
* ``ray``: tasks on a Ray instance: a fresh local one with ``num_cpus=workers`` (no dashboard; its workers get
  the parent's ``sys.path`` through ``PYTHONPATH``), or the cluster at ``ray_address``. If Ray is already
  initialised in this process, that instance is used. Only an instance started here is shut down here.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import multiprocessing
import os
import sys
import time
import traceback
import warnings
from collections.abc import Callable, Iterable
from typing import Any

from tqdm import tqdm

BACKENDS = ("serial", "process", "ray")
_TRACEBACK_LINES = 6
_RAY_INSTALL = "pip install 'dexjax[ray]'"
_PR_SET_PDEATHSIG = 1  # linux/prctl.h
_PARENT_POLL_SECONDS = 1.0


@dataclasses.dataclass
class RunResult:
  """Outcome of `run_tasks`.

  Attributes:
    results: index -> the dict its task returned, for the indices that succeeded.
    failures: index -> "ExceptionType: message" and the last lines of the traceback, for those that raised.
    seconds: wall time of the run, seconds.
    backend: the backend used.
  """

  results: dict[int, dict] = dataclasses.field(default_factory=dict)
  failures: dict[int, str] = dataclasses.field(default_factory=dict)
  seconds: float = 0.0
  backend: str = "serial"

  @property
  def ok(self) -> bool:
    """True when no index failed."""
    return not self.failures


def describe_exception(error: BaseException) -> str:
  """"Type: message" of ``error`` and the last lines of its formatted traceback (chained causes included)."""
  lines = "".join(traceback.format_exception(error)).rstrip().splitlines()
  tail = "\n".join(lines[-_TRACEBACK_LINES:])
  return f"{type(error).__name__}: {error}\n{tail}"


def _call(task: Callable[[int], dict], index: int) -> tuple[bool, Any]:
  """Runs ``task(index)`` and returns (True, result) or (False, description); runs in the worker, so the
  traceback is the worker's and unpicklable exceptions never cross the process boundary."""
  try:
    return True, task(index)
  except Exception as error:  # every task error is reported per index; the run goes on
    return False, describe_exception(error)


class _Collector:
  """Files each outcome into a `RunResult`, advances the bar and calls ``on_result`` for successes."""

  def __init__(self, run: RunResult, bar: tqdm, on_result: Callable[[int, dict], None] | None):
    self.run, self.bar, self.on_result = run, bar, on_result

  def add(self, index: int, ok: bool, value: Any) -> None:
    if ok:
      self.run.results[index] = value
      if self.on_result is not None:
        self.on_result(index, value)
    else:
      self.run.failures[index] = value
    self.bar.update(1)
    if self.run.failures:
      self.bar.set_postfix(failed=len(self.run.failures), refresh=False)


def run_tasks(task: Callable[[int], dict], indices: Iterable[int], *, backend: str | None = None, workers: int = 2,
              progress: bool = True, on_result: Callable[[int, dict], None] | None = None,
              ray_address: str | None = None, description: str = "tasks") -> RunResult:
  """Calls ``task(index)`` for every index on ``workers`` workers and collects the results.

  Args:
    task: a picklable top-level function (or `functools.partial` of one) of an int index returning a small
      picklable dict.
    indices: the indices to run (duplicates are run once).
    backend: 'serial', 'process' or 'ray'; None picks 'serial' for ``workers <= 1`` and 'process' otherwise.
    workers: parallel workers (processes, or Ray CPUs of a local instance).
    progress: show a tqdm bar of finished tasks on stderr.
    on_result: called in this process as ``on_result(index, result)`` for each success, as it arrives.
    ray_address: address of an existing Ray cluster (backend 'ray' only); default: start a local instance.
    description: label of the progress bar.

  Raises:
    ValueError: unknown backend or ``workers < 1``.
    ImportError: backend 'ray' without Ray installed.
  """
  if backend is None:
    backend = "serial" if workers <= 1 else "process"
  if backend not in BACKENDS:
    raise ValueError(f"backend: expected one of {BACKENDS}, got {backend!r}")
  if workers < 1:
    raise ValueError(f"workers: expected >= 1, got {workers}")
  order = list(dict.fromkeys(int(i) for i in indices))
  run = RunResult(backend=backend)
  start = time.perf_counter()
  started = backend == "ray" and start_ray(workers, ray_address)  # before the bar: Ray prints while starting
  try:
    with tqdm(total=len(order), desc=description, unit="task", disable=not progress, file=sys.stderr) as bar:
      collector = _Collector(run, bar, on_result)
      if backend == "serial":
        for index in order:
          collector.add(index, *_call(task, index))
      elif backend == "process":
        _run_processes(task, order, workers, collector)
      else:
        _run_ray(task, order, collector)
  finally:
    if started:
      _import_ray().shutdown()
  run.seconds = time.perf_counter() - start
  return run


# Run by each process-backend worker as its pool initializer, through the builtin ``exec`` (so the worker runs it
# right after start-up, before it imports dexjax (several seconds) to unpickle its first task): die with the parent.
# On Linux the kernel sends SIGKILL to the worker when its parent exits (prctl PR_SET_PDEATHSIG; works even while
# the worker is busy in compiled code); elsewhere a daemon thread polls os.getppid() every second. A parent already
# gone when this runs (a race at start-up) ends the worker at once. Mesh-scale and imperfect-mesh warnings are the
# parent's (it loaded the same objects first), so the workers do not repeat them.
_WORKER_INIT = """
import ctypes, os, signal, sys, threading, time, warnings
armed = False
if sys.platform.startswith('linux'):
  try:
    armed = ctypes.CDLL(None, use_errno=True).prctl({option}, signal.SIGKILL, 0, 0, 0) == 0
  except (OSError, AttributeError):
    armed = False
if os.getppid() != {parent_pid}:
  os._exit(1)
if not armed:
  def watch_parent():
    while os.getppid() == {parent_pid}:
      time.sleep({poll})
    os._exit(1)
  threading.Thread(target=watch_parent, name='dexjax-parent-watchdog', daemon=True).start()
warnings.filterwarnings('ignore', message="mesh '.*': largest extent")
warnings.filterwarnings('ignore', message="mesh '.*': .*loaded as the solid its generalized winding number")
"""


def die_with_parent(parent_pid: int) -> None:
  """Makes this (worker) process exit when the process ``parent_pid`` that started it dies, however it dies
  (SIGKILL included); see ``_WORKER_INIT``. `run_tasks`' process workers do this before anything else."""
  exec(_worker_init_code(parent_pid), {})  # pylint: disable=exec-used (our own constant code)


def _worker_init_code(parent_pid: int) -> str:
  return _WORKER_INIT.format(option=_PR_SET_PDEATHSIG, parent_pid=int(parent_pid), poll=_PARENT_POLL_SECONDS)


def _run_processes(task, order: list[int], workers: int, collector: _Collector) -> None:
  if not order:
    return
  context = multiprocessing.get_context("spawn")
  with concurrent.futures.ProcessPoolExecutor(max_workers=min(workers, len(order)), mp_context=context,
                                              initializer=exec, initargs=(_worker_init_code(os.getpid()), {})) as pool:
    futures = {pool.submit(_call, task, index): index for index in order}
    for future in concurrent.futures.as_completed(futures):
      index = futures[future]
      try:
        ok, value = future.result()
      except Exception as error:  # the task could not be sent, or its worker died (BrokenProcessPool)
        ok, value = False, describe_exception(error)
      collector.add(index, ok, value)


def _import_ray():
  try:
    import ray
  except ImportError as error:
    raise ImportError(f"backend 'ray' needs Ray, which is not installed: {_RAY_INSTALL}") from error
  return ray


def start_ray(workers: int = 2, address: str | None = None) -> bool:
  """Initialises Ray unless it already is; returns True when this call started (connected) it.

  Without ``address`` a fresh local instance with ``num_cpus=workers`` and no dashboard is started, whose
  workers import from this process's ``sys.path``; with it, the cluster at ``address`` is joined.
  """
  ray = _import_ray()
  if ray.is_initialized():
    return False
  if address is not None:
    ray.init(address=address, log_to_driver=True)
    return True
  saved = os.environ.get("PYTHONPATH")
  os.environ["PYTHONPATH"] = os.pathsep.join(p or os.getcwd() for p in sys.path)  # inherited by Ray's workers
  try:
    with warnings.catch_warnings():  # JAX warns of os.fork; Ray's daemons are fork + exec subprocesses, safe
      warnings.filterwarnings("ignore", message="os.fork", category=RuntimeWarning)
      ray.init(address="local", num_cpus=workers, include_dashboard=False, log_to_driver=True,
               configure_logging=False)
  finally:
    if saved is None:
      os.environ.pop("PYTHONPATH", None)
    else:
      os.environ["PYTHONPATH"] = saved
  return True


def _run_ray(task, order: list[int], collector: _Collector) -> None:
  ray = _import_ray()
  remote = ray.remote(num_cpus=1, max_retries=1)(_call)  # retried once only if its worker dies
  pending = {remote.remote(task, index): index for index in order}
  while pending:
    done, _ = ray.wait(list(pending), num_returns=1)
    for ref in done:
      index = pending.pop(ref)
      try:
        ok, value = ray.get(ref)
      except Exception as error:  # the worker died or the task could not run (ray.exceptions.RayError)
        ok, value = False, describe_exception(error)
      collector.add(index, ok, value)
