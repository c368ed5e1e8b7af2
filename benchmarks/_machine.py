"""The ``machine`` entry every benchmark prints: when and where it ran, and how busy the machine was.

This machine is shared and noisy (2 cores): the 1-minute load average at the start of a run says how much of it
the run had, and the date ties the figures to the README tables regenerated from them.
"""

from __future__ import annotations

import datetime
import os
import platform
import sys

import jax
import numpy as np


def describe() -> dict:
  """{'date' (UTC, ISO 8601), 'cpus', 'python', 'platform', 'jax', 'numpy', 'device', 'load_average' (1 min)}."""
  return {'date': datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds'),
          'cpus': os.cpu_count(), 'python': sys.version.split()[0], 'platform': platform.platform(),
          'jax': jax.__version__, 'numpy': np.__version__, 'device': str(jax.devices()[0]),
          'load_average': round(os.getloadavg()[0], 2)}
