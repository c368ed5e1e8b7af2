"""``python -m dexjax.plan`` end to end on a depth image rendered from procedural objects the project never trained
on (level 2, seeds 500-505), with the camera's intrinsics file: every policy returns a grasp centred on an object
(its pixel inside that object's rendered mask) with a 4 x 4 pose; a noisy 16-bit PNG with holes still plans; bad
input gets one clear error line, and an image without graspable pixels a documented "no grasp" result.

Most tests use untrained quick-start networks (what they predict does not matter there; where the policies may
look does); without ``--model`` the shipped models plan.
"""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dexjax.cli import is_dexjax_png
from dexjax.models import GQCNNConfig, GraspQualityModel, Normalization, init_gqcnn, save_model
from dexjax.plan import main as plan_main
from dexjax.policy import IMAGE_POLICIES
from dexjax.render.__main__ import main as render_main


@pytest.fixture(scope='module')
def scene(tmp_path_factory, cache_dir):
  root = tmp_path_factory.mktemp('plan')
  with pytest.MonkeyPatch.context() as mp:
    mp.setenv('DEXJAX_CACHE', str(cache_dir))
    assert render_main(['heap', str(root / 'heap.png'), '--seed', '3', '--objects', 'procedural:L2/500:506',
                        '--npz', str(root / 'heap.npz')]) == 0
  data = np.load(root / 'heap.npz')
  fx, fy, cx, cy = (float(v) for v in data['intrinsics'])
  h, w = data['depth'].shape
  (root / 'K.json').write_text(json.dumps({'fx': fx, 'fy': fy, 'cx': cx, 'cy': cy, 'width': w, 'height': h}))
  np.save(root / 'depth.npy', data['depth'])
  for gripper, pose_dim in (('parallel_jaw', 1), ('suction', 2)):
    config = GQCNNConfig.small(pose_dim=pose_dim)
    norm = Normalization(jnp.float32(0.68), jnp.float32(0.03), jnp.full(pose_dim, 0.3), jnp.full(pose_dim, 0.2))
    model = GraspQualityModel(init_gqcnn(jax.random.key(pose_dim), config), norm, config, gripper, 96)
    save_model(root / 'run' / gripper / 'best', 0, model)
  return root, data['mask']


def _plan(root, *extra):
  return plan_main([str(root / 'depth.npy'), '--intrinsics', str(root / 'K.json'), '--model', str(root / 'run'),
                    '--out', str(root / 'plan.json'), '--overwrite', '--num-candidates', '100', *extra])


def _on_object(plan, mask) -> bool:
  u, v = (int(round(x)) for x in plan['pixel'])
  return mask[v, u] >= 0


def test_every_policy_grasps_an_object_with_a_pose(scene):
  root, mask = scene
  for policy in IMAGE_POLICIES:  # the supervisor needs a simulated bin
    assert _plan(root, '--policy', policy, '--cem', 'gqcnn') == 0, policy
    plan = json.loads((root / 'plan.json').read_text())
    assert plan['policy'] == policy and plan['gripper'] in ('parallel_jaw', 'suction')
    assert _on_object(plan, mask), (policy, plan['pixel'])
    pose = np.asarray(plan['pose'])
    assert pose.shape == (4, 4) and np.allclose(pose[:3, :3].T @ pose[:3, :3], np.eye(3), atol=1e-5)
    assert pose[2, 3] == pytest.approx(plan['depth'], abs=1e-5)  # camera-frame z of the grasp point
    assert plan['plan_s'] > 0 and plan['observation']['segmentation'] == 'plane'
    if policy == 'ambidextrous':
      assert set(plan['grippers']) == {'parallel_jaw', 'suction'}
      best = max(plan['grippers'].values(), key=lambda g: g['probability'])
      assert best['gripper'] == plan['gripper'] and best['probability'] == plan['probability']


def test_a_noisy_16_bit_png_with_holes_plans_on_an_object(scene, tmp_path):
  from PIL import Image  # pylint: disable=g-import-not-at-top
  root, mask = scene
  depth = np.load(root / 'depth.npy')
  rng = np.random.default_rng(0)
  noisy = depth + rng.normal(0.0, 0.001, depth.shape)
  noisy[rng.random(depth.shape) < 0.05] = 0.0  # 5 % of the pixels without a return, as a real sensor
  Image.fromarray(np.round(noisy * 1000).astype(np.uint16)).save(tmp_path / 'depth.png')
  out, png = tmp_path / 'plan.json', tmp_path / 'plan.png'
  assert plan_main([str(tmp_path / 'depth.png'), '--intrinsics', str(root / 'K.json'), '--model', str(root / 'run'),
                    '--out', str(out), '--png', str(png), '--policy', 'suction', '--cem', 'gqcnn']) == 0
  plan = json.loads(out.read_text())
  assert _on_object(plan, mask) and plan['observation']['invalid_fraction'] == pytest.approx(0.05, abs=0.005)
  assert is_dexjax_png(png)


def test_bad_input_gets_one_clear_error(scene, tmp_path, capsys):
  root, _ = scene
  depth = np.load(root / 'depth.npy')
  k = json.loads((root / 'K.json').read_text())
  (tmp_path / 'K_small.json').write_text(json.dumps({**k, 'width': 400}))
  np.save(tmp_path / 'nan.npy', np.full_like(depth, np.nan))
  np.save(tmp_path / 'empty.npy', np.zeros(depth.shape, bool))
  cases = [
      (['--intrinsics', str(tmp_path / 'K_small.json')], '500x500'),
      (['--segmask', str(tmp_path / 'empty.npy')], 'empty'),
      (['--model', str(tmp_path)], 'no saved GQ-CNN'),
      (['--polish', '-1'], '--polish: expected a number of steps >= 0'),
      (['--policy', 'ranking', '--polish', '3'], 'only the CEM policies'),
  ]
  for extra, message in cases:
    args = [str(root / 'depth.npy'), '--intrinsics', str(root / 'K.json'), '--model', str(root / 'run'),
            '--out', str(tmp_path / 'p.json')]
    for i in range(0, len(extra), 2):  # an option given again replaces the default above
      if extra[i] in args:
        args[args.index(extra[i]) + 1] = extra[i + 1]
      else:
        args += extra[i:i + 2]
    assert plan_main(args) == 2, extra
    err = capsys.readouterr().err
    assert err.startswith('error: ') and message in err and 'Traceback' not in err, err
  assert plan_main([str(tmp_path / 'nan.npy'), '--intrinsics', str(root / 'K.json'), '--out', str(tmp_path / 'p.json'),
                    '--policy', 'suction_heuristic']) == 2
  assert 'no valid' in capsys.readouterr().err
  assert not (tmp_path / 'p.json').exists()


def test_without_model_the_shipped_models_plan(scene, tmp_path):
  """A fresh install plans at once: no --model, no training run, no network (here with gradient polishing)."""
  root, mask = scene
  before = jax.config.jax_compilation_cache_dir
  assert plan_main([str(root / 'depth.npy'), '--intrinsics', str(root / 'K.json'), '--out', str(tmp_path / 'p.json'),
                    '--num-candidates', '100', '--polish', '4']) == 0
  # Compiled plans go to $DEXJAX_CACHE/jax only while the plan compiles: later compilations in this process do not.
  assert jax.config.jax_compilation_cache_dir == before
  plan = json.loads((tmp_path / 'p.json').read_text())
  assert plan['model'] == 'pretrained' and plan['gripper'] in ('parallel_jaw', 'suction')
  assert plan['polish_steps'] == 4  # the shipped models' best grasps polished by gradient steps
  assert _on_object(plan, mask) and 0.0 <= plan['probability'] <= 1.0


def test_no_graspable_pixel_is_a_documented_no_grasp_result(scene, tmp_path):
  root, _ = scene
  corner = np.zeros(np.load(root / 'depth.npy').shape, bool)
  corner[:20, :20] = True  # inside the crop border: no grasp may be centred there
  np.save(tmp_path / 'corner.npy', corner)
  out = tmp_path / 'plan.json'
  assert plan_main([str(root / 'depth.npy'), '--intrinsics', str(root / 'K.json'), '--segmask',
                    str(tmp_path / 'corner.npy'), '--out', str(out), '--policy', 'composite_heuristic',
                    '--num-candidates', '50']) == 1
  plan = json.loads(out.read_text())
  assert plan['gripper'] is None and 'border' in plan['reason']
