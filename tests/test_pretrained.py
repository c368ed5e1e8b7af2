"""The GQ-CNNs shipped with the package and single-file models: they load without a training run, score unseen
objects, `python -m dexjax.evaluate --checkpoint pretrained` scores them, and fine-tuning them on a small dataset
of new objects (`python -m dexjax.train --init pretrained`) beats training from scratch on the same data.

The dataset is generated here, with Dex-Net 4.0's camera and generation defaults, from procedural objects of a
seed no training set uses (``@11``): the conditions the shipped models are for.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from dexjax.generate import GenerateConfig, generate_dataset
from dexjax.models import (PRETRAINED, load, load_model_file, load_models, pretrained, pretrained_info,
                           save_model, save_model_file)
from dexjax.models.shipped import WEIGHTS_DIR, pretrained_path

GRIPPERS = ('parallel_jaw', 'suction')


def _inputs(model, n=16, seed=0):
  rng = np.random.default_rng(seed)
  s = model.config.crop_size
  crops = rng.uniform(0.65, 0.75, (n, s, s, 1)).astype(np.float32)
  poses = rng.uniform(0.0, 0.5, (n, model.config.pose_dim)) + [0.7, 0.0][:model.config.pose_dim]
  return crops, poses.astype(np.float32)


def test_shipped_models_load_from_the_package_for_both_grippers():
  for gripper in GRIPPERS:
    path = pretrained_path(gripper)
    assert path.parent == WEIGHTS_DIR and path.stat().st_size < 5_000_000  # "a few MB at most"
    model = pretrained(gripper)
    assert model.gripper == gripper and model.config.pose_dim == (1 if gripper == 'parallel_jaw' else 2)
    crops, poses = _inputs(model)
    probs = np.asarray(model(crops, poses))
    assert probs.shape == (16,) and np.all((probs >= 0) & (probs <= 1))
    info = pretrained_info(gripper)
    assert {'data', 'training', 'metrics'} <= set(info), info.keys()
  assert pretrained('suction') is pretrained('suction')  # cached
  with pytest.raises(ValueError, match='gripper: expected one of'):
    pretrained('vacuum')


def test_model_files_round_trip_and_bad_files_name_the_problem(tmp_path):
  model = pretrained('suction')
  path = save_model_file(tmp_path / 'm.msgpack', model, {'note': 'copy'})
  assert not list(tmp_path.glob('*.tmp'))
  again = load_model_file(path)
  crops, poses = _inputs(model)
  np.testing.assert_array_equal(np.asarray(again(crops, poses)), np.asarray(model(crops, poses)))
  assert again.config == model.config and again.crop_window == model.crop_window
  with pytest.raises(ValueError, match=r"m.msgpack: field 'gripper': expected 'parallel_jaw'"):
    load_model_file(path, 'parallel_jaw')
  (tmp_path / 'bad.msgpack').write_bytes(b'not a model')
  with pytest.raises(ValueError, match='bad.msgpack: not a dexjax model file'):
    load_model_file(tmp_path / 'bad.msgpack')
  # A file whose parameters do not fit its stated architecture (a wider first convolution).
  other = pretrained('parallel_jaw')
  wrong = dataclasses.replace(other, config=dataclasses.replace(
      other.config, conv_filters=(8,) + other.config.conv_filters[1:]))
  save_model_file(tmp_path / 'wrong.msgpack', wrong)
  with pytest.raises(ValueError, match="wrong.msgpack: field 'params'"):
    load_model_file(tmp_path / 'wrong.msgpack')
  with pytest.raises(FileNotFoundError, match='no such model file'):
    load_model_file(tmp_path / 'missing.msgpack')


def test_load_models_resolves_every_kind_of_model_path(tmp_path):
  assert set(load_models(None)) == set(GRIPPERS) and set(load_models(PRETRAINED, ('suction',))) == {'suction'}
  for gripper in GRIPPERS:
    save_model(tmp_path / 'run' / gripper / 'best', 3, pretrained(gripper))
  run = load_models(tmp_path / 'run')
  assert set(run) == set(GRIPPERS)
  crops, poses = _inputs(run['parallel_jaw'])
  np.testing.assert_allclose(np.asarray(run['parallel_jaw'](crops, poses)),
                             np.asarray(pretrained('parallel_jaw')(crops, poses)), atol=1e-6)
  assert set(load_models(tmp_path / 'run' / 'suction')) == {'suction'}
  assert set(load_models(save_model_file(tmp_path / 'pj.msgpack', pretrained('parallel_jaw')))) == {'parallel_jaw'}
  with pytest.raises(FileNotFoundError, match='no saved GQ-CNN'):
    load_models(tmp_path / 'nothing')


# ----- on generated data of unseen objects (heavy: generation compiles once, ~1-2 minutes) -----

UNSEEN = ('procedural:L1/0:3@11', 'procedural:L2/0:3@11', 'procedural:L3/0:3@11')


@pytest.fixture(scope='module')
def unseen(tmp_path_factory, cache_dir):
  """A 32-image dataset of 9 unseen objects with Dex-Net 4.0's generation defaults."""
  out = tmp_path_factory.mktemp('unseen')
  config = GenerateConfig()
  config = dataclasses.replace(config, objects=dataclasses.replace(config.objects, sources=UNSEEN))
  summary = generate_dataset(config, out, 32, cache_dir=str(cache_dir), progress=False, preview=False)
  assert not summary['shards']['failed']
  return out


@pytest.mark.heavy
def test_evaluate_pretrained_scores_unseen_objects(unseen, capsys):
  from dexjax.evaluate import main as evaluate_main  # pylint: disable=g-import-not-at-top
  assert evaluate_main(['--checkpoint', 'pretrained', '--data', str(unseen), '--no-progress', '--intervals', 'object',
                        '--resamples', '200']) == 0
  result = json.loads(capsys.readouterr().out)
  assert result['checkpoint'] == 'pretrained' and set(result['grippers']) == set(GRIPPERS)
  for gripper, metrics in result['grippers'].items():
    assert metrics['examples'] > 500 and metrics['positives'] > 5, (gripper, metrics)
    # Far above chance on objects it never saw (the model card has the full measurement on thousands of rows).
    assert metrics['balanced_accuracy'] > 0.7, (gripper, metrics)
    assert metrics['average_precision'] > 2 * metrics['positives'] / metrics['examples'], (gripper, metrics)
    # Resampling the 9 objects (and the heaps of grasps that touch none): an interval around each score.
    intervals = metrics['intervals']
    assert intervals['by'] == 'object' and intervals['resamples'] == 200 and 9 <= intervals['groups'] <= 9 + 32
    for key in ('balanced_accuracy', 'average_precision'):
      lo, hi = intervals[key]
      assert lo < metrics[key] < hi and hi - lo > 0.005, (gripper, key, intervals)
  assert result['symmetric_views'] == {g: pretrained(g).symmetric_views for g in GRIPPERS}
  # --views single scores the same rows with one view per grasp.
  assert evaluate_main(['--checkpoint', 'pretrained', '--data', str(unseen), '--no-progress', '--gripper', 'suction',
                        '--views', 'single']) == 0
  single = json.loads(capsys.readouterr().out)
  assert single['symmetric_views'] == {'suction': False}
  assert single['grippers']['suction']['examples'] == result['grippers']['suction']['examples']
  assert single['grippers']['suction']['balanced_accuracy'] > 0.7


@pytest.mark.heavy
def test_fine_tuning_the_shipped_models_beats_training_from_scratch(unseen, tmp_path):
  from dexjax.train.__main__ import main as train_main  # pylint: disable=g-import-not-at-top
  from dexjax.train.report import read_records  # pylint: disable=g-import-not-at-top
  config = tmp_path / 'tiny.yaml'
  config.write_text('loop: {epochs: 2, batch_size: 32, normalization_rows: 2000}\n'
                    'optimizer: {learning_rate: 0.002}\ncheckpoint: {every_steps: 1000}\n')
  best = {}
  for name, extra in (('scratch', []), ('fine', ['--init', 'pretrained'])):
    out = tmp_path / name
    assert train_main(['--config', str(config), '--data', str(unseen), '--out', str(out), '--no-progress',
                       *extra]) == 0
    records = read_records(out)
    best[name] = {g: max(r['val_balanced_accuracy'] or 0 for r in records if r['gripper'] == g) for g in GRIPPERS}
  fine = load(tmp_path / 'fine', 'suction')
  assert fine.config == pretrained('suction').config  # the run took the shipped architecture
  np.testing.assert_array_equal(np.asarray(fine.normalization.image_mean),
                                np.asarray(pretrained('suction').normalization.image_mean))
  for gripper in GRIPPERS:
    assert best['fine'][gripper] > best['scratch'][gripper], best


def test_init_takes_the_architecture_of_the_models_and_names_what_is_missing(tmp_path):
  from dexjax.models import GQCNNConfig  # pylint: disable=g-import-not-at-top
  from dexjax.train import TrainConfig  # pylint: disable=g-import-not-at-top
  from dexjax.train.run import apply_init  # pylint: disable=g-import-not-at-top
  other = dataclasses.replace(TrainConfig(), model=GQCNNConfig(), crop_window=128)
  assert apply_init(other) == (other, {})
  config, models = apply_init(dataclasses.replace(other, init=PRETRAINED))
  assert set(models) == set(GRIPPERS)
  assert config.model_config('suction') == pretrained('suction').config
  assert config.crop_window == pretrained('suction').crop_window
  save_model(tmp_path / 'run' / 'suction' / 'best', 1, pretrained('suction'))
  with pytest.raises(ValueError, match=r"init: .*run: no model of parallel_jaw there.*--grippers suction"):
    apply_init(dataclasses.replace(other, init=str(tmp_path / 'run')))
  config, models = apply_init(dataclasses.replace(other, init=str(tmp_path / 'run'), grippers=('suction',)))
  assert set(models) == {'suction'}
