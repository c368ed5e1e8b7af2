"""Objects to grasp: built-in test meshes, procedural object sets and the object-spec resolver.

Specs: ``'builtin:NAME'``, ``'procedural:L{level}/{index}[@{seed}]'`` or a mesh file path.
"""

from dexjax.objects.builtin import BUILTIN_OBJECTS
from dexjax.objects.builtin import BUILTIN_PREFIX
from dexjax.objects.builtin import builtin_mesh
from dexjax.objects.builtin import check_object_spec
from dexjax.objects.builtin import load_object_model
from dexjax.objects.builtin import resolve_mesh
from dexjax.objects.procedural import MAX_EXTENT
from dexjax.objects.procedural import MAX_FACES
from dexjax.objects.procedural import MAX_MASS
from dexjax.objects.procedural import MAX_RANGE_COUNT
from dexjax.objects.procedural import MIN_MASS
from dexjax.objects.procedural import MIN_EXTENT
from dexjax.objects.procedural import PROCEDURAL_LEVELS
from dexjax.objects.procedural import PROCEDURAL_VERSION
from dexjax.objects.procedural import PROCEDURAL_PREFIX
from dexjax.objects.procedural import parse_procedural_spec
from dexjax.objects.procedural import procedural_families
from dexjax.objects.procedural import procedural_material
from dexjax.objects.procedural import procedural_mesh
from dexjax.objects.procedural import procedural_mesh_problems
from dexjax.objects.procedural import procedural_params
from dexjax.objects.procedural import procedural_spec
from dexjax.objects.procedural import procedural_specs
from dexjax.objects.procedural_materials import Material
from dexjax.objects.collision import CONVEX_SOLIDITY
from dexjax.objects.collision import HullSettings
from dexjax.objects.collision import cached_collision_hulls
from dexjax.objects.collision import collision_hulls
from dexjax.objects.collision import hulls_cache_key
from dexjax.objects.folder import FolderReport
from dexjax.objects.folder import LoadedObject
from dexjax.objects.folder import PreparedObject
from dexjax.objects.folder import Rejection
from dexjax.objects.folder import load_mesh_folder
from dexjax.objects.folder import prepare_object
from dexjax.objects.sets import check_object_sources
from dexjax.objects.sets import expand_object_sources
from dexjax.objects.sets import load_object_set
from dexjax.objects.sets import prepare_object_set
from dexjax.objects.sets import NoObjectsError
from dexjax.objects.sets import usable_objects

__all__ = [
    "BUILTIN_OBJECTS", "BUILTIN_PREFIX", "builtin_mesh", "check_object_spec", "load_object_model", "resolve_mesh",
    "MAX_EXTENT", "MAX_FACES", "MAX_MASS", "MAX_RANGE_COUNT", "MIN_EXTENT", "MIN_MASS", "PROCEDURAL_LEVELS",
    "PROCEDURAL_PREFIX", "PROCEDURAL_VERSION",
    "parse_procedural_spec", "procedural_families", "procedural_material", "procedural_mesh",
    "procedural_mesh_problems", "procedural_params", "procedural_spec", "procedural_specs", "Material",
    "CONVEX_SOLIDITY", "HullSettings", "cached_collision_hulls", "collision_hulls", "hulls_cache_key",
    "FolderReport", "LoadedObject", "PreparedObject", "Rejection", "load_mesh_folder", "prepare_object",
    "check_object_sources", "expand_object_sources", "load_object_set", "prepare_object_set", "NoObjectsError",
    "usable_objects",
    "save_contact_sheet", "ObjectMass", "object_masses", "mass_summary", "prior_summary",
]

_MASSES = ('ObjectMass', 'object_masses', 'mass_summary', 'prior_summary')


def __getattr__(name: str):
  """Lazily provides `save_contact_sheet` (imports matplotlib only when previews are drawn) and the mass table
  (`object_masses`, ...; imports the heap physics only when used)."""
  if name == 'save_contact_sheet':
    from dexjax.objects.preview import save_contact_sheet  # pylint: disable=g-import-not-at-top
    return save_contact_sheet
  if name in _MASSES:
    import importlib  # pylint: disable=g-import-not-at-top
    return getattr(importlib.import_module('dexjax.objects.masses'), name)
  raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
