"""Benchmark picking metrics (against SciPy and exact kinematics), repeated attempts and cleared bins, and the attempt
log (torn lines, damage, resume)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import stats

from dexjax.bench import (AttemptLogError, MotionModel, append_attempt, calibration, choice_summary,
                          cleared_fraction, move_seconds, object_difficulty, precision_at_choice, rated_acceleration,
                          read_attempts, repeated_attempts, sem_interval, summarize, wilson_interval)


@pytest.mark.parametrize('k,n', [(0, 1), (0, 10), (3, 10), (10, 10), (57, 61), (1, 75), (125, 131)])
def test_wilson_interval_matches_scipy(k, n):
  ci = stats.binomtest(k, n).proportion_ci(confidence_level=0.95, method='wilson')
  np.testing.assert_allclose(wilson_interval(k, n), (ci.low, ci.high), atol=1e-12)


def test_sem_interval_is_the_seeds_normal_interval():
  p, n = 125 / 131, 131
  half = stats.norm.ppf(0.975) * math.sqrt(p * (1 - p) / n)
  np.testing.assert_allclose(sem_interval(125, 131), (p - half, min(1.0, p + half)), atol=1e-12)
  assert sem_interval(10, 10) == (1.0, 1.0)  # the seed's interval collapses at 0 and 1; Wilson's does not
  assert wilson_interval(10, 10)[0] < 0.75
  assert all(math.isnan(x) for x in sem_interval(0, 0) + wilson_interval(0, 0))


@pytest.mark.parametrize('distance', [0.01, 0.2, 0.45, 1.3])
def test_move_seconds_is_the_shortest_minimum_jerk_move_within_both_limits(distance):
  """The move's time is the shortest duration T whose minimum-jerk profile s(t) = D (10 tau^3 - 15 tau^4 + 6 tau^5)
  stays within the speed and the acceleration limits: check both limits on the profile numerically (central
  differences), that one of them is reached, and that a 1 % shorter move breaks one."""
  speed, acceleration = 1.5, 2.27

  def peaks(duration):
    t = np.linspace(0.0, duration, 20001)
    tau = t / duration
    s = distance * tau ** 3 * (10 - 15 * tau + 6 * tau ** 2)
    v = np.gradient(s, t)
    return v.max(), np.abs(np.gradient(v, t)).max()

  t = move_seconds(distance, speed, acceleration)
  v, a = peaks(t)
  assert v <= speed * (1 + 1e-3) and a <= acceleration * (1 + 1e-3)
  assert max(v / speed, a / acceleration) == pytest.approx(1.0, abs=2e-3)
  v, a = peaks(0.99 * t)
  assert v > speed or a > acceleration
  assert move_seconds(0.0, speed, acceleration) == 0.0


def test_rated_acceleration_of_the_seeds_cup():
  """The seed's cup (0.9 kg payload) rated with S = 1.5 for 0.6 kg: vertically a <= g (S - 1) = 4.9 m/s²; the
  labels' friction box mu (V - m g) / sqrt(3) over m at mu = 0.8 gives 2.27 m/s², the binding one."""
  g = 9.81
  vertical = 0.9 * g / 0.6 - g
  lateral = 0.8 * (0.9 * g - 0.6 * g) / (math.sqrt(3.0) * 0.6)
  assert rated_acceleration() == pytest.approx(min(vertical, lateral)) == pytest.approx(2.2655, abs=1e-4)
  assert rated_acceleration(friction=2.0) == pytest.approx(vertical)  # a grippy lip: the vacuum limit binds
  assert MotionModel().acceleration == rated_acceleration()


def test_motion_model_slows_with_a_slower_robot_and_longer_paths():
  base = MotionModel()
  seconds = base.attempt_seconds()
  assert 1.5 < seconds < 8.0  # a pick-and-place cycle of the seed's YuMi
  assert MotionModel(tool_speed=0.5).attempt_seconds() > seconds
  assert MotionModel(transport_distance=0.8).attempt_seconds() > seconds
  assert MotionModel(actuation_seconds=0.5).attempt_seconds() == pytest.approx(seconds + 0.4)


def _record(policy, level, obj, success, analytic=None, physics=None, plan=1.0, motion=2.0, trial=0, start=10,
            gripper='suction', center=None, q=None):
  return {'policy': policy, 'level': level, 'object': obj, 'success': success, 'analytic': analytic,
          'physics': physics, 'plan_seconds': plan, 'motion_seconds': motion, 'trial': trial,
          'objects_at_start': start, 'gripper': gripper, 'world_center': center, 'q': q}


def test_summarize_counts_reliability_mpph_agreement_and_per_object():
  records = ([_record('a', 1, 'cube', True, True, True, q=0.9)] * 3
             + [_record('a', 1, 'cube', False, True, False, q=0.7)]
             + [_record('a', 2, 'mug', False, False, False, q=0.3), _record('a', 2, 'mug', False, False, False, q=0.5)]
             + [_record('a', 2, None, False)]
             + [_record('b', 1, 'cube', True, plan=0.5)] * 4)
  out = summarize(records)
  a, b = out['a'], out['b']
  assert (a['attempts'], a['successes']) == (7, 3) and a['reliability'] == pytest.approx(3 / 7)
  assert a['mpph'] == pytest.approx(3600 * 3 / (7 * 3.0))  # successes per hour of plan + motion time
  assert a['mpph'] == pytest.approx(a['reliability'] * 3600 / a['seconds_per_attempt'])
  assert a['judge_agreement'] == pytest.approx(5 / 6) and a['judged_by_both'] == 6
  # On the grasps the policy expects to succeed (q above 0.5: not the mug's 0.3 and 0.5) the judges agree on 3 of 4.
  assert a['judge_agreement_confident'] == pytest.approx(3 / 4) and a['judged_confident'] == 4
  assert math.isnan(out['b']['judge_agreement_confident']) and out['b']['judged_confident'] == 0
  from dexjax.bench.picking_metrics import CONFIDENT  # pylint: disable=g-import-not-at-top
  from dexjax.quality import REWARD_THRESHOLD  # pylint: disable=g-import-not-at-top
  assert CONFIDENT == REWARD_THRESHOLD  # "expects to succeed" is the reward's own threshold
  assert a['per_object']['cube']['attempts'] == 4 and a['per_object']['cube']['reliability'] == 0.75
  assert set(a['per_object']) == {'cube', 'mug'}  # an attempt that aimed at no object counts for the policy only
  assert (a['per_level']['2']['attempts'], a['per_level']['2']['successes']) == (3, 0)
  assert b['reliability'] == 1.0 and b['mpph'] == pytest.approx(3600 / 2.5) and math.isnan(b['judge_agreement'])
  difficulty = object_difficulty(out)
  assert list(difficulty) == ['mug', 'cube']  # hardest first
  assert difficulty['cube']['reliability'] == pytest.approx((0.75 + 1.0) / 2)
  assert difficulty['cube']['sem'] == pytest.approx(np.std([0.75, 1.0], ddof=1) / math.sqrt(2))
  assert difficulty['mug'] == {'reliability': 0.0, 'sem': 0.0, 'policies': 1}
  assert a['cleared'] == pytest.approx(3 / 10) and b['cleared'] == pytest.approx(4 / 10)
  assert a['repeated_attempts'] == b['repeated_attempts'] == 0  # no grasp centres recorded


def _choices(seed: int, n: int = 400) -> list[dict]:
  """Attempts of a policy whose q is over-confident: success ~ Bernoulli(q^2) under both judges' draws."""
  rng = np.random.default_rng(seed)
  q = rng.uniform(0, 1, n)
  gripper = rng.choice(['parallel_jaw', 'suction'], n)
  return [{'gripper': str(g), 'q': float(p), 'analytic': bool(rng.uniform() < p * p),
           'physics': bool(rng.uniform() < p * p)} for g, p in zip(gripper, q)]


def test_calibration_matches_a_numpy_histogram_reference():
  records = _choices(0)
  q = np.array([r['q'] for r in records])
  hit = np.array([r['analytic'] for r in records], float)
  counts, _ = np.histogram(q, bins=10, range=(0, 1))
  sums, _ = np.histogram(q, bins=10, range=(0, 1), weights=q)
  wins, _ = np.histogram(q, bins=10, range=(0, 1), weights=hit)
  full = counts > 0
  ece = np.sum(counts[full] / len(q) * np.abs(sums[full] / counts[full] - wins[full] / counts[full]))
  out = calibration(records, 'analytic', 10)
  assert out['count'] == 400 and [b['count'] for b in out['bins']] == counts.tolist()
  np.testing.assert_allclose([b['mean_q'] for b in out['bins']], sums / counts, atol=1e-12)
  np.testing.assert_allclose([b['success'] for b in out['bins']], wins / counts, atol=1e-12)
  assert out['ece'] == pytest.approx(ece, abs=1e-12)
  # An over-confident policy (success q^2): the expected error is E|q - q^2| = 1/6 in the limit.
  assert 0.12 < out['ece'] < 0.22
  calibrated = [dict(r, analytic=bool(np.random.default_rng(i).uniform() < r['q'])) for i, r in enumerate(records)]
  assert calibration(calibrated)['ece'] < 0.08


def test_calibration_bins_decimal_probabilities_at_their_edges_and_counts_no_grasp_apart():
  records = [{'gripper': 'suction', 'q': float(np.float32(q)), 'analytic': a, 'physics': None}
             for q, a in ((0.7, True), (0.7, False), (0.3, True), (1.0, True), (0.0, False))]
  records.append({'gripper': None, 'q': 0.0, 'analytic': False, 'physics': False})
  bins = calibration(records, 'analytic', 10)['bins']
  assert [b['count'] for b in bins] == [1, 0, 0, 1, 0, 0, 0, 2, 0, 1]  # float32 0.7 = 0.69999999 goes to [0.7, 0.8)
  assert math.isnan(bins[1]['mean_q']) and bins[7]['success'] == 0.5
  # |0.7 - 0.5| * 2/5 + |0.3 - 1| / 5 + 0 + 0 = 0.22
  assert calibration(records)['ece'] == pytest.approx(0.22, abs=1e-6)
  p = precision_at_choice(records, 'analytic')
  assert p['no_grasp'] == 1 and p['all']['chosen'] == 5 and p['suction']['precision'] == pytest.approx(3 / 5)
  assert p['parallel_jaw']['chosen'] == 0 and math.isnan(p['parallel_jaw']['precision'])
  assert set(choice_summary(records)) == {'analytic'}  # physics judged only the attempt without a grasp
  with pytest.raises(ValueError, match='bins'):
    calibration(records, bins=0)


def test_precision_at_choice_per_gripper_with_wilson_intervals():
  records = _choices(1)
  p = precision_at_choice(records, 'physics')
  for g in ('parallel_jaw', 'suction'):
    rows = [r for r in records if r['gripper'] == g]
    k = sum(r['physics'] for r in rows)
    assert p[g]['chosen'] == len(rows) and p[g]['successes'] == k
    assert p[g]['wilson_95'] == pytest.approx(list(wilson_interval(k, len(rows))))
    assert p[g]['mean_q'] == pytest.approx(np.mean([r['q'] for r in rows]))
  assert p['all']['chosen'] == 400 and p['all']['precision'] == pytest.approx(np.mean([r['physics'] for r in records]))


def test_cleared_fraction_and_repeated_attempts():
  c = lambda x: [x, 0.0, 0.05]
  records = [_record('a', 1, 'cube', False, center=c(0.0)), _record('a', 1, 'cube', False, center=c(0.005)),
             _record('a', 1, 'cube', False, center=c(0.005), gripper='parallel_jaw'),  # another gripper
             _record('a', 1, 'cube', True, center=c(0.02)), _record('a', 1, 'cube', False, center=c(0.0049)),
             _record('a', 1, 'box', True, trial=1, start=4, center=c(0.0)),  # another trial: no memory of trial 0
             _record('a', 1, 'box', True, trial=1, start=4, center=c(0.0))]  # after a success: not a repeat
  assert repeated_attempts(records) == [False, True, False, False, True, False, False]
  assert repeated_attempts(records, radius=0.001) == [False, False, False, False, True, False, False]
  out = summarize(records)['a']
  assert out['repeated_attempts'] == 2
  assert out['cleared'] == pytest.approx((1 / 10 + 2 / 4) / 2)  # the mean over trials
  assert math.isnan(cleared_fraction([]))


def test_attempt_log_appends_whole_lines_drops_a_torn_last_one_and_rejects_damage(tmp_path):
  path = tmp_path / 'attempts.jsonl'
  assert read_attempts(path) == []
  append_attempt(path, {'trial': 0, 'attempt': 0, 'q': np.float32(0.5), 'pose': np.arange(3.0), 'x': float('nan')})
  append_attempt(path, {'trial': 0, 'attempt': 1})
  assert read_attempts(path) == [{'attempt': 0, 'pose': [0.0, 1.0, 2.0], 'q': 0.5, 'trial': 0, 'x': None},
                                 {'attempt': 1, 'trial': 0}]
  whole = path.read_bytes()
  with open(path, 'ab') as f:  # a kill in the middle of the third record
    f.write(b'{"trial": 0, "att')
  assert len(read_attempts(path)) == 2 and path.read_bytes() != whole
  assert len(read_attempts(path, repair=True)) == 2 and path.read_bytes() == whole
  append_attempt(path, {'trial': 0, 'attempt': 2})
  assert [r['attempt'] for r in read_attempts(path)] == [0, 1, 2]
  path.write_bytes(whole.replace(b'"attempt": 1', b'"attempt": 1,,'))
  with pytest.raises(AttemptLogError, match=r'attempts.jsonl: line 2: expected one JSON object'):
    read_attempts(path)
  path.write_text(json.dumps([1, 2]) + '\n')
  with pytest.raises(AttemptLogError, match='line 1'):
    read_attempts(path)
