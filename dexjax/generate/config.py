"""The configuration of a dataset-generation run: every parameter of the pipeline, read from YAML.

`GenerateConfig` gathers the parameter dataclasses of each stage (heap distribution, settling, camera
distribution, rendering and sensor noise, image samplers, grippers and their perturbation models, reward,
supervisor, collection policy) plus the object sources and the dataset layout. Defaults are Dex-Net 4.0's;
``configs/dexnet4.yaml`` spells them out. `load_generate_config` applies a YAML file on top of the defaults,
then optionally a gripper file (``configs/quality.yaml`` layout) and a camera file, and checks every field
(`dexjax.config.ConfigError` names the file and the dotted field).

The content of shard i is a function of (`fingerprint` of this config, seed, i) only: the fingerprint covers
every field that changes what is generated, and nothing else (not the image count, output directory or
worker count).
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any, Mapping

from dexjax.config import (MAX_GRID_SIZE, ConfigError, as_dict, check_fields, check_sections, count_rule, load_yaml,
                           override, plain_json, string_list, validate_generate_config)
from dexjax.data.shards import FORMAT_VERSION, config_fingerprint
from dexjax.generate.labels import LABEL_VERSION
from dexjax.generate.policy import PolicyParams
from dexjax.generate.supervisor import SupervisorParams
from dexjax.models.shipped import PRETRAINED
from dexjax.objects.procedural import PROCEDURAL_VERSION
from dexjax.policy.presets import CEM_PRESETS
from dexjax.quality.heap_reward import RewardParams
from dexjax.quality.report import ReportSettings, settings_from_config
from dexjax.render.distribution import CameraDistribution
from dexjax.render.noise import SensorNoise
from dexjax.render.rendering import BACKENDS as RENDER_BACKENDS
from dexjax.render.rendering import RenderSettings
from dexjax.sampling.image_samplers import AntipodalImageSampler, SuctionImageSampler
from dexjax.sim.heap import Bin, HeapDistribution
from dexjax.sim.scene import SettleSettings


@dataclasses.dataclass(frozen=True)
class ObjectsConfig:
  """Which objects heaps are drawn from, and how they are modelled.

  Attributes:
    sources: object sources (`dexjax.objects.load_object_set`: ``builtin:NAME``, ``builtin:level2``,
      ``procedural:L2/0:100``, mesh files, folders).
    scale: factor applied to meshes read from files (e.g. 0.001 for millimetre meshes).
    grid_size: signed-distance grid resolution of each object's model (reward and supervisor), 8 to 512
      (`dexjax.config_rules.MAX_GRID_SIZE`); 64 keeps 99.6-100 % of 128's rewards at 1.5-2.4x less labelling time
      than 100 (``docs/generate.md``, grid resolution).
  """

  sources: tuple[str, ...] = ('builtin:level2',)
  scale: float = 1.0
  grid_size: int = 64


@dataclasses.dataclass(frozen=True)
class DatasetConfig:
  """Layout of the dataset.

  Attributes:
    images_per_shard: rendered images per shard (a shard is the unit of work, resume and parallelism).
    images_per_heap: cameras sampled per settled heap (each image is stored with its own rows).
    render_backend: ``'auto'``, ``'gl'`` or ``'raycast'`` (`dexjax.render.DepthRenderer`).
    inpaint_holes: the depth image stored and sampled is the one a policy plans on: pixels without a return
      (``noise.use_dropout``) are inpainted (`dexjax.policy.inpaint_depth`, as `dexjax.policy.prepare_observation`
      and the benchmark do), and candidates come only from pixels with a return (suction points, jaw contact
      edges), as from a policy's observation mask. Images without holes are unchanged. False: holes stay NaN in
      the stored image (the samplers avoid them; the training crops read them as 0).
  """

  images_per_shard: int = 16
  images_per_heap: int = 1
  render_backend: str = 'auto'
  inpaint_holes: bool = True


COLLECTION_POLICIES = ('tau', 'on_policy')


@dataclasses.dataclass(frozen=True)
class CollectionConfig:
  """Which policy proposes the candidate actions that tau labels (``policy``, below).

  Attributes:
    policy: ``'tau'``: the seed's candidates, uniform on the image sampler's set; ``'on_policy'``: the grasps a
      learned policy scores on the image (`dexjax.generate.on_policy`: every CEM round of each gripper the
      models cover, ``policy.top_k`` of the highest-scored first), mixed with the supervisor's as tau mixes them.
    model: ``on_policy``: the learned policy's GQ-CNNs (a training run, saved model or model file; `dexjax.models.
      load_models`), an absolute path once loaded; ``'pretrained'``: the shipped models.
    model_digest: the models' content digest (`dexjax.generate.on_policy.model_digest`), set when the config is
      loaded: the fingerprint covers it, not the path.
    cem: the collecting policy's CEM preset, ``'seed'`` or ``'gqcnn'`` (`dexjax.policy.cem_params`).
  """

  policy: str = 'tau'
  model: str = ''
  model_digest: str = ''
  cem: str = 'seed'


@dataclasses.dataclass(frozen=True)
class GenerateConfig:
  """Every parameter of a generation run (defaults: Dex-Net 4.0; see the module docstring).

  ``settle.bin`` is the bin of every stage (settling, rendering, reward); the parallel-jaw image sampler's
  ``gripper_width`` is the gripper's ``max_width`` (set by `load_generate_config`). ``camera_intrinsics``
  (fx, fy, cx, cy, width, height), when set, replaces the sampled intrinsics, and ``camera_pose`` (9 entries of
  the camera-to-world rotation, row-major, then the position in metres) the sampled pose (see
  `dexjax.generate.cameras`).
  """

  seed: int = 0
  objects: ObjectsConfig = ObjectsConfig()
  dataset: DatasetConfig = DatasetConfig()
  heap: HeapDistribution = HeapDistribution()
  settle: SettleSettings = SettleSettings()
  camera: CameraDistribution = CameraDistribution()
  camera_intrinsics: tuple[float, ...] = ()
  camera_pose: tuple[float, ...] = ()
  render: RenderSettings = RenderSettings()
  noise: SensorNoise = SensorNoise()
  parallel_jaw_sampler: AntipodalImageSampler = AntipodalImageSampler()
  suction_sampler: SuctionImageSampler = SuctionImageSampler()
  grippers: ReportSettings = ReportSettings()
  reward: RewardParams = RewardParams()
  supervisor: SupervisorParams = SupervisorParams()
  policy: PolicyParams = PolicyParams()
  collection: CollectionConfig = CollectionConfig()

  @property
  def bin(self) -> Bin:
    return self.settle.bin


_GRIPPER_SECTIONS = ('grippers', 'perturbations', 'quality')  # configs/quality.yaml's layout
_TOP = ('seed', 'objects', 'dataset', 'heap', 'bin', 'settle', 'camera', 'render', 'noise', 'samplers', 'reward',
        'supervisor', 'policy', 'collection') + _GRIPPER_SECTIONS
_SAMPLERS = ('parallel_jaw', 'suction')
_REWARD_FIELDS = ('suction_contact_distance', 'threshold', 'num_samples')


def _section(data: Mapping[str, Any], name: str, source: str) -> dict[str, Any] | None:
  value = data.get(name)
  if value is not None and not isinstance(value, Mapping):
    raise ConfigError(source, name, f'expected a mapping of field: value, got {value!r}')
  return dict(value) if value is not None else None


def _objects(values: dict[str, Any] | None, source: str) -> ObjectsConfig:
  values = dict(values or {})
  sources = values.pop('sources', None)
  objects = override(ObjectsConfig(), values, source=source, section='objects', minimum=0)
  if sources is not None:
    sources = string_list(sources, source=source, field='objects.sources', what='object sources')
    objects = dataclasses.replace(objects, sources=sources)
  return check_fields([count_rule('grid_size', objects.grid_size, 8, MAX_GRID_SIZE,
                                  'voxels per axis of each signed-distance grid; MAX_GRID_SIZE'),
                       ('scale', objects.scale > 0, 'a number > 0 (metres per mesh-file unit)')],
                      objects, source=source, section='objects')


def _camera(config: GenerateConfig, values: dict[str, Any] | None, source: str) -> GenerateConfig:
  """Applies the ``camera`` section: distribution fields, and ``file`` (relative to the config's folder)."""
  from dexjax.generate.cameras import apply_camera_file  # pylint: disable=g-import-not-at-top
  values = dict(values or {})
  camera_file = values.pop('file', None)
  dist = _checked('camera', override(config.camera, values, source=source, section='camera'), source)
  config = dataclasses.replace(config, camera=dist)
  if camera_file is None:
    return config
  if not isinstance(camera_file, str) or not camera_file:
    raise ConfigError(source, 'camera.file', f'expected a path to an intrinsics or camera file, got {camera_file!r}')
  return apply_camera_file(config, os.path.join(os.path.dirname(os.path.abspath(source)), camera_file))


def _checked(where: str, params: Any, source: str) -> Any:
  """``params.validate()`` with its ValueError turned into a `ConfigError` naming the file."""
  try:
    params.validate()
  except ValueError as e:
    raise ConfigError(source, where, str(e)) from None
  return params


def config_from_dict(data: Mapping[str, Any], source: str = '<config>') -> GenerateConfig:
  """A `GenerateConfig` from a decoded YAML mapping (layout: ``configs/dexnet4.yaml``); unset fields keep defaults.

  Raises:
    ConfigError: an unknown section or field, a value of the wrong type or out of range.
  """
  check_sections(data, _TOP, source=source)
  c = GenerateConfig()
  seed = data.get('seed', c.seed)
  if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
    raise ConfigError(source, 'seed', f'expected an integer >= 0, got {seed!r}')
  dataset = override(c.dataset, _section(data, 'dataset', source), source=source, section='dataset', minimum=1)
  if dataset.render_backend not in RENDER_BACKENDS:
    raise ConfigError(source, 'dataset.render_backend', f'expected one of {RENDER_BACKENDS}, got '
                                                         f'{dataset.render_backend!r}')
  bin_ = _checked('bin', override(c.bin, _section(data, 'bin', source), source=source, section='bin'), source)
  settle = override(c.settle, _section(data, 'settle', source), source=source, section='settle', minimum=0)
  settle = _checked('settle', dataclasses.replace(settle, bin=bin_), source)
  samplers = _section(data, 'samplers', source) or {}
  check_sections(samplers, _SAMPLERS, source=source, section='samplers')
  reward = _section(data, 'reward', source) or {}
  if 'collision_tolerance' in reward:
    raise ConfigError(source, 'reward.collision_tolerance',
                      'moved to quality.collision_tolerance (one tolerance for the heap reward, the supervisor and '
                      'the single-object quality); write quality: {collision_tolerance: ...}')
  check_sections(reward, _REWARD_FIELDS, source=source, section='reward')
  grippers_data = {k: data[k] for k in _GRIPPER_SECTIONS if k in data}
  grippers = settings_from_config(grippers_data, source) if grippers_data else c.grippers
  config = GenerateConfig(
      seed=seed,
      objects=_objects(_section(data, 'objects', source), source),
      dataset=dataset,
      heap=override(c.heap, _section(data, 'heap', source), source=source, section='heap', minimum=0),
      settle=settle,
      render=_checked('render', override(c.render, _section(data, 'render', source), source=source,
                                         section='render', minimum=0), source),
      noise=_checked('noise', override(c.noise, _section(data, 'noise', source), source=source, section='noise',
                                       minimum=0), source),
      parallel_jaw_sampler=override(c.parallel_jaw_sampler, samplers.get('parallel_jaw'), source=source,
                                    section='samplers.parallel_jaw', minimum=0),
      suction_sampler=override(c.suction_sampler, samplers.get('suction'), source=source, section='samplers.suction',
                               minimum=0),
      grippers=grippers,
      reward=override(c.reward, reward, source=source, section='reward', minimum=0),
      supervisor=override(c.supervisor, _section(data, 'supervisor', source), source=source, section='supervisor',
                          minimum=0),
      policy=_checked('policy', override(c.policy, _section(data, 'policy', source), source=source,
                                         section='policy', minimum=0), source))
  config = _collection(config, _section(data, 'collection', source), source)
  return validate_generate_config(_camera(_tied(config), _section(data, 'camera', source), source), source)


def _collection(config: GenerateConfig, values: dict[str, Any] | None, source: str) -> GenerateConfig:
  """Applies the ``collection`` section (its ``model`` relative to the config's folder) and loads the model."""
  values = dict(values or {})
  if 'model_digest' in values:
    raise ConfigError(source, 'collection.model_digest', 'set from the model when the config is loaded; remove it')
  if values.get('model') and values['model'] != PRETRAINED:
    values['model'] = os.path.join(os.path.dirname(os.path.abspath(source)), str(values['model']))
  collection = override(config.collection, values, source=source, section='collection')
  return with_collection(config, collection.policy, collection.model or None, collection.cem, source=source)


def with_collection(config: GenerateConfig, policy: str | None = None, model: str | os.PathLike[str] | None = None,
                    cem: str | None = None, *, source: str = '<arguments>') -> GenerateConfig:
  """``config`` collecting with ``policy`` (`COLLECTION_POLICIES`), the learned policy's ``model`` (loaded here for
  its digest) and CEM preset ``cem``; None keeps a field.

  Raises:
    ConfigError: an unknown policy or preset, ``on_policy`` without a model, a model with ``tau``.
    FileNotFoundError, ValueError: nothing loadable at ``model`` (`dexjax.models.load_models`).
  """
  c = config.collection
  policy = c.policy if policy is None else policy
  if model is not None:
    model = os.fspath(model) if os.fspath(model) == PRETRAINED else os.path.abspath(os.fspath(model))
  model = c.model if model is None else model
  cem = c.cem if cem is None else cem
  if policy not in COLLECTION_POLICIES:
    raise ConfigError(source, 'collection.policy', f'expected one of {COLLECTION_POLICIES}, got {policy!r}')
  if cem not in CEM_PRESETS:
    raise ConfigError(source, 'collection.cem', f'expected one of {CEM_PRESETS}, got {cem!r}')
  if policy == 'tau':
    if model:
      raise ConfigError(source, 'collection.model', "expected none with policy 'tau' (the seed's candidates need "
                                                    f"no model), got {model!r}; or set policy: on_policy")
    return dataclasses.replace(config, collection=CollectionConfig(cem=cem))
  if not model:
    raise ConfigError(source, 'collection.model', "expected the learned policy's GQ-CNNs with policy 'on_policy' "
                                                  '(a training run, saved model or model file; --model RUN)')
  from dexjax.generate.on_policy import collection_models  # pylint: disable=g-import-not-at-top (flax/orbax)
  _, digest = collection_models(model)
  return dataclasses.replace(config, collection=CollectionConfig(policy, model, digest, cem))


def _tied(config: GenerateConfig) -> GenerateConfig:
  """Ties the parameters that must agree across stages: the jaw sampler's width is the gripper's opening, and the
  reward's quality settings (wrench test, collision tolerance and sampling) are the ``quality`` section's, which
  the supervisor uses too."""
  sampler = config.parallel_jaw_sampler.replace(gripper_width=config.grippers.parallel_jaw.max_width)
  reward = config.reward.replace(quality=config.grippers.config)
  return dataclasses.replace(config, parallel_jaw_sampler=sampler, reward=reward)


def with_grippers(config: GenerateConfig, path: str | os.PathLike[str]) -> GenerateConfig:
  """``config`` with the grippers, their perturbation models and the quality settings of a gripper file
  (``configs/quality.yaml`` layout; its ``num_samples`` and ``threshold`` are not used: the reward's are)."""
  return _tied(dataclasses.replace(config, grippers=settings_from_config(load_yaml(path), os.fspath(path))))


def load_generate_config(path: str | os.PathLike[str] | None = None, *,
                         gripper_config: str | os.PathLike[str] | None = None,
                         camera_config: str | os.PathLike[str] | None = None,
                         objects: list[str] | None = None, seed: int | None = None,
                         collection_policy: str | None = None,
                         model: str | os.PathLike[str] | None = None) -> GenerateConfig:
  """The run's config: defaults, then the YAML file ``path``, then the optional overrides.

  Args:
    path: a generation config (``configs/dexnet4.yaml`` layout); None: the defaults.
    gripper_config: a gripper file (``configs/quality.yaml`` layout), replacing the ``grippers`` section.
    camera_config: a camera file: a YAML mapping of `CameraDistribution` fields (the pose and intrinsics
      ranges), or an intrinsics / camera file read by `dexjax.render.load_intrinsics` / `load_camera` (JSON,
      ROS CameraInfo); see `dexjax.generate.cameras`.
    objects: object sources replacing ``objects.sources``.
    seed: replaces ``seed``.
    collection_policy, model: replace ``collection.policy`` and ``collection.model`` (`with_collection`).
  """
  config = config_from_dict(load_yaml(path), os.fspath(path)) if path is not None else GenerateConfig()
  if gripper_config is not None:
    config = with_grippers(config, gripper_config)
  if camera_config is not None:
    from dexjax.generate.cameras import apply_camera_file  # pylint: disable=g-import-not-at-top
    config = apply_camera_file(config, camera_config)
  if objects:
    config = dataclasses.replace(config, objects=dataclasses.replace(config.objects, sources=tuple(objects)))
  if seed is not None:
    if seed < 0:
      raise ConfigError('--seed', 'seed', f'expected an integer >= 0, got {seed}')
    config = dataclasses.replace(config, seed=seed)
  if collection_policy is not None or model is not None:
    policy = collection_policy if collection_policy is not None else ('on_policy' if model else None)
    config = with_collection(config, policy, model, source='--collection-policy / --model')
  return config


# Settling fields that change speed, not results, enter the fingerprint at fixed values (those datasets were made
# with before they became speed-only), so changing them never changes it and older datasets keep theirs
# (`rollout_wave` is no longer a setting: each thread settles one heap at a time since 2026-12-05).
_SPEED_ONLY = {'chunk_steps': 25, 'rollout_wave': 256}


def content_fields(record: Mapping[str, Any]) -> dict[str, Any]:
  """The fields of a config record (``as_dict(config)``, or a run's ``config.json`` ``config``) that determine a
  shard's content, JSON-ready: without the seed and the settling threads, with the settling chunks and waves at
  fixed values (`_SPEED_ONLY`), and without the sleep fields when ``settle.sleep`` is off (or absent): the
  physics of datasets made before sleeping objects (2026-12-04), which therefore keep their fingerprint; nor
  ``policy.top_k`` when it is 0 (it orders only a learned policy's candidates; the seed's tau has none); the
  ``collection`` section only when it collects on-policy, then with the model's digest and not its path."""
  data = plain_json(record)
  data.pop('seed', None)
  settle = data['settle']
  settle.pop('nthread', None)
  settle.update(_SPEED_ONLY)
  if not settle.get('sleep', False):
    settle.pop('sleep', None)
    settle.pop('sleep_tolerance', None)
  if not data.get('policy', {}).get('top_k'):
    data.get('policy', {}).pop('top_k', None)
  collection = data.pop('collection', None) or {}
  if collection.get('policy', 'tau') != 'tau':
    data['collection'] = {k: v for k, v in collection.items() if k != 'model'}
  return data


def fingerprint(config: GenerateConfig) -> str:
  """`dexjax.data.config_fingerprint` of everything that determines a shard's content (`content_fields`: not the
  seed), the shard format, the labelling version (`dexjax.generate.labels.LABEL_VERSION`) and the procedural
  objects' (`dexjax.objects.PROCEDURAL_VERSION`: a spec such as ``procedural:L1/0:3`` names other meshes when it
  changes)."""
  data = content_fields(as_dict(config))
  data['versions'] = {'shard_format': FORMAT_VERSION, 'labels': LABEL_VERSION, 'procedural': PROCEDURAL_VERSION}
  return config_fingerprint(data)

