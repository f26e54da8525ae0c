"""What a keyframe reports as switched: each association that changed over the keyframe, once,
and not one that refine's rounds switched away and back (the Rerun event "switched from L25 to
L25" on indoor-tags seed 2, noise x4, at pose 289)."""

from __future__ import annotations

import numpy as np

from pipeline.backend.hypotheses import AssociationRecord
from pipeline.backend.methods.base import AssociationMethod
from pipeline.backend.slam import Backend
from pipeline.config import load_config
from pipeline.log.messages import Detection, Odometry

COVARIANCE = tuple(np.diag([1e-4, 1e-4, 1e-2]).ravel())


class Scripted(AssociationMethod):
    """Pose 0's two detections make landmarks 0 and 1; every later detection is a record over
    both, first on landmark 0. `script[pose]` lists the switches refine makes after that pose's
    update: (pose of the record, component it goes to), in order."""

    def __init__(self, context, script: dict[int, list[tuple[int, int]]]):
        super().__init__(context)
        self.script = script
        self.by_pose: dict[int, AssociationRecord] = {}

    def associate(self, m, candidates, keyframe) -> AssociationRecord:
        self.pose = m.pose_index
        if m.pose_index == 0:
            return self.new_landmark(m, keyframe)
        record = AssociationRecord(m, [0, 1], np.array([0.5, 0.5]), active=0)
        self.by_pose[m.pose_index] = record
        return record

    def refine(self, moved) -> list[AssociationRecord]:
        pose = self.pose
        switched = []
        for record_pose, component in self.script.get(pose, []):
            record = self.by_pose[record_pose]
            record.active = component
            record.switches += 1
            switched.append(record)
        return switched


def detection(bearing: float) -> Detection:
    return Detection(0, 0.9, bearing, 0.0, 5.0, COVARIANCE, "apriltag")


def switched(report) -> list[tuple[int, int]]:
    """(pose, landmark) of each switched record, as it stands when the keyframe is done."""
    return [(r.measurement.pose_index, r.landmark_id) for r in report.switched]


def run(script: dict[int, list[tuple[int, int]]], num_poses: int = 5):
    """The back-end and, per keyframe, what it reported as switched."""
    backend = Backend(load_config(), np.eye(2), "ml")
    backend.method = Scripted(backend.context, script)
    odometry_covariance = tuple(np.diag([1e-4] * 3 + [1e-3] * 3).ravel())
    reports = [switched(backend.add_keyframe(None, [detection(0.3), detection(-0.3)]))]
    for i in range(1, num_poses):
        step = Odometry(i, i - 1, i, (0.1, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), odometry_covariance)
        reports.append(switched(backend.add_keyframe(step, [detection(0.3)])))
    return backend, reports


def test_a_switch_away_and_back_within_a_keyframe_is_no_switch():
    # at pose 2, pose 1's record goes to landmark 1 and back to 0: nothing changed
    backend, reports = run({2: [(1, 1), (1, 0)]})
    assert reports[2] == []
    assert backend.switches == 0


def test_each_change_is_reported_once_with_its_final_landmark():
    # pose 2: 0 -> 1 -> 0 -> 1 is one change; pose 3: pose 2's own record and pose 1's back
    backend, reports = run({2: [(1, 1), (1, 0), (1, 1)], 3: [(2, 1), (1, 0), (3, 1)]})
    assert reports[2] == [(1, 1)]
    assert reports[3] == [(2, 1), (1, 0), (3, 1)]
    assert backend.switches == 4
    assert reports[:2] + reports[4:] == [[], [], []]


def test_a_keyframe_own_record_that_returns_to_its_first_choice_is_no_switch():
    backend, reports = run({3: [(3, 1), (3, 0)], 4: [(4, 1)]})
    assert reports[3] == []
    assert reports[4] == [(4, 1)]
    assert backend.switches == 1
