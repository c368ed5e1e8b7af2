"""Object geometry: mesh loading and repair, signed distance grids and the `ObjectModel` pytree."""

from dexjax.geometry.build import build_object_model
from dexjax.geometry.build import grid_frame
from dexjax.geometry.build import sample_surface
from dexjax.geometry.cache import CACHE_ENV_VAR
from dexjax.geometry.cache import CACHE_FORMAT_VERSION
from dexjax.geometry.cache import cache_key
from dexjax.geometry.cache import cached_object_model
from dexjax.geometry.cache import default_cache_dir
from dexjax.geometry.mesh_io import MAX_HOLE_EDGES
from dexjax.geometry.mesh_io import MeshError
from dexjax.geometry.mesh_io import SUPPORTED_EXTENSIONS
from dexjax.geometry.mesh_io import load_mesh
from dexjax.geometry.mesh_io import validate_and_repair
from dexjax.geometry.object_model import ObjectModel
from dexjax.geometry.sdf import first_crossing
from dexjax.geometry.sdf import ray_cast
from dexjax.geometry.sdf import sdf_gradient
from dexjax.geometry.sdf import sdf_value
from dexjax.geometry.sdf import surface_normal
from dexjax.geometry.transforms import normalize
from dexjax.geometry.transforms import perpendicular
from dexjax.geometry.transforms import sample_cone
from dexjax.geometry.transforms import sample_unit_sphere
from dexjax.geometry.transforms import so3_exp
from dexjax.geometry.transforms import tangent_basis
