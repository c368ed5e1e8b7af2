"""``notebooks/benchmark.ipynb`` in a real Jupyter kernel: a tiny benchmark."""

from __future__ import annotations


def test_benchmark_notebook(run_notebook):
  """Both judges on every attempt, the supervisor marked privileged, the table, the figures and the judges'
  confusion counts."""
  small = {"OBJECTS": ["procedural:L1/0:1@41", "procedural:L2/0:1@41"], "PER_TRIAL": 2, "TRIALS": 1,
           "MAX_ATTEMPTS": 3, "POLICIES": ["supervisor", "ambidextrous", "random"]}
  values = {"results": "results", "records": "records", "confusion": "confusion", "figures": "sorted(figures)"}
  run = run_notebook("benchmark.ipynb", small, values)
  results, records, confusion = run.values["results"], run.values["records"], run.values["confusion"]
  assert set(results["policies"]) == {"supervisor", "ambidextrous", "random"}
  assert [name for name, e in results["policies"].items() if e["privileged"]] == ["supervisor"]
  assert sum(confusion.values()) == len(records) == sum(e["attempts"] for e in results["policies"].values())
  assert run.values["figures"] == ["calibration.png", "difficulty.png", "per_object.png", "reliability.png"]
  assert all(r["verdicts"].keys() == {"analytic", "physics"} for r in records)
  assert "reliability" in run.stdout().lower()  # the printed table
  assert "supervisor (privileged): cleared" in run.stdout()
  assert run.images() == 4  # the four figures, drawn by the notebook's backend (dexjax leaves it alone)
