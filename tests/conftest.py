"""Shared fixtures: object models of the built-in shapes, built once per test session (small grids)."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=1")
# One OpenMP / BLAS thread per process: xdist runs two workers on this machine's two cores, and an OpenMP team that
# spins waiting for a core the other worker holds is many times slower than one thread (scikit-learn's Barnes-Hut
# t-SNE in notebooks/analysis.ipynb: 9 s alone, 73 s beside a busy JAX process with two threads, 8 s with one;
# 2026-12-05). Set before NumPy or scikit-learn loads; notebook kernels and CLI subprocesses inherit it.
os.environ.setdefault("OMP_NUM_THREADS", "1")


MIN_CACHED_COMPILE_S = 0.0  # the test session's persistent-cache threshold: every program (JAX's default: 1 s)


def _share_compiled_programs():
  """JAX's persistent compilation cache in ``$DEXJAX_CACHE/jax`` (the one the CLIs use) for the whole session: a
  program compiled by one test file is loaded, not compiled again, by a later file (`_release_compiled_programs`
  drops the in-memory copies after each file), by the other xdist worker and by notebook kernels. Every compilation
  is kept (`MIN_CACHED_COMPILE_S`; the CLIs keep those over 1 s): compiling is most of the suite's time, and most of
  it is small programs. tests/test_policy.py compiled 1,044 programs in 155 s, 1,001 of them under 0.2 s (46 s in
  all); with every program kept, that file ran in 186 s from an empty cache and in 41 s from a full one (2026-12-05).
  CI starts from an empty ``$DEXJAX_CACHE``, so each program is still compiled once there.

  Both settings are also exported (``JAX_COMPILATION_CACHE_DIR``, ``JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS``),
  so child processes use the same cache: CLIs run as subprocesses, generation and benchmark workers (local and
  Ray) and notebook kernels; `dexjax.compile_cache.persistent_compilation_cache` keeps a cache and a lower
  threshold the process already has. A test that changes ``$DEXJAX_CACHE`` (objects) keeps this cache."""
  from dexjax.compile_cache import default_compilation_cache_dir  # pylint: disable=import-outside-toplevel
  os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", default_compilation_cache_dir())
  os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", str(MIN_CACHED_COMPILE_S))
  import jax  # pylint: disable=import-outside-toplevel
  jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
  jax.config.update("jax_persistent_cache_min_compile_time_secs",
                    float(os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"]))


_share_compiled_programs()

GRID = 64  # small grids keep the suite fast; the library default is 100


@pytest.fixture(scope="session")
def cache_dir(tmp_path_factory):
  return tmp_path_factory.mktemp("object_cache")


def _model(name, cache_dir):
  from dexjax.objects import load_object_model
  return load_object_model(f"builtin:{name}", cache_dir=cache_dir, grid_size=GRID)


@pytest.fixture(scope="session")
def cube(cache_dir):
  return _model("cube", cache_dir)


@pytest.fixture(scope="session")
def box(cache_dir):
  return _model("box", cache_dir)


@pytest.fixture(scope="session")
def box_with_hole(cache_dir):
  return _model("box_with_hole", cache_dir)


@pytest.fixture(scope="session")
def sphere(cache_dir):
  return _model("sphere", cache_dir)


@pytest.fixture(scope="session")
def cylinder(cache_dir):
  return _model("cylinder", cache_dir)


def _reflect_about_grasp_pixel(crop, rows, cols):
  """Reference: explicit pixel loops of i -> S - i along the chosen axes of crop (S, S, C); outside the crop is 0."""
  import numpy as np
  s = crop.shape[0]
  out = np.zeros_like(crop)
  for r in range(s):
    for c in range(s):
      sr, sc = (s - r if rows else r), (s - c if cols else c)
      if 0 <= sr < s and 0 <= sc < s:
        out[r, c] = crop[sr, sc]
  return out


def _numpy_symmetric_view(crop, rotate, flip_lr, flip_ud):
  """Reference view of a grasp crop (S, S, C): an optional 180-degree turn about the grasp pixel (S/2, S/2), then
  optional left-right and up-down flips, each by `_reflect_about_grasp_pixel`."""
  if rotate:
    crop = _reflect_about_grasp_pixel(crop, True, True)
  if flip_lr:
    crop = _reflect_about_grasp_pixel(crop, False, True)
  if flip_ud:
    crop = _reflect_about_grasp_pixel(crop, True, False)
  return crop


@pytest.fixture(scope="session")
def numpy_symmetric_view():
  """The NumPy reference of `dexjax.models.symmetry.symmetric_view`'s crop: f(crop, rotate, flip_lr, flip_ud)."""
  return _numpy_symmetric_view


@pytest.fixture
def run_notebook(tmp_path, cache_dir, monkeypatch):
  """f(name, parameters=None, values=None) -> `notebook_kernel.NotebookRun`: ``notebooks/<name>`` executed in a real
  Jupyter kernel with its parameter cell overridden, ``values`` (name -> expression) evaluated in the kernel at the
  end; the kernel's object cache is the session's ``cache_dir``. See tests/notebook_kernel.py."""
  from notebook_kernel import run_notebook as run  # pylint: disable=import-outside-toplevel
  monkeypatch.setenv("DEXJAX_CACHE", str(cache_dir))
  monkeypatch.delenv("DEXJAX_MODEL", raising=False)  # the shipped models

  def _run(name, parameters=None, values=None, timeout=1200):
    return run(name, tmp_path, parameters, values, timeout)
  return _run


@pytest.fixture(scope="module", autouse=True)
def _release_compiled_programs():
  """After each test file, drops JAX's compiled programs and traces (jitted functions recompile, or load from the
  persistent cache, when a later file calls them). A worker runs dozens of files; keeping everything every file
  compiled grew each worker to 7 GB by the end of the suite."""
  yield
  if os.environ.get("DEXJAX_TEST_KEEP_COMPILED"):
    return
  import gc
  import jax
  jax.clear_caches()
  gc.collect()
