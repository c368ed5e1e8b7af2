"""Runs a notebook of ``notebooks/`` in a real Jupyter kernel (nbclient + ipykernel), as Colab or Jupyter would.

`run_notebook` is the body of the ``run_notebook`` fixture (tests/conftest.py):

* the notebook's **parameter cell** (the code cell tagged ``parameters``, papermill's convention) keeps its text;
  each override is written as ``NAME = repr(value)`` into a cell inserted right after it, and every overridden
  name must be assigned in the parameter cell (a renamed setting fails instead of silently running full size);
* every cell runs in order in a fresh ``python3`` kernel started in a temporary working directory, which
  inherits this process's environment (``DEXJAX_CACHE``, ``XLA_FLAGS``, the JAX cache settings conftest exports);
  any cell error fails with nbclient's ``CellExecutionError`` (the cell, the exception and its traceback);
* as in Jupyter, what the kernel's C and C++ code writes to file descriptors 1 and 2 appears in the cells' outputs
  (ipykernel captures it unless it runs under pytest, so the kernel does not inherit ``PYTEST_CURRENT_TEST``); the
  kernel's standard error passes through `dexjax.compile_cache.quiet_tuning_feature_warnings` from its start
  (`QUIET_KERNEL`), as a CLI's does inside its compilation cache: the kernel uses the session's JAX cache, and each
  hit would print XLA:CPU's false tuning-attribute warning into a cell's output; every other line is kept;
* a last cell evaluates the test's ``values`` expressions in the kernel and pickles them (JAX arrays as NumPy,
  containers and their order kept) for the test to check.
"""

from __future__ import annotations

import ast
import dataclasses
import os
import pathlib
import pickle
import textwrap
from typing import Any

NOTEBOOKS = pathlib.Path(__file__).resolve().parent.parent / "notebooks"
PARAMETERS_TAG = "parameters"
#: Run by the kernel at start-up (IPython ``exec_lines``, after ipykernel captures file descriptor 2): enters
#: `quiet_tuning_feature_warnings` for the kernel's lifetime (the context manager is kept in the namespace).
QUIET_KERNEL = ("import dexjax.compile_cache as _compile_cache; "
                "_dexjax_quiet_stderr = _compile_cache.quiet_tuning_feature_warnings(); "
                "_dexjax_quiet_stderr.__enter__(); del _compile_cache")


@dataclasses.dataclass
class NotebookRun:
  """An executed notebook: ``values`` (name -> value of the test's expression in the kernel) and the notebook with
  its outputs."""

  values: dict[str, Any]
  notebook: Any

  def outputs(self, output_type: str | None = None) -> list[dict]:
    """Every output of every code cell, in order (only those of ``output_type`` when given)."""
    return [o for c in self.notebook.cells if c.cell_type == "code" for o in c.get("outputs", [])
            if output_type is None or o.output_type == output_type]

  def images(self) -> int:
    """Number of PNG images the cells displayed (figures shown by ``plt.show()`` or ``display``)."""
    return sum("image/png" in o.get("data", {}) for o in self.outputs() if o.output_type in ("display_data",
                                                                                             "execute_result"))

  def stdout(self) -> str:
    """Everything the cells printed."""
    return "".join(o.text for o in self.outputs("stream") if o.name == "stdout")

  def stderr(self) -> str:
    """Everything the cells wrote to standard error (Python warnings, progress bars, C++ logs)."""
    return "".join(o.text for o in self.outputs("stream") if o.name == "stderr")


def code_cells(path: pathlib.Path) -> list:
  """The code cells of the notebook at ``path`` (nbformat 4)."""
  import nbformat  # pylint: disable=import-outside-toplevel
  return [c for c in nbformat.read(path, as_version=4).cells if c.cell_type == "code"]


def parameter_names(source: str) -> set[str]:
  """Names assigned at the top level of a cell's source (``A = 1``, ``A: int = 1``, ``A, B = 1, 2``)."""
  names = set()
  for node in ast.parse(source).body:
    targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
    for target in targets:
      for sub in ast.walk(target):
        if isinstance(sub, ast.Name):
          names.add(sub.id)
  return names


def _with_parameters(nb, name: str, parameters: dict[str, Any]):
  import nbformat  # pylint: disable=import-outside-toplevel
  index = [i for i, c in enumerate(nb.cells) if c.cell_type == "code" and PARAMETERS_TAG in c.metadata.get("tags", [])]
  assert len(index) == 1, f"{name}: expected one code cell tagged {PARAMETERS_TAG!r}, found {len(index)}"
  known = parameter_names(nb.cells[index[0]].source)
  unknown = sorted(set(parameters) - known)
  assert not unknown, f"{name}: {unknown} are not assigned in the parameter cell (it assigns {sorted(known)})"
  if parameters:
    lines = [f"{key} = {value!r}" for key, value in parameters.items()]
    cell = nbformat.v4.new_code_cell("\n".join(lines), metadata={"tags": ["injected-parameters"]})
    nb.cells.insert(index[0] + 1, cell)
  return nb


def _probe_cell(values: dict[str, str], path: pathlib.Path):
  import nbformat  # pylint: disable=import-outside-toplevel
  header = textwrap.dedent("""\
      import pickle as _pickle
      import jax as _jax
      import numpy as _np

      def _host(x):  # JAX arrays to NumPy, keeping containers and their order (jax.device_get sorts dict keys)
          if isinstance(x, dict):
              return type(x)((k, _host(v)) for k, v in x.items())
          if isinstance(x, (list, tuple)) and not hasattr(x, "_fields"):
              return type(x)(_host(v) for v in x)
          return _np.asarray(x) if isinstance(x, _jax.Array) else x

      """)
  items = "".join(f"    {key!r}: {expression},\n" for key, expression in values.items())
  dump = f"with open({str(path)!r}, 'wb') as _f:\n    _pickle.dump(_host(_values), _f)\n"
  return nbformat.v4.new_code_cell(header + "_values = {\n" + items + "}\n" + dump)


def run_notebook(name: str, workdir: pathlib.Path, parameters: dict[str, Any] | None = None,
                 values: dict[str, str] | None = None, timeout: int = 1200) -> NotebookRun:
  """Executes ``notebooks/<name>`` in a fresh kernel; see the module docstring.

  Args:
    name: the notebook's file name.
    workdir: an empty directory: the kernel's working directory; the executed notebook is saved there.
    parameters: name -> value, overriding the parameter cell (values must round-trip through ``repr``).
    values: name -> Python expression evaluated in the kernel after the last cell; must be picklable.
    timeout: seconds allowed per cell.
  """
  import nbformat  # pylint: disable=import-outside-toplevel
  from nbclient import NotebookClient  # pylint: disable=import-outside-toplevel

  nb = _with_parameters(nbformat.read(NOTEBOOKS / name, as_version=4), name, dict(parameters or {}))
  out = workdir / "values.pkl"
  nb.cells.append(_probe_cell(dict(values or {}), out))
  env = dict(os.environ)  # with the session's JAX cache settings (tests/conftest.py exports them)
  env.pop("PYTEST_CURRENT_TEST", None)  # else ipykernel leaves C-level output (XLA's logs) out of the cells' outputs
  env["MPLBACKEND"] = "module://matplotlib_inline.backend_inline"  # ipykernel's default, whatever this process uses
  client = NotebookClient(nb, timeout=timeout, kernel_name="python3", resources={"metadata": {"path": str(workdir)}},
                          extra_arguments=[f"--IPKernelApp.exec_lines={QUIET_KERNEL}"])
  try:
    client.execute(env=env)
  finally:
    nbformat.write(nb, workdir / name)  # outputs so far, for a failing run's post-mortem
  with open(out, "rb") as f:
    return NotebookRun(values=pickle.load(f), notebook=nb)
