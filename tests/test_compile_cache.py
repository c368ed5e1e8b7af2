"""`dexjax.compile_cache.persistent_compilation_cache`: where the CLIs keep compiled programs, and which threshold;
a warm cache prints none of XLA:CPU's false tuning-feature warnings, and every other line of standard error stays."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import pytest
from jax.experimental.compilation_cache import compilation_cache

from dexjax import compile_cache as cc
from dexjax.compile_cache import persistent_compilation_cache

_NAMES = ('jax_compilation_cache_dir', 'jax_persistent_cache_min_compile_time_secs')


@pytest.fixture
def jax_cache_settings():
  """Restores the session's cache settings (tests/conftest.py) after the test; JAX opens the cache again at the next
  compilation."""
  before = {name: getattr(jax.config, name) for name in _NAMES}
  yield
  for name, value in before.items():
    jax.config.update(name, value)
  compilation_cache.reset_cache()


def _settings():
  return tuple(getattr(jax.config, name) for name in _NAMES)


def test_without_a_jax_cache_the_block_uses_dexjax_cache_over_one_second(tmp_path, monkeypatch, jax_cache_settings):
  monkeypatch.setenv('DEXJAX_CACHE', str(tmp_path / 'objects'))
  jax.config.update(_NAMES[0], None)
  jax.config.update(_NAMES[1], 5.0)
  with persistent_compilation_cache():
    assert _settings() == (str(tmp_path / 'objects' / 'jax'), 1.0)
  assert _settings() == (None, 5.0)  # restored: later compilations are not written there


def test_a_cache_and_a_lower_threshold_the_process_has_are_kept(tmp_path, monkeypatch, jax_cache_settings):
  monkeypatch.setenv('DEXJAX_CACHE', str(tmp_path / 'objects'))
  mine = tmp_path / 'mine'
  jax.config.update(_NAMES[0], str(mine))
  jax.config.update(_NAMES[1], 0.0)
  with persistent_compilation_cache():
    assert _settings() == (str(mine), 0.0)
    jax.block_until_ready(jax.jit(lambda x: jnp.sin(x) * 3.25 + 0.125)(jnp.arange(7.0)))  # a program no test has
  assert _settings() == (str(mine), 0.0)
  assert any(mine.iterdir())  # the program went to the process's cache, not to $DEXJAX_CACHE/jax
  assert not (tmp_path / 'objects' / 'jax').exists()


_WARNING = ('E1206 12:01:29.878514    4680 cpu_aot_loader.cc:195] Loading XLA:CPU AOT result. Target machine feature '
            '{} is not  supported on the host machine. Machine type used for XLA:CPU compilation doesn\'t match the '
            'machine type for execution. Compile machine features: [+avx,+avx512f,+prefer-no-gather] vs host machine '
            'features: [avx,avx512f]. This could lead to execution errors such as SIGILL.')


def test_the_filter_drops_only_the_tuning_attribute_warnings():
  lines = [_WARNING.format('+prefer-no-gather'), 'W0000 other.cc:1] a warning', _WARNING.format('+prefer-no-scatter'),
           _WARNING.format('+avx512f'), _WARNING.format('+fast-gather'), 'Traceback (most recent call last):']
  read, write = os.pipe()
  out_read, out_write = os.pipe()
  os.write(write, ('\n'.join(lines) + '\nprogress 50%').encode())  # a partial last line is forwarded too
  os.close(write)
  cc.forward_without_tuning_warnings(read, out_write)
  os.close(out_write)
  forwarded = os.read(out_read, 1 << 16).decode().split('\n')
  assert forwarded == [lines[1], lines[3], lines[5], 'progress 50%']  # a real instruction-set feature stays
  for fd in (read, out_read):
    os.close(fd)


_CACHED_RUN = textwrap.dedent("""
    import os, jax, jax.numpy as jnp
    from dexjax.compile_cache import persistent_compilation_cache
    with persistent_compilation_cache():
      os.write(2, b'kept line\\n')
      jax.block_until_ready(jax.jit(lambda x: jnp.take(x, jnp.array([2, 0, 1])) * 1.75 - 0.5)(jnp.arange(3.0)))
    """)


def _cached_run(tmp_path, **extra) -> str:
  """Stderr of a process that runs a tiny jitted function in a `persistent_compilation_cache` block, with
  ``$DEXJAX_CACHE`` in ``tmp_path``, every program cached and no JAX cache of the test session."""
  env = {k: v for k, v in os.environ.items() if k != 'JAX_COMPILATION_CACHE_DIR'}
  env.update(DEXJAX_CACHE=str(tmp_path), JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS='0', JAX_PLATFORMS='cpu', **extra)
  done = subprocess.run([sys.executable, '-c', _CACHED_RUN], env=env, capture_output=True, text=True, timeout=300,
                        check=False)
  assert done.returncode == 0, done.stderr
  return done.stderr


def _has_avx512() -> bool:
  try:
    return 'avx512' in Path('/proc/cpuinfo').read_text()
  except OSError:
    return False


def test_a_warm_cache_prints_no_tuning_feature_warning(tmp_path):
  first = _cached_run(tmp_path)
  assert any((tmp_path / 'jax').iterdir())
  warm = _cached_run(tmp_path)  # loads the programs the first run wrote
  for err in (first, warm):
    assert 'kept line' in err and 'cpu_aot_loader' not in err, err
  if _has_avx512():  # the hosts where XLA prints the warning: it is there without the filter
    assert 'Target machine feature +prefer-no-gather' in _cached_run(tmp_path, DEXJAX_SHOW_AOT_WARNINGS='1')


def test_what_a_crashing_process_wrote_last_still_arrives():
  script = textwrap.dedent(f"""
      import os, runpy
      quiet = runpy.run_path({cc.__file__!r})['quiet_tuning_feature_warnings']
      with quiet():
        os.write(2, b'last words\\n')
        os.abort()
      """)
  done = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True, timeout=60, check=False)
  assert done.returncode != 0 and 'last words' in done.stderr
