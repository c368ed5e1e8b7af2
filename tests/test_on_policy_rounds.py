"""On-policy dataset synthesis end to end, with tiny settings: one round collected by the shipped policy and
trained from it (`dexjax.train.on_policy_rounds`), its rows the grasps that policy scored, the round resumable."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import yaml

from dexjax.config import ConfigError
from dexjax.data import list_shards
from dexjax.data.shards import read_shard
from dexjax.generate import pipeline
from dexjax.generate.config import config_from_dict, fingerprint, with_collection
from dexjax.generate.on_policy import collection_models, collection_policy, model_digest
from dexjax.generate.policy import POLICY, SUPERVISOR
from dexjax.policy.observation import Observation
from dexjax.render.camera import Camera, Intrinsics
from dexjax.train.config import CheckpointConfig, LoopConfig, TrainConfig
from dexjax.train.on_policy_rounds import ROUNDS_FILE, round_configs, round_dirs, round_training_data, run_rounds
from test_generate import SMALL

SMALL_ON_POLICY = {**SMALL, 'policy': {'actions_per_gripper': 12, 'epsilon': 0.25, 'top_k': 4}}
GENERATE = config_from_dict(SMALL_ON_POLICY, 'small.yaml')
TRAIN = TrainConfig(loop=LoopConfig(epochs=1, batch_size=8, eval_batch_size=64, normalization_rows=200),
                    checkpoint=CheckpointConfig(every_steps=4, keep=1),
                    split=dataclasses.replace(TrainConfig().split, val_fraction=0.25))


@pytest.fixture(scope='module')
def one_round(tmp_path_factory):
  """(rounds directory, records, log lines): one round collected on-policy with the shipped models."""
  out, cache = tmp_path_factory.mktemp('rounds'), str(tmp_path_factory.mktemp('rounds_cache'))
  lines = []
  records = run_rounds(GENERATE, TRAIN, out, 1, 4, init='pretrained', cache_dir=cache, progress=False,
                       log=lines.append)
  return out, records, lines, cache


def test_a_round_collects_with_the_policy_and_fine_tunes_it(one_round):
  out, records, lines, _ = one_round
  data_dir, train_dir = round_dirs(out, 0)
  assert [(r['round'], r['step']) for r in records] == [(0, 'collect'), (0, 'train')]
  assert records[0]['collection']['policy'] == 'on_policy' and records[1]['init'] == 'pretrained'
  assert (train_dir / 'summary.json').is_file() and (train_dir / 'parallel_jaw' / 'best').is_dir()
  assert records[1]['data'] == [str(data_dir)]
  # The round's data is tied to the weights it was collected with: the run's config holds their digest.
  saved = json.loads((data_dir / 'config.json').read_text())['config']['collection']
  assert saved['model_digest'] == model_digest(collection_models('pretrained')[0])
  codes = np.concatenate([read_shard(p).rows['policy'] for p in list_shards(data_dir)])
  assert set(np.unique(codes)) <= {POLICY, SUPERVISOR} and (codes == POLICY).mean() > 0.5
  # The next round would collect with this round's models and fine-tune them.
  gen, tr = round_configs(GENERATE, TRAIN, out, 1)
  assert gen.collection.model == str(train_dir) and tr.init == str(train_dir) and gen.seed == GENERATE.seed + 1
  assert fingerprint(gen) != fingerprint(GENERATE)


def test_a_round_is_relabelled_with_its_collection_recorded(one_round, tmp_path):
  """Relabelling an on-policy run keeps its record: the collection (and so the fingerprint) of the run it came
  from, without loading the model again."""
  from dexjax.generate.run import load_run_config  # pylint: disable=g-import-not-at-top
  out, _, _, _ = one_round
  data_dir = round_dirs(out, 0)[0]
  path = tmp_path / 'small.yaml'
  path.write_text(yaml.safe_dump(SMALL_ON_POLICY))
  config = load_run_config(data_dir, path)
  recorded = json.loads((data_dir / 'config.json').read_text())
  assert config.collection.policy == 'on_policy' and fingerprint(config) == recorded['fingerprint']


def test_a_finished_round_is_skipped_when_rerun(one_round):
  out, records, _, cache = one_round
  before = (out / ROUNDS_FILE).read_text()
  lines = []
  again = run_rounds(GENERATE, TRAIN, out, 1, 4, init='pretrained', cache_dir=cache, progress=False,
                     log=lines.append)
  assert again == records and (out / ROUNDS_FILE).read_text() == before
  assert lines == [f'round 0: done ({round_dirs(out, 0)[1]})']


def test_policy_rows_are_the_grasps_the_policy_scored(one_round):
  """Every row coded POLICY is one of the grasps the collecting CEM scored on its image (replanned with the
  image's own key), and the top_k first rows of each gripper are its highest-scored ones."""
  out, _, _, _ = one_round
  data_dir = round_dirs(out, 0)[0]
  gen = round_configs(GENERATE, TRAIN, out, 0, 'pretrained')[0]
  policy = collection_policy(collection_models('pretrained')[0])
  shard = read_shard(list_shards(data_dir)[0])
  images, rows = shard.images, shard.rows
  checked = 0
  for j in range(len(images['depth'])):
    fx, fy, cx, cy = images['camera_intrinsics'][j]
    h, w = images['depth'][j].shape
    camera = Camera(Intrinsics(fx=fx, fy=fy, cx=cx, cy=cy, width=w, height=h),
                    jnp.asarray(images['camera_rotation'][j]), jnp.asarray(images['camera_translation'][j]))
    obs = Observation(depth=jnp.asarray(images['depth'][j]), mask=jnp.asarray(images['mask'][j] >= 0), camera=camera)
    planned = pipeline._plan(pipeline._policy_key(gen.seed, 0, j), obs, policy)  # pylint: disable=protected-access
    for g, name in enumerate(('parallel_jaw', 'suction')):
      grasps, valid, score = jax.tree.map(np.asarray, planned[name])
      mine = (rows['image_index'] == j) & (rows['gripper'] == g)
      for k in np.flatnonzero(mine & (rows['policy'] == POLICY)):
        hit = valid & (np.abs(grasps.center - rows['center'][k]).max(-1) < 1e-3) & (
            np.abs(grasps.depth - rows['grasp_depth'][k]) < 1e-5)
        assert hit.any(), (j, name, rows['center'][k])
        checked += 1
      first = np.flatnonzero(mine)[:GENERATE.policy.top_k]
      best = np.sort(score[valid])[::-1][:GENERATE.policy.top_k]
      led = [score[valid & (np.abs(grasps.center - rows['center'][k]).max(-1) < 1e-3)].max() for k in first
             if rows['policy'][k] == POLICY]
      assert np.all(np.isin(np.round(led, 5), np.round(best, 5))), (j, name)
  assert checked >= 20


def test_collection_config_names_field_and_expected_value(tmp_path):
  with pytest.raises(ConfigError, match=r"small.yaml: collection.model: expected the learned policy's GQ-CNNs"):
    config_from_dict({**SMALL, 'collection': {'policy': 'on_policy'}}, 'small.yaml')
  with pytest.raises(ConfigError, match=r"collection.policy: expected one of \('tau', 'on_policy'\), got 'greedy'"):
    config_from_dict({**SMALL, 'collection': {'policy': 'greedy'}}, 'small.yaml')
  with pytest.raises(ConfigError, match=r'collection.model_digest: set from the model'):
    config_from_dict({**SMALL, 'collection': {'model_digest': 'abc'}}, 'small.yaml')
  with pytest.raises(FileNotFoundError):
    with_collection(GENERATE, 'on_policy', tmp_path / 'no_such_run')
  # The seed's collection policy leaves the fingerprint as it was before the section existed.
  assert fingerprint(with_collection(GENERATE, 'tau')) == fingerprint(GENERATE)


def test_on_policy_yaml_is_the_deployment_recipe_with_the_policys_choices_first():
  """configs/on_policy.yaml: configs/deployment.yaml's bins and sensor on other heaps, the policy's top 10 first."""
  from dexjax.generate.config import load_generate_config  # pylint: disable=g-import-not-at-top
  config, deployment = load_generate_config('configs/on_policy.yaml'), load_generate_config('configs/deployment.yaml')
  assert config.policy.top_k == 10 and config.seed != deployment.seed and config.collection.policy == 'tau'
  assert dataclasses.replace(config, seed=deployment.seed, policy=deployment.policy) == deployment


def test_rounds_train_on_their_own_collection_or_on_all_so_far_with_the_base_data(tmp_path):
  base = tmp_path / 'deployment'
  assert round_training_data(tmp_path, 2) == [round_dirs(tmp_path, 2)[0]]
  assert round_training_data(tmp_path, 2, [base], aggregate=True) == [base] + [round_dirs(tmp_path, r)[0]
                                                                              for r in range(3)]
  # A base dataset without shards is refused before the first (long) collection writes anything.
  with pytest.raises(FileNotFoundError, match=r'deployment: no dataset shards .* \(--base-data\)'):
    run_rounds(GENERATE, TRAIN, tmp_path / 'rounds', 1, 4, base_data=[base], progress=False)
  assert not (tmp_path / 'rounds').exists()
