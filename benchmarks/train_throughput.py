"""GQ-CNN training and inference throughput on this machine next to its FLOP-count bound; one JSON object.

  python benchmarks/train_throughput.py [--steps 20] [--repeats 5] [--data DIR]

For the Dex-Net 4.0 network (96 x 96 crops, 631,410 parameters) and the quick-start network (32 x 32):

* ``train_examples_per_s``: the jitted training step of `dexjax.train` (per-example symmetry augmentation,
  normalisation, forward, backward, the Dex-Net 4.0 optax update) on batches of 64 resident crops; median over
  ``--repeats`` runs of ``--steps`` steps.
* ``inference_crops_per_s``: `dexjax.models.predict` (normalise, network in chunks of ``inference_chunk``
  crops, softmax) on batches of 256 crops, median.
* ``*_flops_per_example``: the useful work, XLA's cost analysis of the plain network's compiled step / forward
  pass divided by the batch size (dexjax's own counts would include the width-blocked kernels' zeros and count
  the chunk loop's body once); ``analytic_forward_flops``: 2 x multiply-adds of the convolutions and dense layers,
  counted by hand as a check.
* ``compile_s``: compiling the training step.
* ``*_fraction_of_bound``: the median over repeats of rate x useful FLOPs per example / this machine's float32
  matmul rate measured (2048 x 2048) just before that repeat: the roofline is taken at the same moment as the
  rate, since a shared machine's speed drifts within a run. ``matmul_gflops``: the median of those matmul rates,
  and ``*_bound`` = matmul_gflops / useful FLOPs per example.
* ``plain_flax``: the in-run baseline, the same training step and prediction with the network written plainly
  in flax's standard layers (`dexjax.models.plain.PlainGQCNN`: ``nn.Conv``, ``nn.max_pool``, the whole batch at once;
  dexjax's own before width blocking, chunking and its max-pool). Its XLA FLOP counts are the useful work that
  sets both bounds (the width-blocked network's own counts include its multiply-adds by zero);
  ``speedup_over_plain`` is the ratio of the two networks' fractions of the bound (their rates, each divided by
  the matmul rate measured with it, as they run minutes apart); ``max_probability_difference`` the largest
  difference of the two networks' p(success) on the same batch (the run fails above 1e-4).

With ``--data DIR`` (a generated dataset) it also times the input pipeline alone (`dexjax.train.train_batches`:
shard reading, shuffling, grasp crops) in examples/s.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import math
import os
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from dexjax.models import (GQCNNConfig, GraspQualityModel, Normalization, init_gqcnn, num_parameters, predict,
                           success_probability)
from dexjax.models.chunked import INFERENCE_CHUNK
from dexjax.models.plain import PlainGQCNN
from dexjax.models.width_blocked import FILTER_GRADIENT_CHUNK, WIDTH_BLOCK
from dexjax.train import OptimizerConfig, TrainConfig, create_state, make_optimizer, sgd_step
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from _machine import describe  # noqa: E402

TRAIN_BATCH, INFER_BATCH = 64, 256


def _rate(fn, items: int) -> float:
  """items/s of one call of ``fn`` (which blocks until done)."""
  start = time.perf_counter()
  fn()
  return items / (time.perf_counter() - start)


_MATMUL_SIZE = 2048
_matmul = jax.jit(lambda x: x @ x)


def matmul_gflops() -> float:
  """This machine's float32 matmul GFLOP/s now: the median of three 2048 x 2048 x 2048 products."""
  a = jnp.ones((_MATMUL_SIZE, _MATMUL_SIZE), jnp.float32)
  _matmul(a).block_until_ready()
  rates = [_rate(lambda: _matmul(a).block_until_ready(), 2 * _MATMUL_SIZE**3) for _ in range(3)]
  return statistics.median(rates) / 1e9


def _paired_rates(fn, items: int, repeats: int) -> list[tuple[float, float]]:
  """``repeats`` pairs (items/s of ``fn``, matmul GFLOP/s measured just before it): the roofline of each
  measurement is taken at the same moment, since this shared machine's speed drifts within a run."""
  pairs = []
  for _ in range(repeats):
    gflops = matmul_gflops()
    pairs.append((_rate(fn, items), gflops))
  return pairs


def analytic_forward_flops(config: GQCNNConfig) -> int:
  """2 x multiply-adds of one example's forward pass (convolutions and dense layers; pools and ReLUs ignored)."""
  size, channels, macs = config.crop_size, 1, 0
  for index, (filters, kernel) in enumerate(zip(config.conv_filters, config.conv_kernels)):
    size = size - kernel + 1
    macs += size * size * kernel * kernel * channels * filters
    if index in config.pool_after:
      size = math.ceil(size / 2)
    channels = filters
  macs += size * size * channels * config.fc_size + config.pose_dim * config.pose_size
  macs += (config.fc_size + config.pose_size) * config.merge_size + config.merge_size * 2
  return 2 * macs


def _flops(compiled, batch: int) -> float | None:
  analysis = compiled.cost_analysis()
  analysis = analysis[0] if isinstance(analysis, (list, tuple)) else analysis
  flops = (analysis or {}).get('flops')
  return float(flops) / batch if flops else None


def _rates(config: GQCNNConfig, network: str, steps: int, repeats: int) -> dict:
  """Training and inference rates of the library's network (``'dexjax'``) or the plain one (``'plain'``)."""
  rng = np.random.default_rng(0)
  crops = jnp.asarray(rng.normal(0.7, 0.02, (TRAIN_BATCH, config.crop_size, config.crop_size, 1)), jnp.float32)
  batch = {'crops': crops, 'poses': jnp.asarray(rng.normal(0.7, 0.02, (TRAIN_BATCH, 1)), jnp.float32),
           'labels': jnp.asarray(rng.integers(0, 2, TRAIN_BATCH), jnp.int32),
           'weights': jnp.ones(TRAIN_BATCH, jnp.float32)}
  norm = Normalization(jnp.float32(0.7), jnp.float32(0.02), jnp.float32([0.7]), jnp.float32([0.02]))
  state = create_state(jax.random.key(0), config, make_optimizer(OptimizerConfig(), 1000))
  if network == 'plain':
    state = state.replace(apply_fn=PlainGQCNN(config).apply)
  start = time.perf_counter()
  compiled = sgd_step.lower(state, batch, norm, jax.random.key(1), augment=True, suction=False).compile()
  compile_s = time.perf_counter() - start
  step_flops = _flops(compiled, TRAIN_BATCH)
  state, _ = sgd_step(state, batch, norm, jax.random.key(1), augment=True, suction=False)
  jax.block_until_ready(state)
  holder = [state]

  def train():
    s = holder[0]
    for i in range(steps):
      s, _ = sgd_step(s, batch, norm, jax.random.key(i), augment=True, suction=False)
    jax.block_until_ready(s)
    holder[0] = s

  train = _paired_rates(train, steps * TRAIN_BATCH, repeats)
  model = GraspQualityModel(params=init_gqcnn(jax.random.key(2), config), normalization=norm, config=config,
                            gripper='parallel_jaw', crop_window=config.crop_size)
  icrops = jnp.asarray(rng.normal(0.7, 0.02, (INFER_BATCH, config.crop_size, config.crop_size, 1)), jnp.float32)
  iposes = jnp.full((INFER_BATCH, 1), 0.7, jnp.float32)
  infer_fn = predict if network == 'dexjax' else _plain_predict
  # XLA's counts are the useful work only for the plain network (the library's count its blocked kernels' zeros
  # and its chunk loop's body once), so only the plain forward pass is compiled an extra time to count them.
  forward_flops = _flops(infer_fn.lower(model, icrops, iposes).compile(), INFER_BATCH) if network == 'plain' else None
  probabilities = infer_fn(model, icrops, iposes).block_until_ready()
  infer_passes = max(1, steps // 4)

  def infer():
    for _ in range(infer_passes):
      out = infer_fn(model, icrops, iposes)
    out.block_until_ready()

  inference = _paired_rates(infer, infer_passes * INFER_BATCH, repeats)
  return {'compile_s': compile_s, 'train_examples_per_s': statistics.median(r for r, _ in train),
          'inference_crops_per_s': statistics.median(r for r, _ in inference),
          'train_flops_per_example': step_flops, 'forward_flops_per_example': forward_flops,
          '_train': train, '_inference': inference, '_probabilities': np.asarray(probabilities)}


def _fraction(pairs: list[tuple[float, float]], flops_per_item: float) -> float:
  """Median over repeats of (items/s x useful FLOPs per item) / (matmul rate measured with it)."""
  return statistics.median(rate * flops_per_item / (gflops * 1e9) for rate, gflops in pairs)


@jax.jit
def _plain_predict(model: GraspQualityModel, crops: jax.Array, poses: jax.Array) -> jax.Array:
  """`dexjax.models.predict`'s computation (normalise, network, softmax) on the plain network, whole batch."""
  crops, poses = model.normalization.apply(crops, poses, model.config.subtracts_grasp_depth)
  return success_probability(PlainGQCNN(model.config).apply({'params': model.params}, crops, poses))


def measure(config: GQCNNConfig, steps: int, repeats: int) -> dict:
  """The library's network and, in the same run, the plain Flax network (`dexjax.models.plain.PlainGQCNN`).

  The FLOP bound is set by the plain network's XLA FLOP counts (the useful work: width blocking adds
  multiply-adds by zero, which XLA counts), so both fractions are of the same work; each repeat's rate is divided
  by the matmul rate measured just before it. ``max_probability_difference``: the largest difference between the
  two networks' p(success) on the same inference batch and parameters.
  """
  plain = _rates(config, 'plain', steps, repeats)
  library = _rates(config, 'dexjax', steps, repeats)
  difference = float(np.max(np.abs(plain.pop('_probabilities') - library.pop('_probabilities'))))
  if difference > 1e-4:
    raise SystemExit(f'train_throughput: the plain network disagrees with dexjax\'s by {difference:.2e} in p(success)')
  train_flops, forward_flops = plain['train_flops_per_example'], plain['forward_flops_per_example']
  for key in ('train_flops_per_example', 'forward_flops_per_example'):
    del library[key]  # not the useful work (see `_rates`): the plain network's counts are reported instead
  fractions = {}
  for name, rates in (('dexjax', library), ('plain', plain)):
    pairs = rates.pop('_train'), rates.pop('_inference')
    fractions[name] = {'train_fraction_of_bound': _fraction(pairs[0], train_flops),
                       'inference_fraction_of_bound': _fraction(pairs[1], forward_flops)}
    fractions[name]['matmul_gflops'] = statistics.median(g for _, g in pairs[0] + pairs[1])
  gflops = fractions['dexjax']['matmul_gflops']
  out = {'parameters': num_parameters(init_gqcnn(jax.random.key(2), config)), 'crop_size': config.crop_size,
         'width_block': WIDTH_BLOCK, 'filter_gradient_chunk': FILTER_GRADIENT_CHUNK,
         'inference_chunk': INFERENCE_CHUNK, **library,
         'train_flops_per_example': train_flops, 'forward_flops_per_example': forward_flops,
         'analytic_forward_flops': analytic_forward_flops(config),
         'train_bound_examples_per_s': gflops * 1e9 / train_flops,
         'inference_bound_crops_per_s': gflops * 1e9 / forward_flops, **fractions['dexjax'],
         'plain_flax': {**plain, **fractions['plain']},
         'max_probability_difference': difference}
  # The two networks run minutes apart: their speed-up is the ratio of the rates each divided by its matmul rate.
  out['speedup_over_plain'] = {
      kind: fractions['dexjax'][f'{kind}_fraction_of_bound'] / fractions['plain'][f'{kind}_fraction_of_bound']
      for kind in ('train', 'inference')}
  return out


def pipeline_rate(data: str, batches: int) -> dict:
  """Examples/s of the input pipeline alone (quick-start crops, parallel jaw, first ``batches`` batches)."""
  from dexjax.train import dataset_stats, train_batches  # pylint: disable=g-import-not-at-top
  config = dataclasses.replace(TrainConfig(), grippers=('parallel_jaw',))
  config = dataclasses.replace(config, loop=dataclasses.replace(config.loop, normalization_rows=64))
  stats = dataset_stats(data, config)['parallel_jaw']
  start = time.perf_counter()
  n = sum(len(b['labels']) for b in itertools.islice(train_batches(data, config, 'parallel_jaw', 0, stats), batches))
  return {'pipeline_examples_per_s': n / (time.perf_counter() - start), 'pipeline_examples': n}


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
  p.add_argument('--steps', type=int, default=20)
  p.add_argument('--repeats', type=int, default=5)
  p.add_argument('--data', help='a generated dataset: also time the input pipeline')
  p.add_argument('--pipeline-batches', type=int, default=200)
  args = p.parse_args()
  result = {'machine': describe(), 'train_batch': TRAIN_BATCH, 'inference_batch': INFER_BATCH,
            'dexnet4': measure(GQCNNConfig(), args.steps, args.repeats),
            'quickstart': measure(GQCNNConfig.small(), args.steps, args.repeats)}
  if args.data:
    result['input_pipeline'] = pipeline_rate(args.data, args.pipeline_batches)
  print(json.dumps(result, indent=1))


if __name__ == '__main__':
  main()
