"""The log reader (`log/reader.py`): the ground-truth poses in pose order whatever their order
in the file (a log may state several at one stamp, in any order), the images counted per
topic, kept or not, and a bad `mmslam` metadata record named as such."""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader

from pipeline.errors import LogError
from pipeline.log import read_log, schemas
from pipeline.log.metadata import metadata_record
from tests.fuzz_logs import METADATA, _messages_of, _with, _with_metadata


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


def test_images_are_counted_per_topic_whether_kept_or_not(tmp_path):
    path = tmp_path / "log.mcap"
    path.write_bytes(_with(lambda spec: None))
    with path.open("rb") as f:
        topics = [channel.topic for _, channel, _ in make_reader(f).iter_messages()]
    expected = {t: topics.count(t) for t in set(topics) if t.startswith("/camera/")}
    assert expected and all(n > 0 for n in expected.values())
    assert read_log(path).image_counts == expected
    assert read_log(path, load_images=True).image_counts == expected


def test_a_bad_mmslam_metadata_record_is_named(tmp_path):
    record = {**metadata_record(METADATA), "num_classes": "0"}
    path = tmp_path / "log.mcap"
    path.write_bytes(_with_metadata([("mmslam", record)]))
    with pytest.raises(LogError, match=r"bad log .*log\.mcap: metadata 'mmslam': "):
        read_log(path)
