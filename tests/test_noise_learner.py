"""The noise learner's policy (`noise/learner.py`): at which keyframes the estimators are fed,
with what (which keyframes' detections, which poses and joint covariance a drift window is read
from, which scales are in use), when they are read, and what a move changes. The estimators'
own arithmetic is test_noise.py's; here they are checked against a second DriftWindows fed by
hand, and their readings stood in for where the policy alone decides."""

import dataclasses

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import X

from pipeline.backend.noise import learner as learner_module
from pipeline.backend.noise.components import Reading
from pipeline.backend.noise.drift import DriftWindows
from pipeline.backend.noise.learner import HeldDetections, NoiseLearner
from pipeline.backend.noise.scales import NoiseScales
from pipeline.config import load_config

STATED = np.diag([1e-4, 2e-4, 3e-4, 1e-2, 2e-2, 3e-2])  # an odometry step's covariance


def noise_config(**values):
    """[noise] with every keyframe's learning due each `update_every` (4) keyframes, windows of
    4 and 8, and one observation enough to read an estimator."""
    settings = {
        "estimate": True,
        "update_every": 4,
        "drift_window": 4,
        "long_drift_window": 8,
        "min_drift_windows": 1,
        "min_contrasts": 1,
        "drift_windows": 20,
        "contrasts": 20,
    }
    return dataclasses.replace(load_config().noise, **{**settings, **values})


def true_pose(k: int) -> gtsam.Pose3:
    """Keyframe k of a gently curving path, a metre a keyframe."""
    return gtsam.Pose3(gtsam.Rot3.Ypr(0.05 * k, 0.01 * k, 0.0), np.array([k, 0.02 * k * k, 0.0]))


def odometry(seed: int, n: int) -> list[gtsam.Pose3]:
    """The steps from keyframe k - 1 to k, k = 1..n, each off the true path's by a little."""
    rng = np.random.default_rng(seed)
    return [
        true_pose(k - 1)
        .between(true_pose(k))
        .compose(gtsam.Pose3.Expmap(0.01 * rng.normal(size=6)))
        for k in range(1, n + 1)
    ]


class Estimate:
    """The estimate the learner reads: the true path, and a joint covariance of two poses that
    depends on which two (so that the wrong ends give another observation). Records every
    key asked."""

    def __init__(self):
        self.poses_asked: list[int] = []
        self.joints_asked: list[list[int]] = []

    def pose(self, key: int) -> gtsam.Pose3:
        self.poses_asked.append(key)
        return true_pose(gtsam.Symbol(key).index())

    def joint_covariance(self, keys: list[int]) -> np.ndarray:
        self.joints_asked.append(list(keys))
        return joint_of(*(gtsam.Symbol(k).index() for k in keys))


def joint_of(*indices: int) -> np.ndarray:
    """A joint covariance of keyframes `indices`, correlated, of their indices: each block
    1e-4 (1 + k), each cross block 0.5e-4 (1 + the earlier k), whatever else is asked with it."""
    n = len(indices)
    joint = np.zeros((6 * n, 6 * n))
    for i, a in enumerate(indices):
        for j, b in enumerate(indices):
            value = 1e-4 * (1 + a) if i == j else 0.5e-4 * (1 + min(a, b))
            joint[6 * i : 6 * i + 6, 6 * j : 6 * j + 6] = value * np.eye(6)
    return joint


def keyframe_detections(k: int) -> HeldDetections:
    """Keyframe k's detections (what they hold is the estimators' business, not checked)."""
    return HeldDetections(
        rotation=true_pose(k).rotation().matrix(),
        translation=true_pose(k).translation(),
        landmarks=np.array([[5.0, 1.0, 0.0], [6.0, -1.0, 0.5], [8.0, 0.0, -0.5]]) + k,
        measured=np.zeros((3, 3)),
        stated=np.broadcast_to(np.eye(3) * 1e-2, (3, 3, 3)).copy(),
        sightings=np.array([2, 3, 4]),
    )


class Held:
    """The `held` the learner is given: each keyframe's detections, the ranges asked kept."""

    def __init__(self):
        self.asked: list[range] = []

    def __call__(self, keyframes: range) -> list[HeldDetections]:
        self.asked.append(keyframes)
        return [keyframe_detections(k) for k in keyframes]


@pytest.fixture
def contrasts_seen(monkeypatch):
    """Every call of contrast_observation the learner makes: its keyframe's translation, the
    scales in use and the free directions; each an observation of its own."""
    calls = []
    real = learner_module.contrast_observation

    def spy(rotation, translation, landmarks, measured, stated, sightings, used, free):
        calls.append((np.array(translation), np.array(used), np.array(free)))
        return real(rotation, translation, landmarks, measured, stated, sightings, used, free)

    monkeypatch.setattr(learner_module, "contrast_observation", spy)
    return calls


def test_a_planar_log_s_pose_is_free_in_yaw_and_horizontally_only(contrasts_seen):
    for planar, free in (
        (False, [True] * 6),
        (True, [False, False, True, True, True, False]),  # roll pitch yaw, x y z
    ):
        learner = NoiseLearner(noise_config(), enabled=True, planar=planar)
        learner.learn(4, Estimate(), Held())
        assert [f.tolist() for _, _, f in contrasts_seen] == [free] * 5
        contrasts_seen.clear()


def test_learning_is_due_every_update_every_keyframes_each_keyframe_seen_once(contrasts_seen):
    learner = NoiseLearner(noise_config(), enabled=True)
    held = Held()
    for k in range(1, 13):
        learner.learn(k, Estimate(), held)
    # keyframes 0..4 at 4, then 5..8 at 8 and 9..12 at 12: each once, the current one included
    assert held.asked == [range(0, 5), range(5, 9), range(9, 13)]
    seen = [float(t[0]) for t, _, _ in contrasts_seen]
    assert seen == pytest.approx(list(range(13)))


@pytest.mark.parametrize(("estimate", "enabled"), [(False, True), (True, False)])
def test_nothing_is_learnt_unless_asked_and_the_method_learns(contrasts_seen, estimate, enabled):
    learner = NoiseLearner(noise_config(estimate=estimate), enabled=enabled)
    held, reader = Held(), Estimate()
    for k in range(1, 9):
        assert not learner.learn(k, reader, held)
    assert held.asked == [] and reader.poses_asked == [] and contrasts_seen == []
    assert not learner.watches_drift


def test_contrasts_are_taken_at_the_detections_scales_in_use(contrasts_seen):
    learner = NoiseLearner(noise_config(), enabled=True)
    learner.scales = NoiseScales((2.0, 3.0, 5.0, 7.0, 11.0, 13.0), (0.5, 4.0, 9.0))
    learner.learn(4, Estimate(), Held())
    assert len(contrasts_seen) == 5
    for _, used, _ in contrasts_seen:
        np.testing.assert_allclose(used, [0.5, 4.0, 9.0])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_each_window_is_read_from_its_ends_poses_and_joint(monkeypatch, seed):
    """At keyframe 8 every open window is read again (the short one of keyframe 4, and both due
    now: 4 and 8): each the same observation as a second DriftWindows makes from the window's
    own poses, the joint of its two ends and the odometry's scales in use; the poses are read
    once, from the earliest window's first, and the joint of all the windows' ends once."""
    steps = odometry(seed, 8)
    learner = NoiseLearner(noise_config(), enabled=True)
    learner.scales = NoiseScales((2.0, 1.0, 3.0, 1.0, 0.5, 1.0), (1.0, 1.0, 1.0))
    read = []
    monkeypatch.setattr(learner.windows, "replace", read.append)
    reader = Estimate()
    for k, step in enumerate(steps, start=1):
        learner.add_step(step, STATED)
        if k < 8:
            learner.learn(k, reader, lambda _: [])
    reader.poses_asked.clear()
    reader.joints_asked.clear()
    learner.learn(8, reader, lambda _: [])
    assert reader.poses_asked == [X(k) for k in range(0, 9)]
    windows = [(0, 4), (4, 8), (0, 8)]
    assert reader.joints_asked == [[X(0), X(4), X(8)]]
    by_hand = DriftWindows(4, 8)
    for step in steps:
        by_hand.add_step(step, STATED)
    used = np.array([2.0, 1.0, 3.0, 1.0, 0.5, 1.0])
    assert len(read[-1]) == len(windows)
    for observation, (first, last) in zip(read[-1], windows, strict=True):
        poses = [true_pose(k) for k in range(first, last + 1)]
        expected = by_hand.observe(first, poses, joint_of(first, last), used)
        np.testing.assert_allclose(observation.y, expected.y, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(observation.rest, expected.rest, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(observation.basis, expected.basis, rtol=1e-9, atol=1e-12)
        assert observation.outlier == pytest.approx(expected.outlier, rel=1e-9)


class Readings:
    """Stands in for an estimator's `reading`: the scales it returns in turn (None: stay), and
    the `current` scales it was asked about."""

    def __init__(self, *scales):
        self.scales = list(scales)
        self.asked: list[np.ndarray] = []

    def __call__(self, current, bounds, min_evidence, deadband, drop, tested=None):
        self.asked.append(np.array(current))
        after = self.scales.pop(0)
        evidence = np.full(len(current), 7.0)
        return Reading(None if after is None else np.array(after), np.array(current), evidence)


def test_an_estimator_is_read_once_it_has_enough_observations_and_only_when_new(
    monkeypatch, contrasts_seen
):
    learner = NoiseLearner(noise_config(min_contrasts=6, drift_window=100), enabled=True)
    readings = Readings(None, None)
    monkeypatch.setattr(learner.contrasts, "reading", readings)
    held = Held()
    learner.learn(4, Estimate(), held)  # five keyframes: one short of min_contrasts
    assert readings.asked == []
    learner.learn(8, Estimate(), held)  # nine
    assert len(readings.asked) == 1
    learner.learn(12, Estimate(), lambda _: [])  # nothing new: not read again
    assert len(readings.asked) == 1
    learner.learn(16, Estimate(), held)
    assert len(readings.asked) == 2


def learn_with(monkeypatch, learner, odometry_after, measurement_after, seed, pose_index):
    """The learner's next reading, its estimators standing in to return these scales."""
    monkeypatch.setattr(learner.windows, "reading", Readings(odometry_after))
    monkeypatch.setattr(learner.contrasts, "reading", Readings(measurement_after))
    for step in odometry(seed, 4):
        learner.add_step(step, STATED)
    return learner.learn(pose_index, Estimate(), Held())


def test_a_move_changes_its_own_scales_and_is_recorded(monkeypatch, contrasts_seen):
    learner = NoiseLearner(noise_config(drift_window=4, long_drift_window=0), enabled=True)
    odometry_after = (1.0, 1.0, 4.0, 1.0, 1.0, 1.0)
    change = learn_with(monkeypatch, learner, odometry_after, None, 3, 4)
    assert change.odometry and not change.measurement
    assert learner.scales.odometry == pytest.approx(odometry_after)
    assert learner.scales.measurement == pytest.approx((1.0, 1.0, 1.0))
    (move,) = learner.moves
    assert (move.pose_index, move.source) == (4, "drift windows")
    assert move.before == pytest.approx((1.0,) * 6) and move.after == pytest.approx(odometry_after)
    assert move.evidence == pytest.approx((7.0,) * 6)

    measurement_after = (2.0, 1.0, 0.25)
    change = learn_with(monkeypatch, learner, None, measurement_after, 4, 8)
    assert change.measurement and not change.odometry
    assert learner.scales.odometry == pytest.approx(odometry_after)
    assert learner.scales.measurement == pytest.approx(measurement_after)
    assert [m.source for m in learner.moves] == ["drift windows", "detections"]
    assert learner.moves[-1].names == ("bearing", "elevation", "range")
