"""Objects to grasp: built-in test meshes and the object-spec resolver (``'builtin:NAME'`` or a file)."""

from dexjax.objects.builtin import BUILTIN_OBJECTS
from dexjax.objects.builtin import BUILTIN_PREFIX
from dexjax.objects.builtin import builtin_mesh
from dexjax.objects.builtin import load_object_model
from dexjax.objects.builtin import resolve_mesh
