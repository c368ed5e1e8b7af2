"""The GQ-CNN training loop on a small synthetic dataset: reproducible batches, learning, resuming after an
interruption, checkpoints, save / load, the train and evaluate command lines, and config errors.

The dataset is synthetic on purpose (a test must not wait for the generator's compile): flat depth images with a
9 x 9 bump (label 1) or pit (label 0) under each grasp, one per grasp on a grid, so the label is visible in the
crop and a working loop must learn it.
"""

from __future__ import annotations

import dataclasses
import json

import jax
import numpy as np
import pytest

from dexjax.config import ConfigError
from dexjax.data import GRIPPER_NAMES, shard_path, write_shard
from dexjax.models import load, predict
from dexjax.train import (CheckpointConfig, Interrupted, LoopConfig, TrainConfig, dataset_stats, evaluate_model,
                          final_state_params, load_train_config, read_records, train_batches, train_config_from_dict,
                          train_gripper)

_SIZE, _GRID = 112, 24


def _write_dataset(out_dir, num_shards: int = 4, images_per_shard: int = 4, seed: int = 0,
                   shard_offset: float = 0.0) -> None:
  """``shard_offset``: shard s's depth is raised by s times this (metres), so rows of different shards differ."""
  rng = np.random.default_rng(seed)
  centers = [(u, v) for v in range(20, _SIZE - 19, _GRID) for u in range(20, _SIZE - 19, _GRID)]  # 4 x 4 grasps
  for s in range(num_shards):
    n = images_per_shard
    depth = (0.8 + s * shard_offset + rng.normal(0, 0.001, (n, _SIZE, _SIZE))).astype(np.float32)
    rows = {k: [] for k in ('gripper', 'center', 'angle', 'depth', 'approach', 'reward', 'image')}
    for i in range(n):
      for k, (u, v) in enumerate(centers):
        label = int(rng.random() < 0.3)
        depth[i, v - 4:v + 5, u - 4:u + 5] = 0.77 if label else 0.83
        for key, value in zip(rows, (k % 2, (u, v), rng.uniform(-np.pi, np.pi), 0.77 + rng.normal(0, 0.01),
                                     rng.uniform(-0.5, 0.5), label, i)):
          rows[key].append(value)
    m = len(rows['reward'])
    images = {'depth': depth, 'mask': np.zeros((n, _SIZE, _SIZE), np.int32),
              'camera_intrinsics': np.tile(np.float32([500, 500, _SIZE / 2, _SIZE / 2]), (n, 1)),
              'camera_rotation': np.tile(np.eye(3, dtype=np.float32), (n, 1, 1)),
              'camera_translation': np.zeros((n, 3), np.float32),
              'heap_id': np.arange(s * n, (s + 1) * n, dtype=np.int64), 'object_ids': np.zeros((n, 1), np.int32),
              'object_poses': np.zeros((n, 1, 7), np.float32), 'object_names': np.array([['box']] * n),
              'object_friction': np.full((n, 1), 0.8, np.float32), 'object_mass': np.full((n, 1), 0.2, np.float32)}
    reward = np.int8(rows['reward'])
    table = {'gripper': np.int8(rows['gripper']), 'center': np.float32(rows['center']),
             'angle': np.float32(rows['angle']), 'grasp_depth': np.float32(rows['depth']),
             'approach_angle': np.float32(rows['approach']), 'grasp_pose': np.tile(np.eye(4, dtype=np.float32),
                                                                                   (m, 1, 1)),
             'reward': reward, 'robust_probability': reward * np.float32(0.9), 'failure': np.zeros(m, np.int8),
             'target_slot': np.zeros(m, np.int8), 'policy': np.zeros(m, np.int8),
             'image_index': np.int32(rows['image'])}
    write_shard(shard_path(out_dir, s), images, table, {'config_fingerprint': 'synthetic', 'seed': seed, 'index': s})


CONFIG = TrainConfig(crop_window=32, grippers=('parallel_jaw',),
                     split=dataclasses.replace(TrainConfig().split, val_fraction=0.25),
                     loop=LoopConfig(epochs=3, batch_size=16, eval_batch_size=64, normalization_rows=500),
                     checkpoint=CheckpointConfig(every_steps=4, keep=2))


@pytest.fixture(scope='module')
def data(tmp_path_factory):
  path = tmp_path_factory.mktemp('synthetic')
  _write_dataset(path, images_per_shard=8)
  return path


@pytest.fixture(scope='module')
def stats(data):
  return dataset_stats(data, CONFIG)['parallel_jaw']


@pytest.fixture(scope='module')
def full_run(data, stats, tmp_path_factory):
  """An uninterrupted 3-epoch run of the parallel-jaw network."""
  out = tmp_path_factory.mktemp('full')
  best = train_gripper(data, out, CONFIG, 'parallel_jaw', stats, log=lambda *a: None)
  return out, best


def test_stats_count_the_training_rows_of_the_gripper(data, stats):
  batches = list(train_batches(data, CONFIG, 'parallel_jaw', 0, stats))
  labels = np.concatenate([b['labels'] for b in batches])
  assert len(labels) == stats.train_rows // 16 * 16  # whole batches only
  assert 0.15 < stats.positive_rate < 0.45
  assert float(stats.normalization.image_std) > 0


def test_normalization_is_fitted_on_a_uniform_random_subset_of_the_training_rows(tmp_path):
  """Rows of each shard lie at their own depth: statistics of the first rows read would be one shard's; a uniform
  random subset has (within sampling error) the mean of all training rows, computed here by brute force."""
  from dexjax.data import iterate_rows
  from dexjax.models import fit_normalization
  from dexjax.train import gripper_examples
  _write_dataset(tmp_path, num_shards=4, images_per_shard=8, shard_offset=0.1)
  config = dataclasses.replace(CONFIG, loop=dataclasses.replace(CONFIG.loop, normalization_rows=40))
  sub = dataset_stats(tmp_path, config)['parallel_jaw']
  everything = [(ex['crops'], ex['poses']) for batch in iterate_rows(
      tmp_path, 'train', batch_size=1000, seed=0, by=config.split.by, val_fraction=config.split.val_fraction,
      split_seed=config.split.seed) if (ex := gripper_examples(
          {k: v[batch['gripper'] == 0] for k, v in batch.items()}, 'parallel_jaw', config.model.crop_size,
          config.crop_window))['crops'].size]
  full = fit_normalization(everything)
  assert sub.train_rows > 3 * 40
  # Shards sit 0.1 m apart (per-row std of the shard offset ~0.11 m): 40 random rows land within ~0.02 m.
  assert abs(float(sub.normalization.image_mean) - float(full.image_mean)) < 0.05
  assert float(sub.normalization.image_std) > 0.07  # rows of several shards, not one shard's 0.02 m bumps
  again = dataset_stats(tmp_path, config)['parallel_jaw']
  assert float(again.normalization.image_mean) == float(sub.normalization.image_mean)  # seeded


def test_batches_are_reproducible_and_skipping_resumes_the_same_order(data, stats):
  epoch1 = list(train_batches(data, CONFIG, 'parallel_jaw', 1, stats))
  again = list(train_batches(data, CONFIG, 'parallel_jaw', 1, stats, skip=3))
  assert len(again) == len(epoch1) - 3
  for a, b in zip(epoch1[3:], again):
    np.testing.assert_array_equal(a['crops'], b['crops'])
    np.testing.assert_array_equal(a['labels'], b['labels'])
  epoch2 = list(train_batches(data, CONFIG, 'parallel_jaw', 2, stats))
  assert not np.array_equal(epoch1[0]['crops'], epoch2[0]['crops'])  # a new order every epoch
  # Class weights: each class carries half of the loss over the training split.
  w_neg, w_pos = stats.class_weights()
  assert w_pos * stats.train_positives == pytest.approx(w_neg * (stats.train_rows - stats.train_positives))
  assert set(np.unique(epoch1[0]['weights'])) <= {np.float32(w_neg), np.float32(w_pos)}


def test_undersampling_keeps_every_positive_and_balances_the_classes(data, stats):
  config = dataclasses.replace(CONFIG, loop=dataclasses.replace(CONFIG.loop, class_balance='undersample',
                                                                batch_size=4))
  labels = np.concatenate([b['labels'] for b in train_batches(data, config, 'parallel_jaw', 0, stats)])
  assert labels.sum() >= stats.train_positives - 4  # all positives (up to the dropped last partial batch)
  assert 0.35 < labels.mean() < 0.65


def test_training_learns_the_synthetic_task_and_writes_metrics(full_run):
  out, best = full_run
  records = read_records(out)
  assert [r['epoch'] for r in records] == [1, 2, 3]
  for key in ('gripper', 'epoch', 'val_accuracy', 'val_balanced_accuracy', 'val_average_precision', 'train_loss'):
    assert key in records[0]
  assert records[-1]['train_loss'] < records[0]['train_loss']
  assert best['val_balanced_accuracy'] >= 0.8
  assert (out / 'curves.png').stat().st_size > 0


def test_saved_model_loads_with_identical_predictions_and_metrics(data, full_run):
  out, best = full_run
  model = load(out, 'parallel_jaw')
  again = load(out / 'parallel_jaw')
  crops = np.random.default_rng(0).normal(0.8, 0.02, (8, 32, 32, 1)).astype(np.float32)
  poses = np.full((8, 1), 0.77, np.float32)
  np.testing.assert_array_equal(np.asarray(predict(model, crops, poses)), np.asarray(predict(again, crops, poses)))
  # Its fully convolutional use on a whole image scores the crop at each stride-aligned cell the same way.
  depth = np.random.default_rng(1).normal(0.8, 0.02, (48, 44)).astype(np.float32)
  cells = np.asarray(jax.jit(model.score_image)(depth, poses[0]))
  assert cells.shape == (5, 4)  # (48 - 32) // 4 + 1, (44 - 32) // 4 + 1
  crops_at = np.stack([depth[4 * i:4 * i + 32, 4 * j:4 * j + 32] for i, j in ((0, 0), (2, 3), (4, 1))])[..., None]
  np.testing.assert_allclose(np.asarray(predict(model, crops_at, poses[:3])), cells[[0, 2, 4], [0, 3, 1]],
                             atol=2e-5)
  # The loaded model reproduces the validation metrics recorded when it was saved.
  metrics = evaluate_model(model, data, CONFIG, 'val')
  assert metrics['balanced_accuracy'] == pytest.approx(best['val_balanced_accuracy'])
  assert metrics['loss'] == pytest.approx(best['val_loss'], rel=1e-5)


def test_run_interrupted_mid_epoch_resumes_to_the_same_parameters(data, stats, full_run, tmp_path):
  out_full, _ = full_run
  steps_per_epoch = stats.train_rows // 16
  stop = steps_per_epoch + 6  # inside epoch 2, two steps after a periodic checkpoint
  assert stop % CONFIG.checkpoint.every_steps != 0
  with pytest.raises(Interrupted):
    train_gripper(data, tmp_path, CONFIG, 'parallel_jaw', stats, stop_after_steps=stop, log=lambda *a: None)
  with pytest.raises(FileExistsError, match='--resume'):
    train_gripper(data, tmp_path, CONFIG, 'parallel_jaw', stats, log=lambda *a: None)
  train_gripper(data, tmp_path, CONFIG, 'parallel_jaw', stats, resume=True, log=lambda *a: None)
  resumed = final_state_params(tmp_path, CONFIG, 'parallel_jaw', stats)
  uninterrupted = final_state_params(out_full, CONFIG, 'parallel_jaw', stats)
  jax.tree.map(np.testing.assert_array_equal, resumed, uninterrupted)
  drop = lambda r: {k: v for k, v in r.items() if k != 'examples_per_s'}
  assert [drop(r) for r in read_records(tmp_path)] == [drop(r) for r in read_records(out_full)]
  # An epoch's end that is also a periodic step: its checkpoint says the epoch is done, so a resumed run starts
  # the next epoch (and does not validate the finished one again).
  every2 = dataclasses.replace(CONFIG, checkpoint=dataclasses.replace(CONFIG.checkpoint, every_steps=2))
  other, lines = tmp_path / 'every2', []
  end2 = 2 * steps_per_epoch  # the end of epoch 2, even: also a periodic step
  with pytest.raises(Interrupted):
    train_gripper(data, other, every2, 'parallel_jaw', stats, stop_after_steps=end2 + 1, log=lambda *a: None)
  train_gripper(data, other, every2, 'parallel_jaw', stats, resume=True, log=lines.append)
  assert f'resumed at step {end2} (epoch 3, batch 0)' in lines[0]
  jax.tree.map(np.testing.assert_array_equal, final_state_params(other, CONFIG, 'parallel_jaw', stats),
               uninterrupted)


def test_train_and_evaluate_command_lines(data, tmp_path, capsys):
  from dexjax.evaluate import main as evaluate_main
  from dexjax.train.__main__ import main as train_main
  config = tmp_path / 'tiny.yaml'
  config.write_text('grippers: [parallel_jaw]\nloop: {epochs: 1, batch_size: 16, normalization_rows: 200}\n'
                    'split: {val_fraction: 0.25}\n')
  out = tmp_path / 'run'
  assert train_main(['--config', str(config), '--data', str(data), '--out', str(out), '--no-progress']) == 0
  printed = capsys.readouterr().out
  assert 'parallel_jaw' in printed and 'best' in printed
  metrics_before = (out / 'metrics.jsonl').read_text()
  # A second run into the same directory without --resume changes nothing.
  assert train_main(['--config', str(config), '--data', str(data), '--out', str(out), '--no-progress']) == 2
  assert '--resume' in capsys.readouterr().err
  assert (out / 'metrics.jsonl').read_text() == metrics_before
  assert evaluate_main(['--checkpoint', str(out), '--data', str(data), '--split', 'val', '--no-progress']) == 0
  result = json.loads(capsys.readouterr().out)
  record = read_records(out)[0]
  assert result['grippers']['parallel_jaw']['balanced_accuracy'] == pytest.approx(record['val_balanced_accuracy'])
  assert result['grippers']['parallel_jaw']['examples'] == record['val_examples']
  assert evaluate_main(['--checkpoint', str(tmp_path / 'nothing'), '--data', str(data)]) == 2
  assert 'no saved GQ-CNN' in capsys.readouterr().err


def test_training_on_several_datasets_reads_their_union(data, tmp_path, capsys):
  """``--data A B``: one run on both datasets; every row of both is in exactly one split, the summary names both,
  and evaluation with intervals groups heaps per dataset (the two share heap ids)."""
  from dexjax.data import iterate_rows
  from dexjax.evaluate import main as evaluate_main
  from dexjax.train.__main__ import main as train_main
  other = tmp_path / 'other'
  _write_dataset(other, num_shards=2, images_per_shard=8, seed=1)
  config = tmp_path / 'tiny.yaml'
  config.write_text('grippers: [parallel_jaw]\nloop: {epochs: 1, batch_size: 16, normalization_rows: 200}\n'
                    'split: {val_fraction: 0.25}\n')
  out = tmp_path / 'run'
  assert train_main(['--config', str(config), '--data', str(data), str(other), '--out', str(out), '--no-progress',
                     '--json']) == 0
  summary = json.loads(capsys.readouterr().out)
  assert summary['data'] == [str(data), str(other)]
  stats = json.loads((out / 'stats.json').read_text())['parallel_jaw']
  val = summary['grippers']['parallel_jaw']['val_examples']
  jaw_rows = lambda d: sum(int((b['gripper'] == 0).sum()) for s in ('train', 'val') for b in iterate_rows(d, s))
  assert stats['train_rows'] + val == jaw_rows(data) + jaw_rows(other)
  both = dataclasses.replace(CONFIG, grippers=('parallel_jaw',))
  model = load(out / 'parallel_jaw')
  metrics = evaluate_model(model, [data, other], both, 'val', interval_by='heap', num_resamples=20)
  assert metrics['examples'] == val and metrics['intervals']['by'] == 'heap'
  # The evaluate CLI scores the same union: ``--data A B`` (the run's split rule, from its config).
  assert evaluate_main(['--checkpoint', str(out), '--data', str(data), str(other), '--split', 'val',
                        '--no-progress']) == 0
  result = json.loads(capsys.readouterr().out)
  assert result['data'] == [str(data.absolute()), str(other.absolute())]
  assert result['grippers']['parallel_jaw']['examples'] == val
  assert result['grippers']['parallel_jaw']['balanced_accuracy'] == pytest.approx(metrics['balanced_accuracy'])
  assert evaluate_main(['--checkpoint', str(out), '--data', str(data), str(tmp_path / 'none')]) == 2
  assert f"{tmp_path / 'none'}: no dataset shards" in capsys.readouterr().err


def test_configs_and_their_errors(tmp_path):
  recipe = load_train_config('configs/dexnet4_pj.yaml')
  assert recipe.grippers == ('parallel_jaw',) and recipe.model.crop_size == 96 == recipe.crop_window
  assert (recipe.loop.epochs, recipe.loop.batch_size, recipe.loop.class_balance) == (50, 64, 'none')
  assert recipe.optimizer.learning_rate == 0.01 and recipe.model.conv_kernels == (9, 5, 5, 5)
  assert load_train_config('configs/dexnet4_suction.yaml').grippers == ('suction',)
  assert load_train_config('configs/quickstart.yaml') == TrainConfig() == load_train_config(None)
  shipped = load_train_config('configs/pretrained.yaml')  # the recipe of the shipped models (docs/models.md)
  assert (shipped.model.crop_size, shipped.crop_window, shipped.loop.class_balance) == (32, 96, 'weight')
  assert shipped.model.input_depth_mode == 'im_depth_sub'
  finetune = load_train_config('configs/finetune.yaml')
  assert finetune.init == 'pretrained' and finetune.optimizer.learning_rate == 0.002 and finetune.loop.epochs == 4
  with pytest.raises(ConfigError, match="x.yaml: loop.class_balance: expected one of"):
    train_config_from_dict({'loop': {'class_balance': 'often'}}, 'x.yaml')
  with pytest.raises(ConfigError, match='x.yaml: model.conv_kernel: unknown field'):
    train_config_from_dict({'model': {'conv_kernel': [3]}}, 'x.yaml')
  with pytest.raises(ConfigError, match='x.yaml: crop_window: expected >= model.crop_size'):
    train_config_from_dict({'crop_window': 16}, 'x.yaml')
  with pytest.raises(ConfigError, match='grippers'):
    train_config_from_dict({'grippers': ['claw']}, 'x.yaml')
  assert GRIPPER_NAMES == TrainConfig().grippers


_TWO_DEVICES = '''
import sys, dataclasses, jax
sys.path.insert(0, {tests!r})
from test_train_loop import CONFIG
from dexjax.train import dataset_stats, train_gripper
assert jax.device_count() == 2, jax.devices()
config = dataclasses.replace(CONFIG, loop=dataclasses.replace(CONFIG.loop, epochs=1))
stats = dataset_stats({data!r}, config)['parallel_jaw']
train_gripper({data!r}, {out!r}, config, 'parallel_jaw', stats, log=lambda *a: None)
'''


def test_data_parallel_over_two_devices_matches_one_device(data, stats, tmp_path):
  """The same run with each batch split over two (virtual CPU) devices ends with the same parameters."""
  import os
  import subprocess
  import sys
  from pathlib import Path
  env = dict(os.environ, XLA_FLAGS='--xla_force_host_platform_device_count=2', JAX_PLATFORMS='cpu')
  script = _TWO_DEVICES.format(tests=str(Path(__file__).parent), data=str(data), out=str(tmp_path / 'two'))
  subprocess.run([sys.executable, '-c', script], check=True, env=env, timeout=600)
  config = dataclasses.replace(CONFIG, loop=dataclasses.replace(CONFIG.loop, epochs=1))
  train_gripper(data, tmp_path / 'one', config, 'parallel_jaw', stats, log=lambda *a: None)
  two = final_state_params(tmp_path / 'two', config, 'parallel_jaw', stats)
  one = final_state_params(tmp_path / 'one', config, 'parallel_jaw', stats)
  jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5), two, one)


@pytest.mark.heavy
def test_train_cli_killed_with_sigkill_resumes_to_the_same_parameters(data, stats, tmp_path):
  """A real kill (SIGKILL, mid-epoch, at any moment relative to checkpoint writes) and ``--resume``."""
  import os
  import signal
  import subprocess
  import sys
  import time
  config = dataclasses.replace(CONFIG, loop=dataclasses.replace(CONFIG.loop, epochs=8))
  path = tmp_path / 'config.yaml'
  path.write_text('crop_window: 32\ngrippers: [parallel_jaw]\nsplit: {val_fraction: 0.25}\n'
                  'loop: {epochs: 8, batch_size: 16, eval_batch_size: 64, normalization_rows: 500}\n'
                  'checkpoint: {every_steps: 4, keep: 2}\n')
  argv = [sys.executable, '-m', 'dexjax.train', '--config', str(path), '--data', str(data), '--out',
          str(tmp_path / 'killed'), '--no-progress']
  process = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
  target = stats.train_rows // 16 * 2 + 3  # a step inside the third epoch
  checkpoints = tmp_path / 'killed' / 'parallel_jaw' / 'checkpoints'
  deadline = time.time() + 300
  while time.time() < deadline and process.poll() is None:
    steps = [int(p.name) for p in checkpoints.glob('*') if p.name.isdigit()]  # not orbax's temporary dirs
    if steps and max(steps) >= target:
      break
    time.sleep(0.05)
  os.kill(process.pid, signal.SIGKILL)
  process.wait()
  assert len(read_records(tmp_path / 'killed')) < 8  # killed before the end
  assert subprocess.run(argv + ['--resume'], stdout=subprocess.DEVNULL, timeout=600).returncode == 0
  train_gripper(data, tmp_path / 'whole', config, 'parallel_jaw', stats, log=lambda *a: None)
  killed = final_state_params(tmp_path / 'killed', config, 'parallel_jaw', stats)
  whole = final_state_params(tmp_path / 'whole', config, 'parallel_jaw', stats)
  jax.tree.map(np.testing.assert_array_equal, killed, whole)
  assert [r['epoch'] for r in read_records(tmp_path / 'killed')] == list(range(1, 9))
