"""Materials of the procedural object families: a density range per family, with its source.

A procedural object's mass is its density times its mesh volume, with the density drawn uniformly from its
family's `Material` range (`dexjax.objects.procedural_params`). A material is one of two kinds:

* an **effective** density (``effective=True``): the mesh is a solid stand-in for a filled or packaged object
  (a box of crackers, a can of soup, a full bottle, a 3-D printed part with sparse infill), so the density is
  the object's mass divided by its outer volume. The level-1 figures are measured on the YCB object set (Calli
  et al. 2015, "The YCB object and model set", masses and dimensions of the objects as published):
  foam brick 28 g in 5 x 7.5 x 5 cm = 149 kg/m^3, cracker box 411 g in 6 x 15.8 x 21 cm = 206, master chef
  coffee can 414 g, 10.2 cm diameter x 13.9 cm = 364, wood block 729 g in 8.5 x 8.5 x 20 cm = 505, pudding box
  187 g in 3.5 x 11 x 8.9 cm = 546, gelatin box 97 g in 2.8 x 8.5 x 7.3 cm = 558, sugar box 514 g in
  3.8 x 8.9 x 17.5 cm = 868, tuna can 171 g, 8.5 cm x 3.3 cm = 914, potted meat can 370 g in 5 x 9.7 x 8.2 cm =
  930, tomato soup can 349 g, 6.6 cm x 10.1 cm = 1010; balls: tennis ball 58 g, 6.5 cm = 409, racquetball 41 g,
  5.5 cm = 463, baseball 148 g, 7.5 cm = 670, softball 191 g, 9.6 cm = 413.
* a **handbook** density (``effective=False``): the mesh is a shell or solid whose volume is the material
  itself (a plastic mug, a glass jar, an aluminium heat sink), so the density is the material's (engineering
  handbook values: melamine ~1500, glass 2400-2600, aluminium 2700, softwood 400-600, polypropylene ~900,
  ABS 1040-1060 kg/m^3).

Where a range is our choice rather than a measurement, `Material.source` says so.
"""

from __future__ import annotations

import dataclasses

__all__ = [
    'Material', 'BOXED_GOODS', 'CANNED_GOODS', 'HOUSEHOLD_SOLIDS', 'BLOCKS', 'BALLS', 'VESSEL_PLASTIC',
    'FILLED_BOTTLE', 'ABS', 'PLASTIC_TOOL', 'SOFTWOOD', 'PACKAGED_GOODS', 'GLASS', 'ALUMINIUM', 'PRINTED_PLA',
]


@dataclasses.dataclass(frozen=True)
class Material:
  """What a family of procedural objects is made of.

  Attributes:
    name: short name, e.g. ``'canned goods'`` (shown by ``python -m dexjax.objects masses``).
    density: (low, high) range the density is drawn from, uniformly, kg/m^3.
    effective: True when the density is an effective one (mass / outer volume of a filled or packaged
      object), False when it is the handbook density of the material the mesh's volume is made of.
    source: where the range comes from (a measurement, a handbook value, or our choice and why).
  """
  name: str
  density: tuple[float, float]
  effective: bool
  source: str

  def __post_init__(self):
    low, high = self.density
    if not 0 < low <= high:
      raise ValueError(f'Material {self.name!r}: density: expected 0 < low <= high (kg/m^3), got {self.density!r}')


# Level 1: household boxes, cans, blocks and balls (effective densities measured on the YCB object set).

BOXED_GOODS = Material(
    'boxed goods', (150.0, 930.0), True,
    'YCB boxes: foam brick 149, cracker 206, wood block 505, pudding 546, gelatin 558, sugar 868, potted meat 930')
CANNED_GOODS = Material('canned goods', (360.0, 1010.0), True, 'YCB cans: coffee 364, tuna 914, tomato soup 1010')
HOUSEHOLD_SOLIDS = Material(
    'household solid', (150.0, 1010.0), True, 'YCB boxes, cans and blocks: foam brick 149 to tomato soup can 1010')
BLOCKS = Material('foam or wood block', (150.0, 505.0), True, 'YCB blocks: foam brick 149, wood block 505')
BALLS = Material('ball', (409.0, 670.0), True, 'YCB balls: tennis 409, softball 413, racquetball 463, baseball 670')

# Level 2: household objects with complex geometry.

VESSEL_PLASTIC = Material(
    'plastic or melamine', (900.0, 1500.0), False,
    'handbook: polypropylene ~900, melamine ~1500; our choice: household mugs and bowls of this size as plastic or '
    'melamine (picnic ware): porcelain (2300-2400) made bowls of 0.26-0.54 kg that neither gripper holds, too '
    'wide for the jaws and too heavy for the cup on their inner bottom under the seed\'s pi/6 gravity cone '
    '(docs/objects.md)')
FILLED_BOTTLE = Material(
    'filled bottle', (600.0, 1000.0), True,
    'our choice: water 1000 (handbook) for a full bottle, down to 600 for a partly filled one')
ABS = Material('ABS', (1040.0, 1060.0), False, 'handbook: ABS 1040-1060 (solid plastic letters)')
PLASTIC_TOOL = Material(
    'plastic (PP/ABS)', (900.0, 1050.0), False,
    'handbook: polypropylene ~900, ABS ~1050; our choice: household tools of this size as plastic-bodied '
    '(a solid steel tool of 10-15 cm would often exceed the suction payload)')
SOFTWOOD = Material('softwood', (400.0, 600.0), False, 'handbook: softwood (pine, spruce) 400-600 (wooden toys)')
PACKAGED_GOODS = Material(
    'packaged goods', (150.0, 1010.0), True,
    'YCB boxes and cans: foam brick 149 to tomato soup can 1010 (a blister pack as a solid stand-in)')

# Level 3: adversarial geometry.

GLASS = Material('glass', (2400.0, 2600.0), False, 'handbook: soda-lime glass 2400-2600 (jars, vials, ink bottles)')
ALUMINIUM = Material('aluminium', (2650.0, 2750.0), False, 'handbook: aluminium 2700, alloys 2650-2750 (heat sinks)')
PRINTED_PLA = Material(
    'PLA, 3-D printed', (400.0, 800.0), True,
    'our choice: solid PLA 1240 (handbook) printed with 20-50 % infill plus walls (FDM parts)')
