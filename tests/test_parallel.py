"""run_tasks: every index runs once on the chosen backend, failures stay per index, results stream to the parent."""

from __future__ import annotations

import functools
import os
import sys

import pytest

from dexjax.generate.parallel import RunResult, describe_exception, run_tasks, start_ray

INDICES = [0, 1, 2, 3]
BAD = 2


def _task(index: int, out_dir: str, fail: int | None = None) -> dict:
  """Writes ``out_dir/<index>.txt`` and returns where it ran; raises for index ``fail``."""
  if index == fail:
    raise RuntimeError(f"shard {index} is broken")
  with open(os.path.join(out_dir, f"{index}.txt"), "w") as file:
    file.write(str(os.getpid()))
  return {"index": index, "pid": os.getpid()}


def _check_run(run: RunResult, tmp_path, backend: str, arrived: list) -> None:
  ok = [i for i in INDICES if i != BAD]
  assert run.backend == backend and not run.ok
  assert sorted(run.results) == ok and list(run.failures) == [BAD]
  assert all(run.results[i]["index"] == i for i in ok)
  assert sorted(p.name for p in tmp_path.iterdir()) == [f"{i}.txt" for i in ok]
  assert "RuntimeError: shard 2 is broken" in run.failures[BAD] and "_task" in run.failures[BAD]
  assert sorted(i for i, _ in arrived) == ok and all(r["index"] == i for i, r in arrived)  # once per success
  assert run.seconds > 0


def _run(tmp_path, backend: str, **kwargs) -> tuple[RunResult, list]:
  arrived: list = []
  task = functools.partial(_task, out_dir=str(tmp_path), fail=BAD)
  run = run_tasks(task, INDICES, backend=backend, workers=2, progress=False,
                  on_result=lambda i, r: arrived.append((i, r)), **kwargs)
  return run, arrived


def test_serial_runs_in_process_and_keeps_going(tmp_path):
  run, arrived = _run(tmp_path, "serial")
  _check_run(run, tmp_path, "serial", arrived)
  assert {r["pid"] for r in run.results.values()} == {os.getpid()}
  assert [i for i, _ in arrived] == [0, 1, 3]  # serial: in index order
  assert run_tasks(_task, [], workers=1, progress=False).results == {}


def test_process_backend_uses_other_processes(tmp_path):
  run, arrived = _run(tmp_path, "process")
  _check_run(run, tmp_path, "process", arrived)
  assert os.getpid() not in {r["pid"] for r in run.results.values()}


def test_bad_arguments_and_progress(tmp_path, capsys):
  with pytest.raises(ValueError, match="backend"):
    run_tasks(_task, INDICES, backend="threads")
  with pytest.raises(ValueError, match="workers"):
    run_tasks(_task, INDICES, backend="serial", workers=0)
  run = run_tasks(functools.partial(_task, out_dir=str(tmp_path)), [5, 5, 6], workers=1, description="shards")
  assert run.backend == "serial" and sorted(run.results) == [5, 6]  # duplicates run once
  err = capsys.readouterr().err
  assert "shards" in err and "2/2" in err  # the bar, on stderr


def test_describe_exception_names_type_message_and_place():
  try:
    _task(BAD, "/nonexistent", fail=BAD)
  except RuntimeError as error:
    text = describe_exception(error)
  assert text.startswith("RuntimeError: shard 2 is broken\n") and "test_parallel.py" in text


def test_ray_missing_is_a_clear_import_error(monkeypatch):
  monkeypatch.setitem(sys.modules, "ray", None)  # makes `import ray` raise ImportError
  with pytest.raises(ImportError, match=r"pip install 'dexjax\[ray\]'"):
    run_tasks(_task, INDICES, backend="ray", progress=False)


@pytest.fixture(scope="module")
def ray_instance():
  import ray  # the test extra installs it
  started = start_ray(workers=2)
  yield ray
  if started:
    ray.shutdown()


def test_ray_backend_on_a_local_instance(tmp_path, ray_instance):
  run, arrived = _run(tmp_path, "ray")
  _check_run(run, tmp_path, "ray", arrived)
  assert os.getpid() not in {r["pid"] for r in run.results.values()}
  assert ray_instance.is_initialized()  # an instance run_tasks did not start stays up
