"""How the shipped GQ-CNNs are made: learning curves, training, scoring on unseen objects, and shipping.

  python scripts/pretrain.py curve --data DIR --eval NAME=DIR ... --out OUT [--fractions 0.125 0.25 0.5 1]
                                   [--config configs/pretrained.yaml] [--epochs E] [--name PREFIX]
                                   [--total-shards N]
  python scripts/pretrain.py score --run RUN --eval NAME=DIR ...
  python scripts/pretrain.py ship --run RUN --eval NAME=DIR ... --data DIR --data-command "..." \
                                  --train-command "..."
  python scripts/pretrain.py s1 --data DIR ... [--model pretrained] [--rows 1000]
  python scripts/pretrain.py ceiling --data DIR [--config YAML] [--shards N] [--draws 100] [--friction-draws K]
                                     [--model pretrained]

``curve`` trains one run per fraction of the dataset's shards (the first k shards: shards hold independent
heaps, so a prefix is a uniform subset) into ``OUT/rows-<fraction>``, each resumable (rerun the same command), and
scores each run's best models on its validation split and on every ``--eval`` dataset (objects never used in
training); it writes ``OUT/curve.json`` after each run and prints it. ``score`` prints the same scores for one run.
``ship`` writes the run's best models into the package (``dexjax/models/weights/<gripper>.msgpack``, read by
`dexjax.models.pretrained`) with a model card's facts in their ``info``: the data (command, objects, rows), the
network, the training (command, seconds) and the metrics. ``s1`` prints Fig. S1 (C) as numbers: the t-SNE
separation of every layer on random rows of unseen objects; ``ceiling`` how far the labels let a model go: the
dataset's rows labelled again with independent draws (a second labelling, and an oracle that knows each grasp's
robust probability from 100 draws), beside the model's scores. Nothing here is needed to *use* the shipped models.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from typing import Any
from pathlib import Path

from dexjax.data import dataset_dirs, list_shards, shard_path
from dexjax.models import load, num_parameters, save_model_file
from dexjax.models.shipped import pretrained_path
from dexjax.train import evaluate_model, load_train_config, read_records, train_run
from dexjax.train.run import CONFIG_FILE, STATS_FILE, SUMMARY_FILE

METRICS = ('balanced_accuracy', 'accuracy', 'precision', 'recall', 'average_precision', 'loss', 'examples',
           'positives')


def _evals(items: list[str]) -> dict[str, Path]:
  out = {}
  for item in items:
    name, _, path = item.partition('=')
    if not path or not list_shards(path):
      raise SystemExit(f'--eval {item}: expected NAME=DIR of a generated dataset')
    out[name] = Path(path)
  return out


def _subset(data: Path, fraction: float, root: Path, total: int | None = None) -> Path:
  """A directory of links to the first ``fraction`` of ``data``'s shards, or of its first ``total`` shards (a
  dataset still being generated: those shards must be there)."""
  finished = list_shards(data)
  k = max(1, round(fraction * (total or len(finished))))
  shards = [shard_path(data, i) for i in range(k)]
  missing = sorted(set(shards) - set(finished))
  if missing:
    raise SystemExit(f'{missing[0]}: not written yet (the first {k} shards are needed)')
  out = root / f'shards-{k}'
  out.mkdir(parents=True, exist_ok=True)
  for shard in shards:
    link = out / Path(shard).name
    if not link.exists():
      link.symlink_to(Path(shard).absolute())
  return out


def _run_models(run: Path, grippers: list[str] | None, symmetric_views: bool) -> dict:
  """The best model of each gripper of ``run`` (those of ``grippers``, default all), with ``symmetric_views``."""
  config = load_train_config(run / CONFIG_FILE)
  for gripper in grippers or []:
    if gripper not in config.grippers:
      raise SystemExit(f'--grippers {gripper}: expected one of the run\'s grippers {list(config.grippers)}')
  return {g: dataclasses.replace(load(run, g), symmetric_views=symmetric_views)
          for g in config.grippers if not grippers or g in grippers}


def score_run(run: Path, evals: dict[str, Path], models: dict | None = None) -> dict:
  """Each gripper's best model (``models``, default `_run_models` of every gripper, one view) on its run's
  validation split and on every evaluation dataset, with 95 % intervals over its objects (the validation split is
  scored again for a model that averages symmetric views; the training records are single-view)."""
  config = load_train_config(run / CONFIG_FILE)
  scores = {}
  for gripper, model in (_run_models(run, None, False) if models is None else models).items():
    records = [r for r in read_records(run) if r['gripper'] == gripper]
    best = max(records, key=lambda r: r['val_balanced_accuracy'] or 0)
    entry = {'validation': {k: best.get(f'val_{k}') for k in METRICS}}
    if model.symmetric_views:
      data = json.loads((run / SUMMARY_FILE).read_text())['data']
      metrics = evaluate_model(model, data, config, 'val')
      entry['validation'] = {k: metrics.get(k) for k in METRICS}
    for name, path in evals.items():
      metrics = evaluate_model(model, path, config, 'all', interval_by='object')
      entry[name] = {k: metrics.get(k) for k in (*METRICS, 'intervals')}
    scores[gripper] = entry
  return scores


def _curve(args) -> dict:
  data, out, evals = Path(args.data), Path(args.out), _evals(args.eval)
  config = load_train_config(args.config)
  if args.epochs:
    config = dataclasses.replace(config, loop=dataclasses.replace(config.loop, epochs=args.epochs))
  result_path = out / 'curve.json'
  results = json.loads(result_path.read_text()) if result_path.exists() else {}
  for fraction in args.fractions:
    subset = _subset(data, fraction, out / 'subsets', args.total_shards)
    run = out / f'{args.name}rows-{fraction:g}'
    key = f'{args.name}{fraction:g}'
    if key in results and results[key].get('done'):
      continue
    summary = train_run(config, subset, run, resume=(run / CONFIG_FILE).exists(), progress=False)
    stats = json.loads((run / STATS_FILE).read_text())
    results[key] = {'config': args.config, 'fraction': fraction, 'shards': len(list_shards(subset)),
                    'train_rows': {g: s['train_rows'] for g, s in stats.items()},
                    'train_seconds': summary['seconds'], 'scores': score_run(run, evals), 'done': True}
    out.mkdir(parents=True, exist_ok=True)
    result_path.write_text(json.dumps(results, indent=1) + '\n')
  return results


def _ship(args) -> dict:
  run, evals = Path(args.run), _evals(args.eval)
  config = load_train_config(run / CONFIG_FILE)
  summary = json.loads((run / SUMMARY_FILE).read_text())
  stats = json.loads((run / STATS_FILE).read_text())
  data_configs = [json.loads((Path(d) / 'config.json').read_text())['config'] for d in args.data]
  data_config = data_configs[0]  # the camera and grippers of the first dataset (a union shares them)
  objects = list(dict.fromkeys(s for c in data_configs for s in c['objects']['sources']))
  models = _run_models(run, args.grippers, args.symmetric_views)
  scores = score_run(run, evals, models)
  written = {}
  for gripper, model in models.items():
    info = {
        'data': {'command': args.data_command, 'objects': objects,
                 'shards': sum(len(list_shards(d)) for d in dataset_dirs(summary['data'])),
                 'train_rows': stats[gripper]['train_rows'], 'positive_rate': stats[gripper]['positive_rate'],
                 'camera': data_config['camera'], 'gripper': data_config['grippers'][gripper]},
        'network': {'crop_size': model.config.crop_size, 'crop_window': model.crop_window,
                    'parameters': num_parameters(model.params), 'symmetric_views': model.symmetric_views},
        'training': {'command': args.train_command, 'seconds': summary['seconds'], 'init': config.init,
                     'epochs': config.loop.epochs, 'best': summary['grippers'][gripper]},
        'metrics': scores[gripper], 'date': time.strftime('%Y-%m-%d')}
    written[gripper] = os.fspath(save_model_file(pretrained_path(gripper), model, info))
  return {'written': written, 'metrics': scores}


def _relabelled(shards: list, models, params, seed: int, heap, friction_draws: int = 0) -> dict:
  """Every row of ``shards`` labelled again (`dexjax.generate.relabel_shard`; ``heap``: the run's heap
  distribution, whose friction prior ``friction_draws`` uses), shard i with ``fold_in(key(seed), i)``: concatenated
  ``robust_probability``, ``reward``, ``failure``."""
  import jax  # pylint: disable=g-import-not-at-top
  import numpy as np  # pylint: disable=g-import-not-at-top
  from dexjax.generate.relabel import relabel_shard  # pylint: disable=g-import-not-at-top
  parts = [relabel_shard(models, params, shard, jax.random.fold_in(jax.random.key(seed), i),
                         friction_draws=friction_draws, heap=heap)
           for i, shard in enumerate(shards)]
  return {k: np.concatenate([getattr(r, k) for r in parts]) for k in ('robust_probability', 'reward', 'failure')}


def _centre_of_mass_distance(shards: list, models) -> Any:
  """(N,) horizontal distance, metres, from each row's grasp point to its target object's centre of mass (NaN
  where no object was contacted): the lever arm gravity acts through, which decides most suction grasps."""
  import numpy as np  # pylint: disable=g-import-not-at-top
  from dexjax.geometry.transforms import quat_to_matrix  # pylint: disable=g-import-not-at-top
  out = []
  for shard in shards:
    rows, images = shard.rows, shard.images
    slot, image = rows['target_slot'], rows['image_index']
    dist = np.full(len(slot), np.nan)
    for n in np.flatnonzero(slot >= 0):
      pose = images['object_poses'][image[n], slot[n]]
      model = models[images['object_ids'][image[n], slot[n]]]
      com = quat_to_matrix(pose[3:], xp=np) @ np.asarray(model.center_of_mass) + pose[:3]
      dist[n] = np.linalg.norm(com[:2] - rows['grasp_pose'][n, :2, 3])
    out.append(dist)
  return np.concatenate(out)


_DISTANCE_BINS_CM = (0, 1, 2, 3, 5, 100)


def _best_threshold(probability, decided, labels) -> dict:
  """Balanced accuracy of "decided and probability > t" against ``labels``, at t = 0.5 and at the best t of
  0.05, 0.10, ..., 0.95 (a predictor of the robust probability may pick its threshold)."""
  import numpy as np  # pylint: disable=g-import-not-at-top
  from dexjax.train.metrics import classification_metrics  # pylint: disable=g-import-not-at-top
  score = lambda t: classification_metrics(decided & (probability > t), labels)['balanced_accuracy']
  best = max((score(t), float(t)) for t in np.round(np.linspace(0.05, 0.95, 19), 2))
  return {'at_0.5': round(score(0.5), 3), 'best': round(best[0], 3), 'best_threshold': best[1]}


def _label_ceiling(args) -> dict:
  """How far a dataset's labels let a model go, measured by labelling its rows again (same heaps, images and
  grasps; `dexjax.generate.relabel_shard`): how many labels a second M-draw labelling with independent draws
  flips and how well it predicts the first (``second_labelling``); how well a predictor that knew each grasp's
  robust probability (estimated with ``--draws`` draws) scores against the labels (``oracle``), also when it
  does not know the objects' friction (``--friction-draws``: ``oracle_without_friction``); and, with
  ``--model``, the model's balanced accuracy against the labels and against the many-draw ones. Rows are also
  binned by the horizontal distance from the grasp to the target's centre of mass (``by_centre_of_mass_distance``:
  the share robust with many draws and, with ``--model``, the share the model predicts to succeed)."""
  import numpy as np  # pylint: disable=g-import-not-at-top
  from dexjax.data import GRIPPER_NAMES, read_shard  # pylint: disable=g-import-not-at-top
  from dexjax.generate import label_params  # pylint: disable=g-import-not-at-top
  from dexjax.objects.sets import usable_objects  # pylint: disable=g-import-not-at-top
  from dexjax.generate.run import load_run_config  # pylint: disable=g-import-not-at-top
  from dexjax.models.shipped import load_models  # pylint: disable=g-import-not-at-top
  from dexjax.quality.heap_reward import NONE, NOT_ROBUST  # pylint: disable=g-import-not-at-top
  from dexjax.train import TrainConfig  # pylint: disable=g-import-not-at-top
  from dexjax.train.metrics import classification_metrics  # pylint: disable=g-import-not-at-top
  from dexjax.train.validation import predict_rows  # pylint: disable=g-import-not-at-top
  data = Path(args.data)
  config = load_run_config(data, args.config)
  paths = list_shards(data)[:args.shards]
  shards = [read_shard(path) for path in paths]
  models = [p.model for p in usable_objects(config)[0]]
  params = label_params(config)
  many = params.replace(reward=params.reward.replace(num_samples=args.draws))
  second = _relabelled(shards, models, params, args.seed, config.heap)
  oracle = _relabelled(shards, models, many, args.seed + 1, config.heap)
  blind = (_relabelled(shards, models, many, args.seed + 2, config.heap, args.friction_draws)
           if args.friction_draws else None)
  col = lambda k: np.concatenate([s.rows[k] for s in shards])
  gripper, labels, failure = col('gripper'), col('reward').astype(bool), col('failure')
  # Each shard's first row among all, by the shard index its rows carry (`predict_rows`' ``shard_index``).
  first_row = dict(zip((s.meta['index'] for s in shards), np.cumsum([0] + [len(s.rows['gripper']) for s in shards])))
  trained = load_models(args.model, GRIPPER_NAMES) if args.model else {}
  distance = _centre_of_mass_distance(shards, models)
  out = {'data': os.fspath(data), 'shards': len(shards), 'num_samples': params.reward.num_samples,
         'draws': args.draws, 'friction_draws': args.friction_draws}
  for code, name in enumerate(GRIPPER_NAMES):
    sel = gripper == code
    decided = np.isin(failure[sel], (NONE, NOT_ROBUST))
    lab = labels[sel]
    result = {'rows': int(sel.sum()), 'positives': int(lab.sum()),
              'robustness_decided': round(float(decided.mean()), 3),
              'second_labelling': {'flipped': round(float((second['reward'][sel] != lab).mean()), 4),
                                   'balanced_accuracy': round(classification_metrics(second['reward'][sel], lab)[
                                       'balanced_accuracy'], 3)},
              'oracle': _best_threshold(oracle['robust_probability'][sel], decided, lab)}
    if blind is not None:
      result['oracle_without_friction'] = _best_threshold(blind['robust_probability'][sel], decided, lab)
    if name in trained:
      rows = predict_rows(trained[name], data, TrainConfig(), 'all')
      # Scores back in the shard order: this gripper's rows of the chosen shards (``--shards``), sorted by their
      # position among all rows.
      mine = np.isin(rows['shard_index'], list(first_row))
      position = np.array([first_row[i] for i in rows['shard_index'][mine]]) + rows['row_index'][mine]
      scores = rows['scores'][mine][np.argsort(position)]
      result['model'] = {
          'balanced_accuracy': round(classification_metrics(scores, lab)['balanced_accuracy'], 3),
          'against_many_draws': round(classification_metrics(scores, oracle['reward'][sel])['balanced_accuracy'], 3)}
    by_distance = {}
    for lo, hi in zip(_DISTANCE_BINS_CM[:-1], _DISTANCE_BINS_CM[1:]):
      b = (distance[sel] >= lo / 100) & (distance[sel] < hi / 100)
      if b.any():
        cell = {'rows': int(b.sum()), 'robust_with_many_draws': round(float(oracle['reward'][sel][b].mean()), 3)}
        if 'model' in result:
          cell['model_predicts_success'] = round(float((scores[b] > 0.5).mean()), 3)
        by_distance[f'{lo}-{hi} cm'] = cell
    result['by_centre_of_mass_distance'] = by_distance
    out[name] = result
  return out


def _figure_s1(args) -> dict:
  """Fig. S1 (C) as numbers: each layer's t-SNE separation of the shipped (or given) models on ``--rows``
  random rows of each gripper from the ``--data`` sets (objects never used in training)."""
  import numpy as np  # pylint: disable=g-import-not-at-top
  from dexjax.models import load_models  # pylint: disable=g-import-not-at-top
  from dexjax.models.feature_analysis import analyse_layers  # pylint: disable=g-import-not-at-top
  from dexjax.train import sample_examples  # pylint: disable=g-import-not-at-top
  out = {}
  for gripper, model in load_models(args.model).items():
    parts = [sample_examples(model, d, args.rows // len(args.data), split='all', seed=args.seed) for d in args.data]
    ex = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    layers = analyse_layers(model, ex['crops'], ex['poses'], ex['labels'], seed=args.seed)
    out[gripper] = {'rows': int(len(ex['labels'])), 'positives': int(ex['labels'].sum()),
                    'separation': {name: round(float(r['separation']), 3) for name, r in layers.items()}}
  return out


def main(argv: list[str] | None = None) -> int:
  p = argparse.ArgumentParser(prog='python scripts/pretrain.py', description=__doc__.split('\n\n')[0])
  sub = p.add_subparsers(dest='command', required=True)
  c = sub.add_parser('curve')
  c.add_argument('--data', required=True)
  c.add_argument('--eval', nargs='+', default=[])
  c.add_argument('--out', required=True)
  c.add_argument('--fractions', nargs='+', type=float, default=[0.125, 0.25, 0.5, 1.0])
  c.add_argument('--config', default='configs/pretrained.yaml')
  c.add_argument('--epochs', type=int)
  c.add_argument('--total-shards', type=int, help='fractions of the first N shards (default: of all there are)')
  c.add_argument('--name', default='', help='prefix of the run directories and result keys (e.g. the network)')
  s = sub.add_parser('score')
  s.add_argument('--run', required=True)
  s.add_argument('--eval', nargs='+', default=[])
  s.add_argument('--grippers', nargs='+', help="only these grippers' models (default: every one of the run)")
  s.add_argument('--symmetric-views', action='store_true', help='average over the four symmetric views')
  h = sub.add_parser('ship')
  h.add_argument('--run', required=True)
  h.add_argument('--eval', nargs='+', default=[])
  h.add_argument('--data', nargs='+', required=True, help='the dataset(s) the run trained on (their configs)')
  h.add_argument('--data-command', required=True)
  h.add_argument('--train-command', required=True)
  h.add_argument('--grippers', nargs='+', help="only these grippers' models (default: every one of the run)")
  h.add_argument('--symmetric-views', action='store_true', help='ship models that average the four symmetric views')
  f = sub.add_parser('s1', help="Fig. S1 (C): per-layer t-SNE separation on unseen objects")
  f.add_argument('--data', nargs='+', required=True)
  f.add_argument('--model', default='pretrained')
  f.add_argument('--rows', type=int, default=1000)
  f.add_argument('--seed', type=int, default=0)
  n = sub.add_parser('ceiling', help="how far the labels let a model go: the rows labelled again")
  n.add_argument('--data', required=True)
  n.add_argument('--config', help='the generation config the data was made with (default: the defaults)')
  n.add_argument('--shards', type=int, help='the first N shards (default: all)')
  n.add_argument('--draws', type=int, default=100, help="the oracle's Monte-Carlo draws per grasp (default 100)")
  n.add_argument('--friction-draws', type=int, default=0,
                 help='also an oracle that does not know the friction: k prior frictions per grasp (default 0: no)')
  n.add_argument('--model', help="also score this model ('pretrained', a run, a model file)")
  n.add_argument('--seed', type=int, default=0)
  args = p.parse_args(argv)
  if args.command == 'ceiling':
    result = _label_ceiling(args)
  elif args.command == 's1':
    result = _figure_s1(args)
  elif args.command == 'curve':
    result = _curve(args)
  elif args.command == 'score':
    run = Path(args.run)
    result = score_run(run, _evals(args.eval), _run_models(run, args.grippers, args.symmetric_views))
  else:
    result = _ship(args)
  print(json.dumps(result, indent=1))
  return 0


if __name__ == '__main__':
  sys.exit(main())
