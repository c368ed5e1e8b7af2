"""Heaps: the Dex-Net 4.0 heap state distribution, MuJoCo scene building and physics settling.

`sample_heap_state` draws a heap's initial state (pure JAX, `vmap` over keys); `heap_object` turns a mesh and
its convex pieces into a rigid body (with the object's own density when it has one, as procedural objects do);
`settle` drops and settles batches of heaps with the MuJoCo C engine (``backend='rollout'``) or MJX
(``backend='mjx'``), flagging objects that leave the bin or never come to rest; `resting_loads` measures the loads
the objects of a settled heap put on each other.
See ``docs/heaps.md``.
"""

from dexjax.sim.bodies import (DEFAULT_DENSITY, DEFAULT_MASS_RANGE, HeapObject, heap_object, heap_objects,
                               mass_solid, object_density, validate_hull)
from dexjax.sim.heap import (COUNT_LAWS, MAX_OBJECTS, Bin, HeapDistribution, HeapState, sample_friction,
                             sample_heap_state, sample_heap_states, sample_object_count, sample_uniform_quaternion,
                             select_heap, truncated_poisson_pmf)
from dexjax.sim.scene import (SettleSettings, bin_boxes, build_heap_model, compile_heap, drop_poses, heap_slots,
                              heap_spec, initial_qpos, quat_to_matrix)
from dexjax.sim.mjx_backend import SettleTimeout
from dexjax.sim.rest import object_speeds, resting, rotate
from dexjax.sim.contact_loads import resting_loads
from dexjax.sim.settling import BACKENDS, SettleResult, default_backend, settle

__all__ = [
    "DEFAULT_DENSITY", "DEFAULT_MASS_RANGE", "HeapObject", "heap_object", "heap_objects", "mass_solid",
    "object_density", "validate_hull",
    "COUNT_LAWS", "MAX_OBJECTS", "Bin", "HeapDistribution", "HeapState", "sample_friction", "sample_heap_state",
    "sample_heap_states", "select_heap", "sample_object_count", "sample_uniform_quaternion",
    "truncated_poisson_pmf",
    "SettleSettings", "bin_boxes", "build_heap_model", "compile_heap", "heap_spec", "drop_poses", "heap_slots", "initial_qpos", "quat_to_matrix",
    "BACKENDS", "SettleResult", "SettleTimeout", "default_backend", "HeapRow", "posed_meshes",
    "save_heap_sheet", "procedural_heap_rows", "object_speeds", "resting", "resting_loads", "rotate", "settle",
]


def __getattr__(name: str):
  """Lazily provides the heap pictures (`save_heap_sheet`, ...; imports matplotlib only when drawing)."""
  if name in ('HeapRow', 'posed_meshes', 'save_heap_sheet', 'procedural_heap_rows'):
    from dexjax.sim import preview  # pylint: disable=g-import-not-at-top
    return getattr(preview, name)
  raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
