"""`dexjax.compile_cache.persistent_compilation_cache`: where the CLIs keep compiled programs, and which threshold."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import pytest
from jax.experimental.compilation_cache import compilation_cache

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
