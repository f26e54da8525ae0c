"""DC-SAM's discrete step in a group too large for the exact solve (`discrete_step.py`): by
turns, the classes follow the reports of the detections the associations give each landmark;
and a group of exactly `exact_class_variables` landmarks is still solved exactly."""

import numpy as np

from pipeline.backend.methods.dcsam import discrete_step
from pipeline.backend.methods.dcsam.discrete_step import DetectionModes, by_turns

CONFUSION = np.array([[0.9, 0.1], [0.1, 0.9]])  # row: true class; column: reported


def reporting(landmark: int, reported: int) -> DetectionModes:
    """A detection sure of `landmark` (cost 0 against 10 for a new one and the null)."""
    return DetectionModes(np.array([0.0, 10.0, 10.0]), (landmark, None), CONFUSION[:, reported])


def test_by_turns_a_landmark_s_class_follows_the_reports_it_is_given():
    """Landmark 7's own evidence leans to class 0 (log 0.6 against log 0.4); three detections
    it holds report class 1: its class is 1."""
    evidence = {7: np.log([0.6, 0.4])}
    modes, classes = by_turns([reporting(7, 1) for _ in range(3)], evidence)
    assert modes == [0, 0, 0]
    assert classes == {7: 1}
    # and with reports of class 0, class 0
    assert by_turns([reporting(7, 0) for _ in range(3)], evidence)[1] == {7: 0}


def test_a_group_of_exactly_the_limit_is_solved_exactly(monkeypatch):
    calls = []

    def spy(members, evidence):
        calls.append(len(members))
        return [0] * len(members), {j: 0 for j in evidence}

    monkeypatch.setattr(discrete_step, "by_turns", spy)
    detections = [reporting(j, j % 2) for j in range(3)]
    for j in range(2):  # one group: detections linked through landmarks they may both take
        detections.append(
            DetectionModes(np.array([0.0, 1.0, 10.0, 10.0]), (j, j + 1, None), CONFUSION[:, 0])
        )
    evidence = {j: np.zeros(2) for j in range(3)}
    discrete_step.solve(detections, evidence, exact_class_variables=3)
    assert calls == []  # three landmarks: exact
    discrete_step.solve(detections, evidence, exact_class_variables=2)
    assert calls == [5]  # more than two: by turns, the group's five detections
