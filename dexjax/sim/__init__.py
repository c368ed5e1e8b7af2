"""Heaps: the Dex-Net 4.0 heap state distribution, MuJoCo scene building and physics settling.

`sample_heap_state` draws a heap's initial state (pure JAX, `vmap` over keys); `heap_object` turns a mesh and
its convex pieces into a rigid body; `settle` drops and settles batches of heaps with the MuJoCo C engine
(``backend='rollout'``) or MJX (``backend='mjx'``), flagging objects that leave the bin or never come to rest.
See ``docs/heaps.md``.
"""

from dexjax.sim.bodies import DEFAULT_DENSITY, DEFAULT_MASS_RANGE, HeapObject, heap_object, validate_hull
from dexjax.sim.heap import (MAX_OBJECTS, Bin, HeapDistribution, HeapState, sample_friction, sample_heap_state,
                             sample_object_count, sample_uniform_quaternion, truncated_poisson_pmf)
from dexjax.sim.scene import SettleSettings, build_heap_model, drop_poses, heap_slots, initial_qpos, quat_to_matrix
from dexjax.sim.settling import (BACKENDS, SettleResult, SettleTimeout, default_backend, object_speeds, resting, rotate,
                               settle)

__all__ = [
    "DEFAULT_DENSITY", "DEFAULT_MASS_RANGE", "HeapObject", "heap_object", "validate_hull", "MAX_OBJECTS", "Bin",
    "HeapDistribution", "HeapState", "sample_friction", "sample_heap_state", "sample_object_count",
    "sample_uniform_quaternion", "truncated_poisson_pmf", "SettleSettings", "build_heap_model", "drop_poses",
    "heap_slots", "initial_qpos", "quat_to_matrix", "BACKENDS", "SettleResult", "SettleTimeout", "default_backend",
    "object_speeds", "resting", "rotate", "settle",
]
