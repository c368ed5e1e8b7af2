"""The masses of an object set, as the physics gets them, beside the reward model's Gamma mass prior.

`object_masses` applies the heap simulation's mass rule (`dexjax.sim.heap_object`: an object's own density,
e.g. a procedural object's material, else 500 kg/m^3 clipped to [0.01, 2] kg) to each loaded object;
`mass_summary` sums a set up (mean, median, quartiles, the shares above the prior's mean and above
`dexjax.objects.MAX_MASS`) and `prior_summary` gives the same figures for the Gamma law the seed's reward
samples masses from (mean 0.25 kg, variance 0.05 kg^2). ``python -m dexjax.objects masses SOURCE ...`` prints
both.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence
from typing import Any, Protocol

import numpy as np
import scipy.special
import trimesh

from dexjax.objects.procedural import MAX_MASS
from dexjax.sim.bodies import DEFAULT_DENSITY, heap_object, mass_solid, object_density

__all__ = ['PRIOR_MASS_MEAN', 'PRIOR_MASS_VARIANCE', 'ObjectMass', 'object_masses', 'mass_summary',
           'prior_summary']

PRIOR_MASS_MEAN: float = 0.25
"""Mean of the seed's Gamma mass law, kg (`dexjax.quality.Perturbations.mass_mean`)."""

PRIOR_MASS_VARIANCE: float = 0.05
"""Variance of the seed's Gamma mass law, kg^2 (`dexjax.quality.Perturbations.mass_variance`)."""


class _Named(Protocol):
  """Anything with a name and a mesh, e.g. `dexjax.objects.LoadedObject` or `PreparedObject`."""
  name: str
  mesh: trimesh.Trimesh


@dataclasses.dataclass(frozen=True)
class ObjectMass:
  """One object's size and mass as the heap simulation sees it.

  Attributes:
    name: the object's name (its spec for built-in and procedural objects).
    family: procedural family (``mesh.metadata['family']``), or None.
    material: material name (``mesh.metadata['material']``), or None.
    extents: (3,) bounding-box extents sorted ascending, metres.
    volume: volume of the solid the mass rule uses (`dexjax.sim.mass_solid`), m^3.
    density: the density the mass rule used, kg/m^3 (the object's own, else `dexjax.sim.DEFAULT_DENSITY`).
    mass: the mass `dexjax.sim.heap_object` gives the object, kg (clipped to [0.01, 2] kg for objects without a
      density of their own).
  """
  name: str
  family: str | None
  material: str | None
  extents: tuple[float, float, float]
  volume: float
  density: float
  mass: float

  def to_json(self) -> dict[str, Any]:
    """A JSON-ready dict (SI units: metres, m^3, kg/m^3, kg)."""
    return dataclasses.asdict(self) | {'extents': list(self.extents)}


def object_masses(objects: Iterable[_Named]) -> list[ObjectMass]:
  """The `ObjectMass` of each object, in order (the mass from `dexjax.sim.heap_object`, as the physics gets it)."""
  rows = []
  for o in objects:
    metadata = o.mesh.metadata if isinstance(o.mesh.metadata, dict) else {}
    own = object_density(o.mesh)
    extents = tuple(float(e) for e in np.sort(np.asarray(o.mesh.extents, np.float64)))
    rows.append(ObjectMass(name=o.name, family=metadata.get('family'), material=metadata.get('material'),
                           extents=extents, volume=float(mass_solid(o.mesh).volume),
                           density=DEFAULT_DENSITY if own is None else own,
                           mass=heap_object(o.mesh, name=o.name).mass))
  return rows


def mass_summary(masses: Sequence[float]) -> dict[str, float]:
  """Summary of a set's masses (kg): count, mean, median, q25, q75, min, max, and the fractions above the
  prior's mean (`PRIOR_MASS_MEAN`) and above `dexjax.objects.MAX_MASS`.

  Raises:
    ValueError: no masses.
  """
  m = np.asarray(masses, np.float64)
  if m.size == 0:
    raise ValueError('mass_summary: expected at least one mass, got none')
  q25, median, q75 = np.percentile(m, [25, 50, 75])
  return {'count': int(m.size), 'mean': float(m.mean()), 'median': float(median), 'q25': float(q25),
          'q75': float(q75), 'min': float(m.min()), 'max': float(m.max()),
          'above_prior_mean': float(np.mean(m > PRIOR_MASS_MEAN)), 'above_max_mass': float(np.mean(m > MAX_MASS))}


def prior_summary(mean: float = PRIOR_MASS_MEAN, variance: float = PRIOR_MASS_VARIANCE) -> dict[str, float]:
  """The same figures as `mass_summary` for the Gamma law with this mean (kg) and variance (kg^2), plus its
  standard deviation ``sd`` (kg): shape k = mean^2 / variance, scale = variance / mean."""
  shape, scale = mean**2 / variance, variance / mean
  quantile = lambda q: float(scipy.special.gammaincinv(shape, q) * scale)
  above = lambda x: float(scipy.special.gammaincc(shape, x / scale))
  return {'mean': mean, 'sd': math.sqrt(variance), 'median': quantile(0.5), 'q25': quantile(0.25),
          'q75': quantile(0.75), 'above_prior_mean': above(mean), 'above_max_mass': above(MAX_MASS)}
