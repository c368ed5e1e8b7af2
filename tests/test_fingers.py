"""Fingers with volume (issue 13): the parallel-jaw fingers and palm are solids in the single-object quality,
the antipodal sampler and the heap reward, from one set of sizes in `ParallelJawGripper`.

Known answers on objects built here from boxes (trimesh, manifold booleans), checked against exact box
geometry in NumPy. Frames: the grasp centre is the origin, the jaws close along x, the gripper approaches
along -z (from above), so with the default fingers the +x finger occupies x in [2.5, 3.5] cm, y in [-1, 1] cm,
z in [-1, 5] cm at the grasp pose and up to z = 10 cm on its approach path (5 cm standoff).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from dexjax.config import ConfigError
from dexjax.geometry import build_object_model, sdf_value
from dexjax.grasps import ParallelJawGrasp, parallel_jaw_pose
from dexjax.grippers import ParallelJawGripper
from dexjax.objects.builtin import L_SHAPE_FOOT_EXTENTS, L_SHAPE_UPRIGHT_EXTENTS, builtin_mesh
from dexjax.quality import (FAILURE_REASONS, Conditions, GripperGeometry, QualityConfig, parallel_jaw_perturbations,
                            parallel_jaw_quality, robust_parallel_jaw_quality)
from dexjax.quality.gripper_geometry import jaw_collides, jaw_collision_points, jaw_solids
from dexjax.quality.heap_reward import HeapScene, parallel_jaw_collisions, stack_models
from dexjax.sampling import sample_antipodal_grasps
from dexjax.sim.heap import Bin

FINGERS = ParallelJawGripper()
POINT_JAWS = ParallelJawGripper(finger_thickness=0.0)
GRID = 100  # ~0.7 mm voxels on these 6-7 cm objects: a 3 mm wall is resolved by the grid
TOL = QualityConfig().collision_tolerance
DOWN = (0.0, 0.0, -1.0)
NOMINAL = Conditions(mass=jnp.float32(0.25), friction=jnp.float32(0.8), gravity=jnp.asarray(DOWN, jnp.float32),
                     disturbance=jnp.zeros(6, jnp.float32))

_quality = jax.jit(parallel_jaw_quality)


def _box(lo, hi) -> trimesh.Trimesh:
  lo, hi = np.asarray(lo, float), np.asarray(hi, float)
  return trimesh.creation.box(extents=hi - lo, transform=trimesh.transformations.translation_matrix((lo + hi) / 2))


def _model(*boxes) -> object:
  mesh = trimesh.boolean.union([_box(lo, hi) for lo, hi in boxes], engine='manifold')
  return build_object_model(mesh, grid_size=GRID)


def _grasp(center=(0.0, 0.0, 0.0), axis=(1.0, 0.0, 0.0), approach=DOWN, width=0.05) -> ParallelJawGrasp:
  f = lambda v: jnp.asarray(v, jnp.float32)
  return ParallelJawGrasp(center=f(center), axis=f(axis), approach=f(approach), width=jnp.float32(width))


def _failure(model, grasp, gripper, config=QualityConfig()) -> str:
  return FAILURE_REASONS[int(_quality(model, grasp, gripper, NOMINAL, config).failure)]


# A block 4.6 cm across x (the grasped part) with a wall 4 mm beyond its +x face: the +x jaw opens into the
# 4 mm slot x in [2.3, 2.7] cm; a base plate under the fingertips (z < -2 cm) joins block and wall.
BLOCK = ((-0.023, -0.015, -0.02), (0.023, 0.015, 0.02))
SLOT_WALL = ((0.027, -0.015, -0.02), (0.037, 0.015, 0.02))
BASE = ((-0.023, -0.015, -0.03), (0.037, 0.015, -0.02))


@pytest.fixture(scope='module')
def fork():
  return _model(BLOCK, SLOT_WALL, BASE)


def test_a_jaw_in_a_4mm_slot_fits_point_jaws_but_not_fingers(fork):
  grasp = _grasp()
  # Point jaws: both start points are outside (the +x one in the slot); the grasp holds the block.
  point = _quality(fork, grasp, POINT_JAWS, NOMINAL)
  assert bool(point.resists), FAILURE_REASONS[int(point.failure)]
  # A 1 cm finger from the pad at x = 2.5 cm reaches 8 mm into the wall (from x = 2.7 cm).
  assert _failure(fork, grasp, FINGERS) == 'jaw_collision'
  # Thickness 0 runs no volume test at all (today's point jaws).
  assert not bool(jaw_collides(fork, grasp, POINT_JAWS, GripperGeometry(), TOL))
  # The tolerance: a 2.5 mm finger (x in [2.5, 2.75] cm) reaches 0.5 mm into the wall and fits; a 5 mm one
  # (2.3 mm deep) does not.
  assert _failure(fork, grasp, FINGERS.replace(finger_thickness=0.0025)) != 'jaw_collision'
  assert _failure(fork, grasp, FINGERS.replace(finger_thickness=0.005)) == 'jaw_collision'


def test_a_grasp_that_fits_real_fingers_is_unchanged(fork, cube):
  # Across the fork's block along y (3 cm): the fingers (x in [-1, 1] cm) stay clear of the slot wall.
  for model, grasp in ((fork, _grasp(axis=(0.0, 1.0, 0.0))), (cube, _grasp())):
    with_fingers = _quality(model, grasp, FINGERS, NOMINAL)
    point = _quality(model, grasp, POINT_JAWS, NOMINAL)
    assert bool(with_fingers.resists)
    assert int(with_fingers.failure) == int(point.failure)
    assert float(with_fingers.residual) == float(point.residual)
  key = jax.random.key(0)
  robust = jax.jit(robust_parallel_jaw_quality)
  a = robust(key, cube, _grasp(), FINGERS, parallel_jaw_perturbations())
  b = robust(key, cube, _grasp(), POINT_JAWS, parallel_jaw_perturbations())
  np.testing.assert_array_equal(np.asarray(a.outcomes.failure), np.asarray(b.outcomes.failure))
  assert float(a.probability) == float(b.probability) >= 0.8


# 3 mm walls through the +x finger, each midway between two planes of 5 mm sample points, so that the plain
# cell-centre samples stay 1 mm outside the wall; all clear of the jaws' closing lines (z = 0, y = 0). A base
# plate under the fingertips joins them to the cube.
THIN_WALLS = {
    # Parallel to the pad, inside the finger's thickness: x in [2.85, 3.15] cm (samples at x = 2.75, 3.25 cm).
    'parallel_to_pad': ((0.0285, -0.02, -0.03), (0.0315, 0.02, -0.003)),
    # Across the finger's width: y in [-0.15, 0.15] cm (samples at y = -0.25, 0.25 cm).
    'across_the_pad': ((0.015, -0.0015, -0.03), (0.04, 0.0015, -0.003)),
    # A shelf across the approach path: z in [0.35, 0.65] cm (samples at z = 0.25, 0.75 cm).
    'across_the_approach': ((0.015, -0.02, 0.0035), (0.04, 0.02, 0.0065)),
}
CUBE = ((-0.02, -0.02, -0.02), (0.02, 0.02, 0.02))
WALL_BASE = ((-0.02, -0.02, -0.03), (0.04, 0.02, -0.02))


@pytest.mark.parametrize('name', sorted(THIN_WALLS))
def test_a_3mm_wall_between_the_samples_is_caught(name):
  model = _model(CUBE, THIN_WALLS[name], WALL_BASE)
  grasp = _grasp()
  # The plain samples (the heap reward's points) miss it: none is more than the tolerance inside the object.
  pose = parallel_jaw_pose(grasp)
  points = jaw_collision_points(FINGERS, GripperGeometry(), grasp.width) @ pose[:3, :3].T + pose[:3, 3]
  plain = np.asarray(jax.jit(jax.vmap(sdf_value, in_axes=(None, 0)))(model, points))
  assert plain.min() > -TOL, plain.min()
  # ... but the grid does hold points of the wall deeper than the tolerance inside the finger (dense check).
  lo, hi, _ = jaw_solids(FINGERS, GripperGeometry(), grasp.width)[0]
  axes = [np.arange(float(a) + 2.5e-4, float(b), 5e-4) for a, b in zip(lo, hi)]
  dense = np.stack(np.meshgrid(*axes, indexing='ij'), -1).reshape(-1, 3) @ np.asarray(pose[:3, :3]).T
  assert float(jax.jit(jax.vmap(sdf_value, in_axes=(None, 0)))(model, jnp.asarray(dense, jnp.float32)).min()) < -TOL
  # The single-object test finds it; point jaws ignore it (the jaw lines do not cross these walls).
  assert _failure(model, grasp, FINGERS) == 'jaw_collision'
  assert _failure(model, grasp, POINT_JAWS) == 'none'


def test_a_collision_on_the_approach_path_is_caught():
  # A roof over the +x finger at z in [7.5, 8.5] cm, above the fingers at the grasp pose (top at 5 cm, palm up
  # to 7 cm) but inside the 5 cm standoff sweep; a pillar beyond the finger (x in [4, 5] cm) and a base plate
  # below the tips carry it.
  roof = ((0.022, -0.015, 0.075), (0.05, 0.015, 0.085))
  pillar = ((0.04, -0.015, -0.03), (0.05, 0.015, 0.085))
  base = ((-0.02, -0.015, -0.03), (0.05, 0.015, -0.02))
  model = _model(((-0.02, -0.015, -0.02), (0.02, 0.015, 0.02)), roof, pillar, base)
  grasp = _grasp()
  assert _failure(model, grasp, FINGERS) == 'jaw_collision'
  no_sweep = QualityConfig(geometry=GripperGeometry(standoff=0.0))
  assert _failure(model, grasp, FINGERS, no_sweep) == 'none'
  assert _failure(model, grasp, POINT_JAWS) == 'none'


def test_heap_reward_and_single_object_quality_test_the_same_points(box):
  """Same gripper, same test: in a heap holding only the object (moved 30 cm up), the heap reward's object
  collision is exactly the single-object test `jaw_collides` (samples and refined points), which flags every grasp
  with a plain sample deeper than the tolerance and more; both follow the gripper's sizes."""
  scene = HeapScene(models=stack_models([box]), object_ids=jnp.zeros(1, jnp.int32), mask=jnp.ones(1, bool),
                    poses=jnp.asarray([[0.0, 0.0, 0.3, 1.0, 0.0, 0.0, 0.0]], jnp.float32),
                    friction=jnp.full(1, 0.8, jnp.float32))
  rng = np.random.default_rng(0)
  axes = np.tile([0.0, 0.0, 1.0], (48, 1))
  angles = rng.uniform(0, 2 * np.pi, 48)
  approaches = np.c_[np.cos(angles), np.sin(angles), np.zeros(48)]
  centers = rng.uniform([-0.04, -0.03, -0.005], [0.04, 0.03, 0.005], (48, 3))
  grasps = ParallelJawGrasp(center=jnp.asarray(centers, jnp.float32), axis=jnp.asarray(axes, jnp.float32),
                            approach=jnp.asarray(approaches, jnp.float32), width=jnp.full(48, 0.05, jnp.float32))
  shift = jnp.asarray([0.0, 0.0, 0.3], jnp.float32)
  outcomes = {}
  for name, gripper in (('default', FINGERS), ('short', FINGERS.replace(finger_length=0.04))):

    @jax.jit
    def one(g, gripper=gripper):
      heap = parallel_jaw_collisions(g.replace(center=g.center + shift), scene, Bin(), gripper)[0]
      pose = parallel_jaw_pose(g)
      pts = jaw_collision_points(gripper, GripperGeometry(), g.width) @ pose[:3, :3].T + pose[:3, 3]
      plain = jnp.any(jax.vmap(lambda p: sdf_value(box, p))(pts) < -TOL)
      return heap, plain, jaw_collides(box, g, gripper, GripperGeometry(), TOL)

    heap, plain, single = map(np.asarray, jax.vmap(one)(grasps))
    np.testing.assert_array_equal(heap, single)
    assert np.all(single[plain])
    outcomes[name] = heap
  assert 0 < outcomes['default'].sum() < outcomes['short'].sum()


def _box_depth(points: np.ndarray, lo, hi) -> np.ndarray:
  """Exact depth (metres, > 0 inside) of points (n, 3) in the axis-aligned box [lo, hi]."""
  return np.min(np.minimum(points - np.asarray(lo), np.asarray(hi) - points), axis=1)


def _dense_gripper_points(grasp, gripper, spacing=1e-3) -> np.ndarray:
  """(n, 3) object-frame points on a ``spacing`` lattice filling the swept fingers and palm (NumPy)."""
  rot, origin = np.asarray(parallel_jaw_pose(grasp))[:3, :3], np.asarray(grasp.center)
  out = []
  for lo, hi, _ in jaw_solids(gripper, GripperGeometry(), grasp.width):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    axes = [np.linspace(a, b, max(2, int(np.ceil((b - a) / spacing)) + 1)) for a, b in zip(lo, hi)]
    out.append(np.stack(np.meshgrid(*axes, indexing='ij'), -1).reshape(-1, 3))
  return np.concatenate(out) @ rot.T + origin


@pytest.mark.parametrize('name', ['box', 'l_shape'])
def test_sampler_keeps_only_grasps_whose_fingers_fit(name, box, cache_dir):
  """Valid sampled grasps are checked against the exact solids (boxes) on a 1 mm lattice of the swept gripper:
  nothing reaches deeper than the tolerance plus the grid's rounding; today's point-jaw samples on the same key
  do reach deep, so the check can fail."""
  from dexjax.objects import load_object_model
  model = box if name == 'box' else load_object_model('builtin:l_shape', cache_dir=cache_dir, grid_size=64)
  lo, hi = np.asarray(builtin_mesh(name).bounds)
  if name == 'box':
    solids = [(lo, hi)]
  else:  # the foot along x at the bottom and the upright at +x
    solids = [(lo, (hi[0], hi[1], lo[2] + L_SHAPE_FOOT_EXTENTS[2])),
              ((hi[0] - L_SHAPE_UPRIGHT_EXTENTS[0], lo[1], lo[2]), hi)]
  sample = jax.jit(sample_antipodal_grasps, static_argnums=2)
  depths = {}
  for label, gripper in (('fingers', FINGERS), ('points', POINT_JAWS)):
    grasps, valid = sample(jax.random.key(4), model, 96, gripper)
    idx = np.flatnonzero(np.asarray(valid))
    assert len(idx) >= 8, (label, len(idx))
    worst = []
    for i in idx[:20]:
      g = jax.tree.map(lambda x, i=i: x[i], grasps)
      pts = _dense_gripper_points(g, FINGERS)
      # A lower bound of the depth in a union of boxes: the largest depth in any one box (exact for one box).
      worst.append(max(_box_depth(pts, a, b).max() for a, b in solids))
    depths[label] = np.array(worst)
  voxel = float(model.voxel_size)
  assert depths['fingers'].max() <= TOL + voxel, depths['fingers'].max()
  assert np.mean(depths['points'] > TOL + voxel) >= 0.2 and depths['points'].max() > 5e-3, depths['points']


@pytest.mark.parametrize('fields, field, expected', [
    ({'finger_thickness': -0.001}, 'finger_thickness', '>= 0'),
    ({'finger_width': 0.0}, 'finger_width', '> 0'),
    ({'finger_length': 0.0, 'tip_depth': 0.0}, 'finger_length', '> 0'),
    ({'tip_depth': 0.07}, 'tip_depth', '[0, finger_length = 0.06]'),
    ({'palm_depth': 0.0}, 'palm_depth', '> 0'),
    ({'palm_width': 0.06}, 'palm_width', 'max_width + 2 finger_thickness = 0.07'),
    ({'max_width': 0.08}, 'palm_width', 'max_width + 2 finger_thickness = 0.1'),
    ({'palm_height': -1.0}, 'palm_height', '> 0'),
])
def test_gripper_validation_names_the_finger_field(fields, field, expected):
  with pytest.raises(ConfigError) as e:
    ParallelJawGripper(**fields).validate('my.yaml', 'grippers.parallel_jaw')
  msg = str(e.value)
  assert f'my.yaml: grippers.parallel_jaw.{field}: expected' in msg and expected in msg, msg
  # Point jaws need no room in the palm for the fingers; a wider palm is always fine.
  ParallelJawGripper(finger_thickness=0.0, palm_width=0.05).validate()
  ParallelJawGripper(palm_width=0.2).validate()


def test_finger_fields_load_validate_and_reach_the_cli_report(tmp_path, capsys):
  """The new gripper and quality fields load from YAML, are checked with file and field, appear in the report's
  parameters, and decide `jaw_collision` in `python -m dexjax.quality` (fork mesh written here)."""
  import json

  from dexjax.generate.config import config_from_dict
  from dexjax.quality.__main__ import main
  from dexjax.quality.report import load_settings
  cfg = tmp_path / 'points.yaml'
  cfg.write_text('grippers:\n  parallel_jaw:\n    finger_thickness: 0.0\n    palm_width: 0.06\n'
                 'quality:\n  collision_tolerance: 0.002\n  geometry:\n    spacing: 0.0025\n')
  settings = load_settings(cfg)
  assert settings.parallel_jaw.finger_thickness == 0.0 and settings.parallel_jaw.palm_width == 0.06
  assert settings.config.collision_tolerance == 0.002 and settings.config.geometry.spacing == 0.0025
  bad = tmp_path / 'bad.yaml'
  for text, field in (('grippers:\n  parallel_jaw:\n    palm_width: 0.06\n', 'grippers.parallel_jaw.palm_width'),
                      ('quality:\n  geometry:\n    spacing: 0.0\n', 'quality.geometry.spacing'),
                      ('quality:\n  geometry:\n    spacingg: 0.1\n', 'quality.geometry.spacingg')):
    bad.write_text(text)
    with pytest.raises(ConfigError, match=f'bad.yaml: {field}'):
      load_settings(bad)
  # Generation configs: one collision tolerance, the quality section's, also for the reward.
  tied = config_from_dict({'quality': {'collision_tolerance': 0.002}}, 'gen.yaml')
  assert tied.reward.quality.collision_tolerance == 0.002 == tied.grippers.config.collision_tolerance
  with pytest.raises(ConfigError, match='gen.yaml: reward.collision_tolerance: moved to quality.collision_tolerance'):
    config_from_dict({'reward': {'collision_tolerance': 0.002}}, 'gen.yaml')
  # The CLI on the fork: the grasp into the slot collides with the default fingers and holds with point jaws.
  mesh = trimesh.boolean.union([_box(lo, hi) for lo, hi in (BLOCK, SLOT_WALL, BASE)], engine='manifold')
  mesh_path = tmp_path / 'fork.stl'
  mesh.export(mesh_path)
  grasps = tmp_path / 'g.json'
  grasps.write_text(json.dumps({'grasps': [{'gripper': 'parallel_jaw', 'center': [0, 0, 0], 'axis': [1, 0, 0],
                                            'approach': [0, 0, -1]}]}))
  cfg.write_text('grippers:\n  parallel_jaw:\n    finger_thickness: 0.0\n')
  docs = {}
  for name, extra in (('fingers', []), ('points', ['--config', str(cfg)])):
    out = tmp_path / f'{name}.json'
    assert main([str(mesh_path), '--grasps', str(grasps), '--samples', '4', '--out', str(out), *extra]) == 0
    docs[name] = json.loads(out.read_text())
  assert docs['fingers']['grasps'][0]['nominal_failure'] == 'jaw_collision'
  assert docs['fingers']['grasps'][0]['robust_probability'] == 0.0
  assert docs['points']['grasps'][0]['nominal_failure'] == 'none'
  params = docs['fingers']['parameters']
  assert params['grippers']['parallel_jaw']['finger_thickness'] == 0.01
  assert params['grippers']['parallel_jaw']['palm_width'] == 0.07
  assert params['quality']['collision_tolerance'] == 0.001 and params['quality']['geometry']['standoff'] == 0.05
  assert docs['points']['parameters']['grippers']['parallel_jaw']['finger_thickness'] == 0.0
