"""The log reader gives the ground-truth poses in pose order, whatever their order in the file:
a log may state several at one stamp (a writer that adds them at the end), in any order."""

from __future__ import annotations

import numpy as np

from pipeline.log import read_log, schemas
from tests.fuzz_logs import _messages_of, _with


def test_ground_truth_poses_at_one_stamp_in_any_order_are_read_in_pose_order(tmp_path):
    def shuffled(spec):
        poses = _messages_of(spec, schemas.GT_POSE)
        last = max(m[2] for m in poses)
        order = [3, 0, 4, 2, 1]  # pose indices in the file
        for message in poses:
            spec.messages.remove(message)
        for k in order:
            message = next(m for m in poses if m[1]["pose_index"] == k)
            message[1] = {**message[1], "stamp_ns": last}
            spec.messages.append([message[0], message[1], last])

    path = tmp_path / "log.mcap"
    path.write_bytes(_with(shuffled))
    log = read_log(path)
    assert [m.pose_index for m in log.ground_truth_poses] == [0, 1, 2, 3, 4]
    translations = [m.translation for m in log.ground_truth_poses]
    original = tmp_path / "original.mcap"
    original.write_bytes(_with(lambda spec: None))
    expected = [m.translation for m in read_log(original).ground_truth_poses]
    np.testing.assert_allclose(translations, expected, atol=1e-12)
