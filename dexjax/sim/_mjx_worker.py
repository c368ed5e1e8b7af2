"""Child-process entry point of the MJX settling backend (started by `dexjax.sim.mjx_backend.run`).

  python -m dexjax.sim._mjx_worker IN.pkl OUT.pkl

Reads ``{'objects', 'states', 'settings'}`` from IN.pkl, settles in this process and writes the
result dict of `dexjax.sim.mjx_backend.settle_in_process` to OUT.pkl. The parent pins this process to one CPU
core before JAX is imported (the deadlock guard) and kills it after its timeout.
"""

from __future__ import annotations

import pickle
import sys


def main(argv: list[str]) -> int:
  if len(argv) != 2:
    print('usage: python -m dexjax.sim._mjx_worker IN.pkl OUT.pkl', file=sys.stderr)
    return 2
  from dexjax.sim.mjx_backend import settle_in_process

  with open(argv[0], 'rb') as f:
    job = pickle.load(f)
  result = settle_in_process(job['objects'], job['states'], job['settings'])
  with open(argv[1], 'wb') as f:
    pickle.dump(result, f)
  return 0


if __name__ == '__main__':
  sys.exit(main(sys.argv[1:]))
