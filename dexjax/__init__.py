"""dexjax: Dex-Net 4.0 rebuilt as a JAX library.

Pure, composable ``jit``/``vmap`` functions for analytic grasp quality of parallel-jaw and suction grippers
(soft-finger and compliant suction-ring contact models, robust Monte-Carlo wrench resistance), grasp samplers,
object models and object sets (`dexjax.objects`), and heaps of objects settled with MuJoCo (`dexjax.sim`).
Every function works on a single item; batch with `jax.vmap`.
"""

from dexjax import config, contacts, data, geometry, objects, quality, render, sampling, sim
from dexjax.config import ConfigError
from dexjax.objects import BUILTIN_OBJECTS, builtin_mesh, load_object_model
from dexjax.contacts import *  # noqa: F401,F403
from dexjax.geometry import *  # noqa: F401,F403
from dexjax.grasps import ParallelJawGrasp, SuctionGrasp, parallel_jaw_pose, suction_pose
from dexjax.grippers import STANDARD_GRAVITY, SUCTION_PAYLOAD_KG, ParallelJawGripper, SuctionGripper
from dexjax.quality import *  # noqa: F401,F403
from dexjax.sampling import *  # noqa: F401,F403

__version__ = "0.1.0"
