"""The `ObjectModel` pytree: everything the analytic quality kernels need to know about a rigid object.

An object model is a bundle of fixed-size arrays in the object's own frame (the mesh frame, metres):

* a **signed** distance grid (negative inside the object, positive outside) with its gradient, sampled at
  voxel centres of a cubic grid of ``D**3`` isotropic voxels;
* area-uniform surface samples with outward unit normals (fixed count ``S``);
* mass properties for a uniform-density solid: volume, centre of mass and the unit-mass inertia tensor;
* the axis-aligned bounding box of the mesh.

Why signed (the original Dex-Net stored ``|phi|``, spec section 1.2): a sign tells inside from outside, so a
jaw or a ray finds the surface as a *sign change* between two samples and refines it to sub-voxel accuracy
by root finding, a jaw that starts inside the object is detected as a collision instead of reporting the
nearest surface, and the outward normal is the normalised gradient (no sign ambiguity, no plane fit). The
price is that the mesh must be watertight; `dexjax.geometry.build_object_model` repairs what it can and
rejects the rest with a message naming the file.

Every field is an array, so a model can be passed through `jax.jit`, stacked with `jax.tree.map` and
`vmap`-ed over (all models built with the same grid size and sample count share one compiled kernel).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class ObjectModel:
  """Fixed-size description of one rigid object, in the object frame (metres).

  Attributes:
    sdf: (D, D, D) float32 signed distance in metres at voxel centres; < 0 inside.
    sdf_grad: (D, D, D, 3) float32 spatial gradient of ``sdf`` (unitless, norm ~ 1 near the surface).
    origin: (3,) float32 position of the centre of voxel (0, 0, 0), metres.
    voxel_size: () float32 edge length of one voxel, metres.
    surface_points: (S, 3) float32 area-uniform samples on the mesh surface, metres.
    surface_normals: (S, 3) float32 outward unit normals at ``surface_points``.
    center_of_mass: (3,) float32 centre of mass of the uniform-density solid, metres.
    volume: () float32 enclosed volume, m^3.
    inertia: (3, 3) float32 inertia tensor about the centre of mass for unit mass, m^2 (multiply by kg).
    bounds: (2, 3) float32 axis-aligned bounding box [min, max] of the mesh, metres.
  """

  sdf: jax.Array
  sdf_grad: jax.Array
  origin: jax.Array
  voxel_size: jax.Array
  surface_points: jax.Array
  surface_normals: jax.Array
  center_of_mass: jax.Array
  volume: jax.Array
  inertia: jax.Array
  bounds: jax.Array

  @property
  def grid_size(self) -> int:
    """Number of voxels D along each axis (static)."""
    return self.sdf.shape[-1]

  @property
  def extents(self) -> jax.Array:
    """(3,) edge lengths of the bounding box, metres."""
    return self.bounds[..., 1, :] - self.bounds[..., 0, :]


@struct.dataclass
class StackedObjectModel(ObjectModel):
  """One object of a stack of models, read in place: every function that takes an `ObjectModel` takes this too.

  ``sdf`` (N, D, D, D) and ``sdf_grad`` (N, D, D, D, 3) are the whole stack's grids, shared, and ``index`` () int32
  says which object's grid is read (`dexjax.geometry.sdf` offsets its lookups by it); the other fields are that
  object's own. Selecting a model per grasp under `jax.vmap` this way batches only ``index`` and the small fields;
  gathering the grids instead (``models.sdf[index]``) copies a whole grid per grasp (measured: 4 MB and two
  thirds of a heap reward's time at D = 64).
  """

  index: jax.Array = 0


def select_model(models: ObjectModel, index: jax.Array) -> StackedObjectModel:
  """The object ``index`` () of stacked ``models`` (leading axis N, e.g. `dexjax.quality.stack_models`) as a
  `StackedObjectModel`: its grids are read in place, its small fields gathered."""
  small = {f.name: getattr(models, f.name)[index] for f in dataclasses.fields(ObjectModel)
           if f.name not in ('sdf', 'sdf_grad')}
  return StackedObjectModel(sdf=models.sdf, sdf_grad=models.sdf_grad, index=jnp.asarray(index, jnp.int32), **small)
