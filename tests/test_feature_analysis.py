"""The Fig. S1 analysis functions (`dexjax.models.feature_analysis`): activations against a NumPy forward pass,
filters, top-activating crops against a brute-force search, t-SNE and the separation score on known layouts."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from dexjax.models import pretrained
from dexjax.models.feature_analysis import (analyse_layers, first_layer_filters, layer_activations, layer_names,
                                            separation, top_activating, tsne_embedding)
from dexjax.models.feature_plots import plot_embeddings, plot_filters, plot_top_activating


def _conv(x, kernel, bias):
  """VALID cross-correlation of (B, H, W, Cin) with (k, k, Cin, Cout), then ReLU."""
  k = kernel.shape[0]
  windows = sliding_window_view(x, (k, k), axis=(1, 2))  # (B, H', W', Cin, k, k)
  return np.maximum(np.einsum('bhwcij,ijco->bhwo', windows, kernel) + bias, 0.0)


def _pool(x):
  """2 x 2 max pool, stride 2, SAME padding (an odd edge is pooled alone)."""
  b, h, w, c = x.shape
  padded = np.full((b, h + h % 2, w + w % 2, c), -np.inf)
  padded[:, :h, :w] = x
  return padded.reshape(b, padded.shape[1] // 2, 2, padded.shape[2] // 2, 2, c).max(axis=(2, 4))


def _reference(model, crops, poses):
  """Every layer of the GQ-CNN computed with NumPy from the parameters (float64)."""
  p = jax.tree.map(lambda v: np.asarray(v, np.float64), model.params)
  norm = model.normalization
  if model.config.input_depth_mode == 'im_depth_sub':  # the crop relative to the grasp depth pose[0]
    crops = crops - poses[:, None, None, :1]
  x = (crops - float(norm.image_mean)) / float(norm.image_std)
  q = (poses - np.asarray(norm.pose_mean)) / np.asarray(norm.pose_std)
  out = {}
  for i in range(len(model.config.conv_filters)):
    conv = p['image_stream'][f'conv{i}']
    x = _conv(x, conv['kernel'], conv['bias'])
    out[f'conv{i}'] = x
    if i in model.config.pool_after:
      x = _pool(x)
  dense = lambda name, v: v @ p[name]['kernel'] + p[name].get('bias', 0.0)
  out['fc3'] = np.maximum(dense('fc3', x.reshape(len(x), -1)), 0.0)
  out['pc1'] = np.maximum(dense('pc1', q), 0.0)
  out['fc4'] = np.maximum(dense('fc4_image', out['fc3']) + dense('fc4_pose', out['pc1']), 0.0)
  out['output'] = dense('fc5', out['fc4'])
  return out


@pytest.fixture(scope='module')
def batch():
  """A shipped model, as one view (the network the analysis opens up), and 48 depth-like crops: a plane with a random
  box on it, at a random depth."""
  model = pretrained('parallel_jaw').replace(symmetric_views=False)
  rng = np.random.default_rng(0)
  s = model.config.crop_size
  crops = np.empty((48, s, s, 1))
  for i in range(48):
    crops[i] = rng.uniform(0.7, 0.8) + rng.normal(0, 0.001, (s, s, 1))
    r, c, h, w = rng.integers(0, s // 2, 4)
    crops[i, r:r + h + 4, c:c + w + 4] -= rng.uniform(0.01, 0.05)
  poses = crops[:, s // 2, s // 2, :] + rng.uniform(0.0, 0.02, (48, 1))
  return model, crops.astype(np.float32), poses.astype(np.float32)


@pytest.mark.parametrize('mode', ['im_depth_sub', 'pose_stream'])
def test_activations_match_a_numpy_forward_pass(batch, mode):
  model, crops, poses = batch
  model = model.replace(config=dataclasses.replace(model.config, input_depth_mode=mode))
  acts = layer_activations(model, crops, poses)
  ref = _reference(model, crops.astype(np.float64), poses.astype(np.float64))
  assert set(acts) == set(layer_names(model))
  for name in layer_names(model):
    np.testing.assert_allclose(acts[name], ref[name], rtol=2e-3, atol=2e-4, err_msg=name)
  probs = np.asarray(model(crops, poses))
  np.testing.assert_allclose(probs, 1 / (1 + np.exp(ref['output'][:, 0] - ref['output'][:, 1])), atol=1e-4)
  # The activations are the network's on the crops as given, whatever the model averages its predictions over.
  views = model.replace(symmetric_views=True)
  np.testing.assert_array_equal(layer_activations(views, crops, poses)['output'], acts['output'])


def test_filters_and_top_activating_crops_match_brute_force(batch):
  model, crops, poses = batch
  filters = first_layer_filters(model)
  kernel = np.asarray(model.params['image_stream']['conv0']['kernel'])
  assert filters.shape == (kernel.shape[3], kernel.shape[0], kernel.shape[1])
  np.testing.assert_array_equal(filters[3], kernel[:, :, 0, 3])
  indices, values = top_activating(model, crops, poses, k=5)
  last = _reference(model, crops.astype(np.float64), poses.astype(np.float64))[f'conv{len(model.config.conv_filters) - 1}']
  peak = last.max(axis=(1, 2))  # (B, C)
  for c in range(peak.shape[1]):
    np.testing.assert_allclose(values[c], np.sort(peak[:, c])[::-1][:5], rtol=2e-3, atol=2e-4)
    np.testing.assert_allclose(peak[indices[c], c], values[c], rtol=2e-3, atol=2e-4)
  with pytest.raises(ValueError, match='layer: expected one of'):
    top_activating(model, crops, poses, layer='fc3')
  with pytest.raises(ValueError, match='k: expected'):
    top_activating(model, crops, poses, k=49)


def test_tsne_and_separation_tell_separated_from_mixed_labels():
  rng = np.random.default_rng(1)
  labels = np.repeat([0, 1], [90, 30])
  apart = rng.normal(0, 1, (120, 40)) + 6.0 * labels[:, None]  # two clusters, unbalanced like grasp labels
  emb = tsne_embedding(apart, perplexity=25, seed=0)
  assert emb.shape == (120, 2) and np.isfinite(emb).all()
  assert separation(emb, labels) > 0.95
  mixed = tsne_embedding(rng.normal(0, 1, (120, 40)), perplexity=25, seed=0)
  assert abs(separation(mixed, labels) - 0.5) < 0.15
  with pytest.raises(ValueError, match='perplexity'):
    tsne_embedding(apart[:20], perplexity=25)
  with pytest.raises(ValueError, match='both classes'):
    separation(emb, np.zeros(120))


def test_analyse_layers_and_plots(batch, tmp_path):
  model, crops, poses = batch
  labels = np.asarray(model(crops, poses)) > np.median(np.asarray(model(crops, poses)))
  layers = analyse_layers(model, crops, poses, labels, perplexity=10)
  assert list(layers) == list(layer_names(model))
  # The network's own output separates the labels defined by its output.
  assert layers['output']['separation'] > 0.8
  for fig, name in ((plot_filters(first_layer_filters(model)), 'a.png'),
                    (plot_top_activating(crops, top_activating(model, crops, poses, k=3)[0], labels), 'b.png'),
                    (plot_embeddings(layers, labels), 'c.png')):
    fig.savefig(tmp_path / name)
    assert (tmp_path / name).stat().st_size > 1000
