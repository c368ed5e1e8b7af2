"""Runs every notebook of ``notebooks/`` at its default sizes in a fresh Jupyter kernel and prints the wall time of
each as JSON (the run times in notebooks/README.md):

  python scripts/time_notebooks.py [NAME.ipynb ...] [--out times.json]

Each notebook runs in its own kernel, one after the other, through the tests' runner (tests/notebook_kernel.py),
with the session's object cache (``$DEXJAX_CACHE``) warm or cold as it is: run it twice to see both.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from notebook_kernel import NOTEBOOKS, run_notebook  # noqa: E402  pylint: disable=wrong-import-position


def main(argv: list[str] | None = None) -> int:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("names", nargs="*", help="notebooks to run (default: all)")
  parser.add_argument("--out", help="also write the JSON here")
  args = parser.parse_args(argv)
  names = args.names or sorted(p.name for p in NOTEBOOKS.glob("*.ipynb"))
  times: dict[str, float] = {}
  for name in names:
    with tempfile.TemporaryDirectory() as tmp:
      start = time.perf_counter()
      run_notebook(name, pathlib.Path(tmp))
      times[name] = round(time.perf_counter() - start, 1)
    print(f"{name}: {times[name]:.0f} s", file=sys.stderr)
  result = {"date": time.strftime("%Y-%m-%d %H:%M"), "seconds": times}
  text = json.dumps(result, indent=1)
  print(text)
  if args.out:
    pathlib.Path(args.out).write_text(text)
  return 0


if __name__ == "__main__":
  sys.exit(main())
