"""The MJX settling backend: ``jax.jit(jax.vmap(settle_one))`` over heaps that share one object set.

Batching: MJX needs one model structure (bodies, geoms, meshes) per compiled function, so heaps are grouped
by their object set (the sorted object ids; bodies are ordered by id, so the order of slots does not matter).
Within a group, drop poses enter as ``qpos`` and each heap's friction as a batched ``geom_friction``; one
compiled function serves the whole group, in batches of ``settings.mjx_batch_size`` heaps (the last batch is padded by
repeating a heap, so every call has the same shape). Each distinct set compiles once (35-200 s on this
CPU), so MJX pays off for many drops of the same objects or on an accelerator; the object sets of a
Dex-Net-style dataset (m of N >> m objects) are nearly all distinct, and the `rollout` backend is the right
choice on a CPU.

Early stop: a `jax.lax.while_loop` steps until every object of the heap rests or ``max_steps``; under `vmap`
the loop runs until the slowest heap of the batch stops while finished heaps are frozen (the step count and
final state of each heap are its own).

Deadlock guard: batched MJX deadlocked on a 2-core CPU inside a batched LAPACK Cholesky (all threads waiting
on a futex, 0 % CPU; reproduced here at 5 objects, batch 64). On CPU, `run` therefore executes the work in a
child process (``python -m dexjax.sim._mjx_worker``) pinned to one core before JAX starts, which avoided the
deadlock in every trial, and kills it after ``settings.mjx_timeout`` seconds (raising `SettleTimeout`), so a
hang can never block a caller or CI (the child compiles afresh on every call). On an accelerator the work runs
in-process, where the 8 most recently compiled functions stay cached.
"""

from __future__ import annotations

import collections
import os
import pickle
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from dexjax.sim.bodies import HeapObject
from dexjax.sim.heap import HeapState, select_heap
from dexjax.sim.rest import resting
from dexjax.sim.scene import SettleSettings, build_heap_model, heap_slots, initial_qpos


class SettleTimeout(TimeoutError):
  """The MJX child process did not finish within ``SettleSettings.mjx_timeout`` seconds and was killed."""


def _group_key(state: HeapState) -> tuple[int, ...]:
  ids = np.asarray(state.object_ids)
  return tuple(int(ids[s]) for s in heap_slots(state))


def _geom_friction(model: mujoco.MjModel, state: HeapState) -> np.ndarray:
  """(ngeom, 3) friction of ``model`` with each object geom's sliding friction set from ``state``."""
  friction = np.array(model.geom_friction)
  slots = heap_slots(state)
  mu = np.clip(np.asarray(state.friction, np.float64), mujoco.mjMINMU, None)
  body = model.geom_bodyid
  for k, slot in enumerate(slots):
    friction[body == k + 1, 0] = mu[slot]
  return friction


_COMPILED: collections.OrderedDict = collections.OrderedDict()
_COMPILED_MAX = 8


def _compiled(objects: Sequence[HeapObject], key: tuple[int, ...], model: mujoco.MjModel, coms: np.ndarray,
              settings: SettleSettings, q0: np.ndarray, gf: np.ndarray) -> tuple[Any, float]:
  """(compiled function, seconds spent compiling) for one object set and batch shape, cached in-process.

  The cache holds the 8 most recent functions and keeps the objects alive, so ``id()`` keys stay unique.
  """
  group = tuple(objects[i] for i in key)
  cache_key = (tuple(id(o) for o in group), key, settings, q0.shape)
  if cache_key in _COMPILED:
    _COMPILED.move_to_end(cache_key)
    return _COMPILED[cache_key][0], 0.0
  t = time.perf_counter()
  fn = _make_settle_batch(model, coms, settings).lower(q0, gf).compile()
  seconds = time.perf_counter() - t
  _COMPILED[cache_key] = (fn, group)
  while len(_COMPILED) > _COMPILED_MAX:
    _COMPILED.popitem(last=False)
  return fn, seconds


def _make_settle_batch(model: mujoco.MjModel, coms: np.ndarray, settings: SettleSettings):
  """A jitted ``(qpos0 (B, nq), geom_friction (B, ngeom, 3)) -> (qpos, qvel, steps, done)`` for one object set."""
  from mujoco import mjx  # deferred: importing MJX is slow and optional

  mx = mjx.put_model(model)
  coms = jnp.asarray(coms, jnp.float32)
  num_bodies = coms.shape[0]

  def settle_one(qpos0, geom_friction):
    m = mx.replace(geom_friction=geom_friction)
    d = mjx.make_data(m).replace(qpos=qpos0)

    def cond(carry):
      _, steps, done = carry
      return jnp.logical_and(jnp.logical_not(done), steps < settings.max_steps)

    def body(carry):
      d, steps, _ = carry
      d = mjx.step(m, d)
      rest = resting(d.qpos.reshape(num_bodies, 7), d.qvel.reshape(num_bodies, 6), coms, settings, jnp)
      return d, steps + 1, jnp.all(rest)

    d, steps, done = jax.lax.while_loop(cond, body, (d, jnp.int32(0), jnp.bool_(False)))
    return d.qpos, d.qvel, steps, done

  return jax.jit(jax.vmap(settle_one))


def settle_in_process(objects: Sequence[HeapObject], states: HeapState, settings: SettleSettings) -> dict[str, Any]:
  """Settles batched NumPy ``states`` with MJX in this process (no deadlock guard: see `run`).

  Heaps are grouped by object set; each group runs in calls of ``settings.mjx_batch_size`` heaps (fewer if the
  group is smaller).

  Returns:
    dict with per-heap lists ``qpos`` ((m_b * 7,) each), ``qvel`` ((m_b * 6,)), and arrays ``steps`` (B,),
    ``diverged`` (B,) bool, ``compile_seconds`` (float, compilation of the groups' functions) and
    ``run_seconds`` (float, the compiled calls).
  """
  batch = states.mask.shape[0]
  groups: dict[tuple[int, ...], list[int]] = {}
  for b in range(batch):
    groups.setdefault(_group_key(select_heap(states, b)), []).append(b)
  qpos: list[Any] = [None] * batch
  qvel: list[Any] = [None] * batch
  steps = np.zeros(batch, np.int32)
  diverged = np.zeros(batch, bool)
  compile_seconds = run_seconds = 0.0
  for key, members in groups.items():
    first = select_heap(states, members[0])
    model = build_heap_model(objects, first, settings)
    ids = np.asarray(first.object_ids)
    coms = np.stack([objects[int(ids[s])].center_of_mass for s in heap_slots(first)])
    size = min(settings.mjx_batch_size, len(members))
    fn = None
    for start in range(0, len(members), size):
      chunk = members[start:start + size]
      padded = chunk + [chunk[-1]] * (size - len(chunk))
      q0 = np.stack([initial_qpos(objects, select_heap(states, b), settings) for b in padded]).astype(np.float32)
      gf = np.stack([_geom_friction(model, select_heap(states, b)) for b in padded]).astype(np.float32)
      if fn is None:
        fn, seconds = _compiled(objects, key, model, coms, settings, q0, gf)
        compile_seconds += seconds
      t = time.perf_counter()
      out = jax.device_get(fn(q0, gf))
      run_seconds += time.perf_counter() - t
      for i, b in enumerate(chunk):
        qpos[b], qvel[b], steps[b] = out[0][i], out[1][i], out[2][i]
        diverged[b] = not (np.all(np.isfinite(out[0][i])) and np.all(np.isfinite(out[1][i])))
  return {'qpos': qpos, 'qvel': qvel, 'steps': steps, 'diverged': diverged, 'compile_seconds': compile_seconds,
          'run_seconds': run_seconds}


def pinned_python_command(args: Sequence[str], *, module: str | None = None, script: str | None = None,
                          single_core: bool = True, core: int | None = None) -> list[str]:
  """A command running ``python -m module`` (or ``python script``) with ``args``, pinned to one CPU core first.

  The pinning (`os.sched_setaffinity`, Linux) happens before anything imports JAX, so JAX's thread pools see a
  single core: the guard against the batched-MJX deadlock. Without ``sched_setaffinity`` it is a no-op.

  Args:
    core: index into the sorted allowed cores (wrapping around); default: the last allowed core.
  """
  if (module is None) == (script is None):
    raise ValueError('pinned_python_command: expected exactly one of module= or script=')
  pick = 'cpus[-1]' if core is None else f'cpus[{int(core)} % len(cpus)]'
  run = f'runpy.run_module({module!r}, run_name="__main__", alter_sys=True)' if module else \
      f'runpy.run_path({script!r}, run_name="__main__")'
  boot = ('import os, sys, runpy\n'
          'cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []\n'
          f'if {bool(single_core)} and cpus: os.sched_setaffinity(0, {{{pick}}})\n'
          f'sys.argv = [{(module or script)!r}] + sys.argv[1:]\n'
          f'{run}\n')
  return [sys.executable, '-c', boot, *args]


def _use_subprocess(settings: SettleSettings) -> bool:
  if settings.mjx_subprocess is not None:
    return bool(settings.mjx_subprocess)
  return jax.default_backend() == 'cpu'


def run(objects: Sequence[HeapObject], states: HeapState, settings: SettleSettings) -> dict[str, Any]:
  """Settles batched NumPy ``states`` with MJX, in a pinned child process with a timeout on CPU.

  Returns:
    The dict of `settle_in_process`.

  Raises:
    SettleTimeout: the child process ran longer than ``settings.mjx_timeout`` seconds (it is killed).
    RuntimeError: the child process failed (its stderr tail is in the message).
  """
  if not _use_subprocess(settings):
    return settle_in_process(objects, states, settings)
  with tempfile.TemporaryDirectory(prefix='dexjax_mjx_') as tmp:
    inp, out = os.path.join(tmp, 'in.pkl'), os.path.join(tmp, 'out.pkl')
    with open(inp, 'wb') as f:
      pickle.dump({'objects': list(objects), 'states': states, 'settings': settings}, f)
    cmd = pinned_python_command([inp, out], module='dexjax.sim._mjx_worker', single_core=settings.mjx_single_core)
    try:
      proc = subprocess.run(cmd, capture_output=True, text=True, timeout=settings.mjx_timeout)
    except subprocess.TimeoutExpired as e:
      raise SettleTimeout(f'settle(backend="mjx"): the MJX child process did not finish within '
                          f'SettleSettings.mjx_timeout = {settings.mjx_timeout} s and was killed (a batched MJX '
                          'deadlock or a long compile; try smaller batches or backend="rollout")') from e
    if proc.returncode != 0:
      raise RuntimeError(f'settle(backend="mjx"): the MJX child process failed with exit code {proc.returncode}:\n'
                         + proc.stderr[-4000:])
    with open(out, 'rb') as f:
      return pickle.load(f)
