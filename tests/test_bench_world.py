"""The benchmark's simulated bin: filled and settled, seen by a camera, an object taken out, the rest settling."""

from __future__ import annotations

import dataclasses
import functools
import json

import jax
import numpy as np
import pytest
from scipy import ndimage

from dexjax.bench.world import BinState, PickingWorld
from dexjax.generate.config import config_from_dict
from dexjax.render.camera import Intrinsics
from dexjax.render.distribution import camera_from_spherical
from dexjax.render.rendering import BIN_LABEL

SOURCES = ['builtin:cube', 'builtin:box', 'builtin:cylinder', 'builtin:l_shape', 'procedural:L1/0:2']
CAMERA_RANGES = {'width': 160, 'height': 160, 'focal': [170.0, 180.0], 'cx': [79.0, 81.0], 'cy': [79.0, 81.0]}
CAMERA = camera_from_spherical(np.zeros(3), 0.7, 4.71, 0.05, Intrinsics(fx=300.0, fy=300.0, cx=80.0, cy=80.0,
                                                                        width=160, height=160))


@pytest.fixture(scope='module')
def world(tmp_path_factory):
  config = config_from_dict({'objects': {'sources': SOURCES, 'grid_size': 32}, 'camera': CAMERA_RANGES}, 'test')
  with PickingWorld(config, cache_dir=tmp_path_factory.mktemp('world_cache')) as w:
    yield w


@pytest.fixture(scope='module')
def full(world):
  return world.fill(jax.random.key(0), 6)


def test_fill_puts_every_object_at_rest_in_the_bin(world, full):
  assert full.count == 6 and sorted(full.object_ids.tolist()) == list(range(6))  # all six, each once
  assert np.all(np.abs(full.poses[:, :2]) < 0.2) and np.all(full.poses[:, 2] > 0.0)
  again = world.settle_again(full)  # already at rest: settling again moves nothing noticeably
  np.testing.assert_allclose(again.poses[:, :3], full.poses[:, :3], atol=3e-3)
  with pytest.raises(ValueError, match=r'expected an integer in \[1, 6\]'):
    world.fill(jax.random.key(0), 7)


def test_the_camera_sees_the_objects_and_the_empty_bin_is_the_background(world, full):
  depth, seg = world.observe(jax.random.key(1), full, CAMERA)
  assert depth.shape == seg.shape == (160, 160)
  seen = set(np.unique(seg).tolist()) - {BIN_LABEL, -2}
  assert seen and seen <= set(range(6))
  background = world.empty_bin(CAMERA)
  on_bin = seg == BIN_LABEL
  # Noise is off by default in a generation config: the bin's pixels match the empty-bin image exactly, object
  # pixels are nearer the camera (all but a few at the objects' feet, where they touch the floor).
  np.testing.assert_allclose(depth[on_bin], background[on_bin], atol=1e-5)
  objects = seg >= 0
  assert np.all(depth[objects] <= background[objects] + 1e-5)
  assert np.mean(depth[objects] < background[objects] - 1e-3) > 0.95


def test_fill_drops_the_objects_it_is_given(world):
  state = world.fill(jax.random.key(3), 2, object_ids=[4, 1])
  assert state.count == 2 and sorted(state.object_ids[state.mask].tolist()) == [1, 4]
  for bad in ([4], [1, 1], [0, 6], [-1, 0]):
    with pytest.raises(ValueError, match=r'object_ids: expected 2 distinct object indices in \[0, 6\)'):
      world.fill(jax.random.key(3), 2, object_ids=bad)


def test_remove_takes_one_object_out_and_the_state_round_trips_through_json(world, full):
  slot = int(np.flatnonzero(full.mask)[0])
  after = world.remove(full, slot)
  assert after.count == 5 and not after.mask[slot] and after.object_ids[slot] == -1
  _, seg = world.observe(jax.random.key(1), after, CAMERA)
  assert slot not in set(np.unique(seg).tolist())
  restored = BinState.from_json(json.loads(json.dumps(after.to_json())))
  for field in ('object_ids', 'mask', 'poses', 'friction'):
    np.testing.assert_array_equal(getattr(restored, field), getattr(after, field))
  with pytest.raises(ValueError, match=f'slot {slot} holds no object'):
    world.remove(after, slot)


def test_scene_stacks_each_slots_model_with_its_pose_and_friction(world, full):
  after = world.remove(full, int(np.flatnonzero(full.mask)[-1]))
  scene = world.scene(after)
  assert np.array_equal(np.asarray(scene.mask), after.mask)
  for slot in np.flatnonzero(after.mask):
    np.testing.assert_array_equal(np.asarray(scene.models.sdf[slot]), np.asarray(world.models[after.object_ids[slot]].sdf))
  np.testing.assert_allclose(np.asarray(scene.poses), after.poses, atol=1e-6)
  assert np.all(np.asarray(scene.friction)[~after.mask] == 0.0)


def test_the_supervisors_scene_carries_each_objects_resting_load(world, full):
  """`PickingWorld.loads` in a settled bin: world-frame loads, none pushing an object up (supports are not loads),
  none in empty slots (the statics are checked in test_resting_loads); the scene of the supervisor holds them, the
  judges' scene does not."""
  loads = world.loads(full)
  assert loads.shape == (full.mask.shape[0], 6) and np.all(np.isfinite(loads))
  np.testing.assert_array_equal(loads[~full.mask], 0.0)
  assert np.all(loads[:, 2] <= 1e-6)
  np.testing.assert_allclose(np.asarray(world.scene(full, loads=True).loads), loads, atol=1e-6)
  assert world.scene(full).loads is None


# --- Trials: the protocol's stopping rules with scripted policies and the real analytic judge -----------------

from dexjax.bench.protocol import Protocol, stop_reason  # noqa: E402
from dexjax.bench.judges import analytic_judge  # noqa: E402
from dexjax.bench.trial import _bin_level, run_trial  # noqa: E402
from dexjax.policy import action_from_grasp  # noqa: E402
from dexjax.sampling.image_grasps import ImageParallelJawGrasp, ImageSuctionGrasp  # noqa: E402


def top_suction(key, obs):
  """A scripted policy: suction straight down (world) at the centre of the highest surface it sees."""
  del key
  depth, mask = np.asarray(obs.depth), np.asarray(obs.mask)
  points = np.asarray(obs.camera.rotation) @ np.stack([  # world z of every pixel (camera looks down)
      (np.arange(depth.shape[1])[None] - float(obs.camera.intrinsics.cx)) / float(obs.camera.intrinsics.fx) * depth,
      (np.arange(depth.shape[0])[:, None] - float(obs.camera.intrinsics.cy)) / float(obs.camera.intrinsics.fy) * depth,
      depth]).reshape(3, -1)
  height = (points[2].reshape(depth.shape) + float(obs.camera.position[2]))
  masked = np.where(mask, height, -np.inf)
  top, _ = ndimage.label(mask & (height > masked.max() - 0.003))  # the highest face: its connected piece
  v, u = np.argwhere(top == top[np.unravel_index(np.argmax(masked), masked.shape)]).mean(axis=0)
  down = np.asarray(obs.camera.rotation).T @ np.array([0.0, 0.0, -1.0])
  grasp = ImageSuctionGrasp(center=np.array([u, v], np.float32), angle=np.float32(np.arctan2(-down[0], down[1])),
                            depth=np.float32(depth[int(round(v)), int(round(u))]),
                            approach_angle=np.float32(np.arccos(np.clip(down[2], -1, 1))))
  return action_from_grasp(obs, grasp, np.float32(1.0), True)


def no_grasp(key, obs):
  return top_suction(key, obs).replace(valid=np.bool_(False))


def test_stop_reason_follows_the_seed():
  seed = Protocol()
  assert (seed.objects_per_trial, seed.trials, seed.max_attempts, seed.max_consecutive_failures) == (25, 5, 75, 10)
  assert stop_reason(0, 75, 10, seed) == 'empty'
  assert stop_reason(3, 75, 0, seed) == 'max_attempts' and stop_reason(3, 74, 0, seed) is None
  assert stop_reason(3, 20, 10, seed) == 'consecutive_failures' and stop_reason(3, 20, 9, seed) is None
  with pytest.raises(ValueError, match='Protocol.trials: expected an integer >= 1'):
    Protocol(trials=0).validate()


@pytest.fixture(scope='module')
def boxes(tmp_path_factory):
  """A world of a cube and a box: flat tops the scripted suction policy always takes."""
  config = config_from_dict({'objects': {'sources': ['builtin:cube', 'builtin:box'], 'grid_size': 32},
                             'camera': CAMERA_RANGES}, 'test')
  with PickingWorld(config, cache_dir=tmp_path_factory.mktemp('boxes_cache')) as w:
    yield w


def test_a_policy_that_picks_every_object_empties_the_bin_and_resumes_identically(boxes, tmp_path):
  world = boxes
  judges = {'analytic': analytic_judge(world)}
  protocol = Protocol(objects_per_trial=2)
  log = tmp_path / 'attempts.jsonl'
  records = run_trial(world, top_suction, judges, policy='top', trial=0, protocol=protocol, log_path=log)
  assert records[-1]['stop'] == 'empty' and records[-1]['objects_left'] == 0
  assert sum(r['success'] for r in records) == 2 and all(r['analytic'] == r['success'] for r in records)
  assert all(r['object'] is not None and r['gripper'] == 'suction' for r in records)
  from dexjax.bench import read_attempts
  assert read_attempts(log) == records
  resumed = run_trial(world, top_suction, judges, policy='top', trial=0, protocol=protocol, logged=records[:1])
  timing = ('plan_seconds', 'stage_seconds')
  strip = lambda rs: [{k: v for k, v in r.items() if k not in timing} for r in rs]
  assert strip(resumed) == strip(records)


def test_consecutive_failures_the_attempt_budget_and_no_grasp_end_a_trial(world):
  judges = {'analytic': analytic_judge(world)}
  records = run_trial(world, edge_suction, judges, policy='edge', trial=1,
                      protocol=Protocol(objects_per_trial=2, max_consecutive_failures=3))
  assert [r['stop'] for r in records] == [None, None, 'consecutive_failures']
  assert all(not r['success'] and r['reason'] != 'no_grasp' and r['objects_left'] == 2 for r in records)
  records = run_trial(world, edge_suction, judges, policy='edge', trial=1,
                      protocol=Protocol(objects_per_trial=2, max_attempts=2))
  assert [r['stop'] for r in records] == [None, 'max_attempts']
  # A policy that finds no grasp would find none again in the unchanged bin: one failed attempt ends the trial.
  records = run_trial(world, no_grasp, judges, policy='none', trial=1, protocol=Protocol(objects_per_trial=2))
  assert [(r['stop'], r['reason'], r['success']) for r in records] == [('no_grasp', 'no_grasp', False)]
  assert records[0]['object'] is None
  # An attempt that aimed at no object gets the bin's level when every object in it shares one.
  level_one = [i for i, level in enumerate(world.levels) if level == 1]
  builtin = [i for i, level in enumerate(world.levels) if level is None]
  assert len(level_one) == 2 and builtin

  def bin_of(ids):
    state = BinState.from_json(records[0]['state'])
    mask = np.zeros_like(state.mask)
    mask[:len(ids)] = True
    object_ids = np.full_like(state.object_ids, -1)
    object_ids[:len(ids)] = ids
    return dataclasses.replace(state, mask=mask, object_ids=object_ids)

  assert _bin_level(world, bin_of(level_one)) == 1
  assert _bin_level(world, bin_of([level_one[0], builtin[0]])) is None


def edge_suction(key, obs):
  """A scripted policy that always fails the same way: suction at the first grasp pixel in raster order (an
  object's border: the lip hangs over the edge), unless that pixel is masked out."""
  del key
  mask = np.asarray(obs.mask)
  v, u = np.argwhere(mask)[0]
  grasp = ImageSuctionGrasp(center=np.array([u, v], np.float32), angle=np.float32(0.0),
                            depth=np.float32(np.asarray(obs.depth)[v, u]), approach_angle=np.float32(0.0))
  return action_from_grasp(obs, grasp, np.float32(0.9), True)


def test_failure_memory_moves_a_policy_off_its_failed_grasp(world):
  """Without a memory a failing deterministic policy repeats the same grasp until the trial ends; with a 2 cm
  memory of the last 5 attempts no later grasp lies within 2 cm of an earlier failure of the memory's window."""
  from dexjax.bench import FailureMemory, repeated_attempts  # pylint: disable=g-import-not-at-top
  judges = {'analytic': analytic_judge(world)}
  protocol = Protocol(objects_per_trial=3, max_consecutive_failures=4)
  plain = run_trial(world, edge_suction, judges, policy='edge', trial=2, protocol=protocol)
  assert not any(r['success'] for r in plain)
  assert repeated_attempts(plain) == [False, True, True, True]
  remembered = run_trial(world, edge_suction, judges, policy='edge', trial=2, protocol=protocol,
                         memory=FailureMemory(radius=0.02, attempts=5))
  centres = [np.asarray(r['world_center']) for r in remembered if r['world_center'] is not None]
  assert len(centres) >= 2 and not any(repeated_attempts(remembered))
  assert min(np.linalg.norm(a - b) for i, a in enumerate(centres) for b in centres[:i]) > 0.02
  assert remembered[0]['world_center'] == plain[0]['world_center']  # the first attempt has nothing to remember
  with pytest.raises(ValueError, match=r'FailureMemory.radius \(--failure-memory\): expected a number >= 0'):
    run_trial(world, edge_suction, judges, policy='edge', trial=2, protocol=protocol, memory=FailureMemory(-1.0))


def deep_jaws(key, obs):
  """A scripted policy that always fails the same way: parallel jaws across the first grasp pixel in raster order,
  centred 3 cm below the surface seen there (the jaws go into the object), unless that pixel is masked out."""
  del key
  v, u = np.argwhere(np.asarray(obs.mask))[0]
  grasp = ImageParallelJawGrasp(center=np.array([u, v], np.float32), angle=np.float32(0.0),
                                depth=np.float32(np.asarray(obs.depth)[v, u] + 0.03), width=np.float32(0.05))
  return action_from_grasp(obs, grasp, np.float32(0.9), True)


def test_failure_memory_remembers_where_the_jaws_aimed_not_their_centre(world):
  """The jaws' centre lies 3 cm below the surface their centre pixel shows, beyond a 1 cm memory of grasp centres;
  the memory keeps the surface point (``aim_point``), so the jaws do not come back to it."""
  from dexjax.bench import FailureMemory, repeated_attempts  # pylint: disable=g-import-not-at-top
  judges = {'analytic': analytic_judge(world)}
  protocol = Protocol(objects_per_trial=3, max_consecutive_failures=3)
  plain = run_trial(world, deep_jaws, judges, policy='deep', trial=2, protocol=protocol)
  assert not any(r['success'] for r in plain) and repeated_attempts(plain) == [False, True, True]
  aim, centre = np.asarray(plain[0]['aim_point']), np.asarray(plain[0]['world_center'])
  assert 0.025 < np.linalg.norm(aim - centre) < 0.035
  remembered = run_trial(world, deep_jaws, judges, policy='deep', trial=2, protocol=protocol,
                         memory=FailureMemory(radius=0.01, attempts=5))
  assert not any(repeated_attempts(remembered))


def test_the_supervisor_empties_a_bin_of_boxes_under_both_judges(boxes):
  """The supervisor policy with the bin's true state empties a bin of a cube and a box; every pick the physics
  judge counts, the labels' reward counts too. (Its first grasps on the cube come down on a tilted cube's corner,
  which the labels' sampled collision test does not see and the force guard stops at; with a 1 cm memory of
  failures it moves on instead of repeating them: docs/benchmark.md.)"""
  from dexjax.bench import FailureMemory, physics_judge, supervisor_policy  # pylint: disable=g-import-not-at-top
  from dexjax.policy import make_policy  # pylint: disable=g-import-not-at-top
  with pytest.raises(ValueError, match="policy 'supervisor': reads the true state of a simulated bin"):
    make_policy('supervisor')
  policy = supervisor_policy(boxes)
  assert policy.privileged and make_policy('supervisor', world=boxes).sets[0].valid.shape == policy.sets[0].valid.shape
  judges = {'physics': physics_judge(boxes), 'analytic': analytic_judge(boxes)}
  records = run_trial(boxes, policy, judges, policy='supervisor', trial=0, advance_by='physics',
                      protocol=Protocol(objects_per_trial=2), memory=FailureMemory(radius=0.01, attempts=5))
  assert records[-1]['stop'] == 'empty' and sum(r['physics'] for r in records) == 2
  assert all(r['analytic'] for r in records if r['physics']) and all(r['q'] > 0.5 for r in records)


def test_the_supervisor_tries_its_best_effort_when_no_grasp_passes(boxes):
  """With the labels' mass law centred on 400 times each object's mass (about 100 kg) no grasp passes the
  supervisor's test (that reward is never robust): without the fallback the trial stops at once with no grasp;
  with it the supervisor executes the collision-free grasps of highest true-mass probability, scored at most the
  threshold 0.5, and empties the bin (a cube and a box, which the labels' reward with their own law counts as
  picked)."""
  from dexjax.bench import supervisor_policy  # pylint: disable=g-import-not-at-top
  heavy = _heavy_labels(supervisor_policy(boxes))
  judges = {'analytic': analytic_judge(boxes)}
  trial = functools.partial(run_trial, boxes, judges=judges, policy='supervisor', trial=0, advance_by='analytic',
                            protocol=Protocol(objects_per_trial=2))
  stopped = trial(dataclasses.replace(heavy, fallback=False))
  assert len(stopped) == 1 and stopped[0]['stop'] == 'no_grasp' and stopped[0]['gripper'] is None
  tried = trial(heavy)
  assert tried[-1]['stop'] == 'empty' and sum(r['analytic'] for r in tried) == 2
  assert all(r['gripper'] is not None and 0.0 <= r['q'] <= 0.5 for r in tried)
  # True masses of about 100 kg (no grasp holds them in any draw) under the labels' own law: the best effort is
  # the grasp the labels' law holds in the most draws; the labels' reward counts it as picked.
  by_law = trial(_heavy_labels(supervisor_policy(boxes), true_masses=True))
  assert by_law[-1]['stop'] == 'empty' and sum(r['analytic'] for r in by_law) == 2
  assert all(r['gripper'] is not None and r['q'] == 0.0 for r in by_law)  # its true-mass probability: 0


def _heavy_labels(policy, true_masses=False):
  """``policy`` with the labels' mass law centred on 400 times each object's mass (about 100 kg), or with true
  masses 400 times the objects' (``true_masses``): no grasp passes."""

  class HeavyLabels(type(policy)):
    def __call__(self, key, observation, scene, masses, *args):
      if true_masses:
        return super().__call__(key, observation, scene, masses * 400.0, *args)
      return super().__call__(key, observation, scene.replace(mass=scene.mass * 400.0), masses, *args)

  return HeavyLabels(**{f.name: getattr(policy, f.name) for f in dataclasses.fields(policy)})


def test_the_supervisor_scores_further_candidates_only_while_none_passes(boxes, monkeypatch):
  """The supervisor scores each gripper's eligible candidates ``num_scored`` at a time, best set quality first:
  on a bin of a cube and a box it stops at the first round holding a grasp both rewards accept (every earlier
  round holds none) and executes the best grasp of the rounds it scored; when no grasp passes (the heavy labels) it
  scores every eligible candidate once, in order of set quality, and executes the best effort over all of them."""
  import importlib  # pylint: disable=g-import-not-at-top
  from dexjax.bench import supervisor_policy  # pylint: disable=g-import-not-at-top
  module = importlib.import_module('dexjax.bench.supervisor_policy')
  rounds, eligible, ranked, candidates = [], {}, module._ranked, module._eligible_quality

  def recording(key, images, idx, top, scene, masses, camera, params, suction, *args):
    robust, rank = ranked(key, images, idx, top, scene, masses, camera, params, suction, *args)
    rounds.append((bool(suction), np.asarray(idx), np.asarray(top), np.asarray(robust), np.asarray(rank)))
    return robust, rank

  def counting(*args):
    images, quality = candidates(*args)
    eligible[bool(args[-1])] = int(np.isfinite(np.asarray(quality)).sum())
    return images, quality

  monkeypatch.setattr(module, '_ranked', recording)
  monkeypatch.setattr(module, '_eligible_quality', counting)
  judges = {'analytic': analytic_judge(boxes)}
  policy = supervisor_policy(boxes, num_scored=8)
  for labels, passes in ((policy, True), (_heavy_labels(policy), False)):
    rounds.clear()
    record = run_trial(boxes, labels, judges, policy='supervisor', trial=0, advance_by='analytic',
                       protocol=Protocol(objects_per_trial=2, max_attempts=1))[0]
    best = {}
    for suction in (False, True):
      mine = [r for r in rounds if r[0] == suction]
      assert mine, suction
      tops = np.concatenate([r[2] for r in mine])
      assert np.all(np.diff(tops[np.isfinite(tops)]) <= 0), suction  # best set quality first
      assert len(np.unique(np.concatenate([r[1] for r in mine])[np.isfinite(tops)])) == np.isfinite(tops).sum()
      assert all(r[4].max() < 2.0 for r in mine[:-1]), suction  # a round runs only while none passes
      if mine[-1][4].max() < 2.0:  # none passed: every eligible candidate was scored, once
        assert np.isfinite(tops).sum() == eligible[suction] > 8, suction
      ranks = np.concatenate([r[4] for r in mine])
      best[suction] = (ranks.max(), np.concatenate([r[3] for r in mine])[ranks.argmax()])
    rank, score = max(best.values(), key=lambda b: b[0])
    assert (rank >= 2.0) == passes and np.isfinite(rank)
    assert record['q'] == pytest.approx(score) and (record['q'] > 0.5) == passes


def test_the_supervisor_takes_an_object_clear_to_lift_first(boxes, monkeypatch):
  """Among grasps that pass, the supervisor takes those on an object that rises straight out of the heap first:
  told that only the object it did not choose (of a cube and a box) is clear to lift, it chooses that one; told
  that only its own choice is, it keeps it; with ``lift_first`` off, what it is told does not matter."""
  import importlib  # pylint: disable=g-import-not-at-top
  from dexjax.bench import supervisor_policy  # pylint: disable=g-import-not-at-top
  module = importlib.import_module('dexjax.bench.supervisor_policy')
  policy = supervisor_policy(boxes)
  judges = {'analytic': analytic_judge(boxes)}
  target = lambda p: run_trial(boxes, p, judges, policy='supervisor', trial=0, advance_by='analytic',
                               protocol=Protocol(objects_per_trial=2, max_attempts=1))[0]['verdicts']['analytic'][
                                   'target_slot']
  chosen = target(policy)
  assert chosen in (0, 1)
  other = 1 - chosen
  for clear, lift_first, expected in ((other, True, other), (chosen, True, chosen), (other, False, chosen)):
    only = lambda scene, slot=clear: scene.mask & (jax.numpy.arange(scene.mask.shape[0]) == slot)
    monkeypatch.setattr(module, '_slots_clear_to_lift', only)
    assert target(dataclasses.replace(policy, lift_first=lift_first)) == expected, (clear, lift_first)


def test_pickability_drops_each_object_alone_and_counts_what_the_policy_picks(boxes):
  """Each object alone in the bin, judged in MuJoCo: the top-suction policy picks the cube and the box in every
  drop within two attempts (a drop picked at the first attempt costs one); the edge policy (the lip over an edge)
  picks nothing in two attempts, and the summary names the object picked in no drop."""
  from dexjax.bench import physics_judge  # pylint: disable=g-import-not-at-top
  from dexjax.bench.pickability import object_pickability, pickability_summary, set_pickability
  judges = {'analytic': analytic_judge(boxes), 'physics': physics_judge(boxes)}
  rows = set_pickability(boxes, top_suction, judges, drops=2, attempts=2)
  assert [r.name for r in rows] == boxes.names
  for i, r in enumerate(rows):
    assert (r.drops, r.picked, r.no_grasp) == (2, 2, 0) and 1 <= r.first_attempt <= 2 and 0 <= r.labels_pass <= 2, r
    assert r.attempts == 2 + (2 - r.first_attempt) and sum(r.failures.values()) == r.attempts - 2, r
    assert r.grippers == {'suction': 2} and r.pickable and r.mass == boxes.bodies[i].mass
  firsts = sum(r.first_attempt for r in rows) / 4
  assert pickability_summary(rows) == {'objects': 2, 'pickable': 2, 'not_pickable': [], 'drops': 4, 'picked': 1.0,
                                       'first_attempt': firsts, 'labels_pass': sum(r.labels_pass for r in rows) / 4}
  edge = object_pickability(boxes, edge_suction, judges, 1, drops=1, attempts=2)
  assert (edge.picked, edge.first_attempt, edge.attempts, edge.pickable) == (0, 0, 2, False)
  assert sum(edge.failures.values()) == 2 and json.loads(json.dumps(edge.to_json()))['pickable'] is False
  assert pickability_summary([edge])['not_pickable'] == [boxes.names[1]]
  with pytest.raises(ValueError, match='Protocol.trials: expected an integer >= 1'):
    object_pickability(boxes, top_suction, judges, 0, drops=0)
