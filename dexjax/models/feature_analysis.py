"""What a trained GQ-CNN learned: the seed's Fig. S1 analysis as functions.

(A) `first_layer_filters`: the first convolution's filters. (B) `top_activating`: for each channel of the last
convolutional layer, the crops that excite it most. (C) `layer_activations` + `tsne_embedding`: every layer's
activations for a set of crops, embedded in 2-D by Barnes-Hut t-SNE (perplexity 25, as the seed), and
`separation` to say in one number how well positives and negatives separate in each embedding (the seed finds
that they separate only at fc4, the layer where the image and pose streams merge).

The computations work on one batch of raw crops (B, S, S, 1) metres and raw poses (B, pose_dim) (the model's
normalisation is applied here), each crop as given: the network's activations, one view per grasp, also for a
model that averages its predictions over symmetric views (``symmetric_views``); plots are in
`dexjax.models.feature_plots`. t-SNE and the separation score use
scikit-learn (``pip install 'dexjax[analysis]'``; Colab has it).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from dexjax.models.gqcnn import GQCNN
from dexjax.models.saved import GraspQualityModel

TSNE_PERPLEXITY = 25.0
"""The seed's t-SNE perplexity (Fig. S1C)."""


def layer_names(model: GraspQualityModel) -> tuple[str, ...]:
  """The layers `layer_activations` reports, input to output: ``conv0`` ... ``conv{n-1}``, ``fc3`` (image
  stream), ``pc1`` (pose stream), ``fc4`` (the merge) and ``output`` (the two logits)."""
  return (*(f'conv{i}' for i in range(len(model.config.conv_filters))), 'fc3', 'pc1', 'fc4', 'output')


@jax.jit
def _intermediates(model: GraspQualityModel, crops: jax.Array, poses: jax.Array) -> dict[str, jax.Array]:
  crops, poses = model.normalization.apply(jnp.asarray(crops, jnp.float32), jnp.asarray(poses, jnp.float32),
                                           model.config.subtracts_grasp_depth)
  logits, state = GQCNN(model.config).apply({'params': model.params}, crops, poses, train=False,
                                            capture_intermediates=True)
  inter = state['intermediates']
  out = {name: value['activation'][0] for name, value in inter['image_stream'].items() if name.startswith('conv')}
  out['fc3'] = jax.nn.relu(inter['fc3']['__call__'][0])
  out['pc1'] = jax.nn.relu(inter['pc1']['__call__'][0])
  out['fc4'] = jax.nn.relu(inter['fc4_image']['__call__'][0] + inter['fc4_pose']['__call__'][0])
  out['output'] = logits
  return out


def layer_activations(model: GraspQualityModel, crops: jax.Array, poses: jax.Array) -> dict[str, np.ndarray]:
  """Every layer's activations after its ReLU (the convolutions before their pooling; ``output``: logits).

  Args:
    model: a trained GQ-CNN.
    crops: (B, S, S, 1) raw grasp crops, metres (S = ``model.config.crop_size``).
    poses: (B, pose_dim) raw poses.

  Returns:
    name (`layer_names`) -> (B, ...) float32: convolutions (B, H, W, C), dense layers (B, D).
  """
  return {k: np.asarray(v) for k, v in _intermediates(model, crops, poses).items()}


def first_layer_filters(model: GraspQualityModel) -> np.ndarray:
  """(A) The first convolution's filters, (C, k, k) (channel, row, column), as learned (on normalised depth)."""
  kernel = np.asarray(model.params['image_stream']['conv0']['kernel'])  # (k, k, 1, C)
  return np.moveaxis(kernel[:, :, 0, :], -1, 0)


def top_activating(model: GraspQualityModel, crops: jax.Array, poses: jax.Array, k: int = 9,
                   layer: str | None = None) -> tuple[np.ndarray, np.ndarray]:
  """(B) For each channel of a convolutional layer (default: the last), the ``k`` crops whose strongest response
  in that channel is largest.

  Returns:
    (indices (C, k) into the batch, strongest responses (C, k)), each row in decreasing order.

  Raises:
    ValueError: ``layer`` is not a convolution, or ``k`` exceeds the batch.
  """
  convs = [n for n in layer_names(model) if n.startswith('conv')]
  layer = layer or convs[-1]
  if layer not in convs:
    raise ValueError(f'layer: expected one of {convs}, got {layer!r}')
  if not 1 <= k <= len(crops):
    raise ValueError(f'k: expected 1 <= k <= {len(crops)} (the batch), got {k}')
  peak = layer_activations(model, crops, poses)[layer].max(axis=(1, 2))  # (B, C)
  order = np.argsort(-peak, axis=0, kind='stable')[:k].T  # (C, k)
  return order, np.take_along_axis(peak.T, order, axis=1)


def _sklearn():
  try:
    import sklearn  # pylint: disable=g-import-not-at-top,unused-import
  except ImportError:
    raise ImportError("t-SNE needs scikit-learn: pip install 'dexjax[analysis]'") from None


def tsne_embedding(features: np.ndarray, perplexity: float = TSNE_PERPLEXITY, seed: int = 0,
                   pca_dims: int | None = 50) -> np.ndarray:
  """(C) Barnes-Hut t-SNE of activations (B, ...) into (B, 2).

  Args:
    features: (B, ...) one layer's activations (flattened per row).
    perplexity: t-SNE perplexity (the seed: 25); must be below B.
    seed: random state of PCA and t-SNE.
    pca_dims: reduce to this many principal components first (standard for wide layers such as a convolution's
      whole feature map; None: no reduction).
  """
  _sklearn()
  from sklearn.decomposition import PCA  # pylint: disable=g-import-not-at-top
  from sklearn.manifold import TSNE  # pylint: disable=g-import-not-at-top
  x = np.asarray(features, np.float64).reshape(len(features), -1)
  if perplexity >= len(x):
    raise ValueError(f'perplexity: expected < the number of rows ({len(x)}), got {perplexity}')
  if pca_dims is not None and x.shape[1] > pca_dims and len(x) > pca_dims:
    x = PCA(pca_dims, random_state=seed).fit_transform(x)
  tsne = TSNE(2, perplexity=perplexity, method='barnes_hut', init='pca', random_state=seed)
  return tsne.fit_transform(x).astype(np.float32)


def separation(embedding: np.ndarray, labels: np.ndarray, neighbours: int = 10) -> float:
  """How well the labels separate in an embedding: balanced accuracy of a ``neighbours``-nearest-neighbour vote
  (each point judged by its neighbours, not itself). 0.5: mixed, 1: separated."""
  _sklearn()
  from sklearn.metrics import balanced_accuracy_score  # pylint: disable=g-import-not-at-top
  from sklearn.neighbors import NearestNeighbors  # pylint: disable=g-import-not-at-top
  labels = np.asarray(labels).astype(int)
  if len(np.unique(labels)) < 2:
    raise ValueError('labels: expected both classes (0 and 1), got one')
  _, idx = NearestNeighbors(n_neighbors=neighbours + 1).fit(embedding).kneighbors(embedding)
  vote = labels[idx[:, 1:]].mean(axis=1)
  prior = labels.mean()  # a vote above the base rate counts as positive (classes are unbalanced)
  return float(balanced_accuracy_score(labels, (vote > prior).astype(int)))


def analyse_layers(model: GraspQualityModel, crops: jax.Array, poses: jax.Array, labels: np.ndarray,
                   perplexity: float = TSNE_PERPLEXITY, seed: int = 0) -> dict[str, dict[str, Any]]:
  """(C) for every layer: ``{'embedding': (B, 2), 'separation': float}`` (`tsne_embedding`, `separation`)."""
  acts = layer_activations(model, crops, poses)
  out = {}
  for name in layer_names(model):
    emb = tsne_embedding(acts[name], perplexity, seed)
    out[name] = {'embedding': emb, 'separation': separation(emb, labels)}
  return out


__all__ = ['TSNE_PERPLEXITY', 'analyse_layers', 'first_layer_filters', 'layer_activations', 'layer_names',
           'separation', 'tsne_embedding', 'top_activating']
