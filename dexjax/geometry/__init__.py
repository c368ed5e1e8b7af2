"""Object geometry: mesh loading and repair, signed distance grids, the `ObjectModel` pytree, its on-disk cache and
small SO(3) / vector helpers.

Cache internals (file keys, atomic writers: `dexjax.geometry.content_cache`, re-exported by `dexjax.geometry.cache`)
and the mesh topology helpers (`dexjax.geometry.mesh_topology`) are not part of this surface.
"""

from dexjax.geometry.build import build_object_model, grid_frame, sample_surface
from dexjax.geometry.cache import CACHE_ENV_VAR, cached_object_model, default_cache_dir
from dexjax.geometry.mesh_io import (MAX_HOLE_EDGES, PLAUSIBLE_EXTENT, SUPPORTED_EXTENSIONS, ImperfectMeshWarning,
                                     MeshError, ScaleWarning, check_scale, load_mesh, validate_and_repair)
from dexjax.geometry.object_model import ObjectModel, StackedObjectModel, select_model
from dexjax.geometry.winding import solidify, winding_signed_distance
from dexjax.geometry.sdf import first_crossing, ray_cast, sdf_gradient, sdf_value, surface_normal
from dexjax.geometry.transforms import (aligned_tangent_basis, normalize, perpendicular, quat_to_matrix, sample_cone,
                                        sample_unit_sphere, so3_exp, tangent_basis)

__all__ = [
    "ObjectModel", "StackedObjectModel", "select_model", "build_object_model", "grid_frame", "sample_surface",
    "CACHE_ENV_VAR", "cached_object_model", "default_cache_dir",
    "MAX_HOLE_EDGES", "PLAUSIBLE_EXTENT", "SUPPORTED_EXTENSIONS", "ImperfectMeshWarning", "MeshError", "ScaleWarning", "check_scale", "load_mesh",
    "validate_and_repair",
    "solidify", "winding_signed_distance",
    "first_crossing", "ray_cast", "sdf_gradient", "sdf_value", "surface_normal",
    "aligned_tangent_basis", "normalize", "perpendicular", "quat_to_matrix", "sample_cone", "sample_unit_sphere",
    "so3_exp", "tangent_basis",
]
