"""Long logs, for measuring what a log's length costs: a log chained to itself end to end.

Copy c of the source log starts where copy c - 1 ended: its odometry continues the pose
indices, its stamps follow on, and its ground truth (poses and landmarks) is the source's moved
to where copy c starts. Each copy sees landmarks of its own (ids shifted past the previous
copy's), so the chained log is a valid, longer drive with ground truth, for every method.

    python -m data_tools.long_log LOG.mcap --poses 50000 --out LONG.mcap
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.foxglove.log_topics import foxglove_mirror
from pipeline.geometry import quaternion_from_rotation
from pipeline.log import (
    DetectionLog,
    Detections,
    GroundTruthLandmarks,
    GroundTruthPose,
    LogWriter,
    Odometry,
    read_log,
)
from pipeline.log.messages import Detection


def _matrix(translation, rotation) -> np.ndarray:
    """A 4x4 pose from a translation and an [x, y, z, w] quaternion."""
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(rotation).as_matrix()
    T[:3, 3] = translation
    return T


def _pose_parts(T: np.ndarray) -> tuple[tuple[float, ...], tuple[float, ...]]:
    q = quaternion_from_rotation(T[:3, :3])
    return tuple(float(v) for v in T[:3, 3]), tuple(float(v) for v in q)


def _copies(source: DetectionLog, poses: int) -> int:
    per_copy = source.num_poses - 1  # the first pose of a copy is the last of the one before
    return max(1, -(-(poses - 1) // per_copy))


def chained(source: DetectionLog, poses: int) -> Iterator[Any]:
    """The messages of `source` chained until the log has at least `poses` poses, in log order
    (the ground-truth landmarks of every copy first)."""
    if not source.odometry or not source.has_ground_truth:
        raise ValueError("the source log needs odometry and ground-truth poses")
    gt = {m.pose_index: _matrix(m.translation, m.rotation) for m in source.ground_truth_poses}
    last = source.num_poses - 1
    if 0 not in gt or last not in gt:
        raise ValueError("the source log needs the ground truth of its first and last poses")
    step = np.linalg.inv(gt[0]) @ gt[last]  # a copy's start to its end
    stamps = source.pose_stamps_ns()
    span = stamps[-1] - stamps[0] + (stamps[-1] - stamps[-2])
    landmarks = source.ground_truth_landmarks.landmarks if source.ground_truth_landmarks else ()
    id_shift = max((lm.id for lm in landmarks), default=0) + 1
    copies = _copies(source, poses)
    starts = [gt[0] @ np.linalg.matrix_power(step, c) @ np.linalg.inv(gt[0]) for c in range(copies)]
    moved = []
    for c, start in enumerate(starts):
        for lm in landmarks:
            position = start @ np.append(lm.position, 1.0)
            moved.append(
                dataclasses.replace(lm, id=lm.id + c * id_shift, position=tuple(position[:3]))
            )
    yield GroundTruthLandmarks(stamps[0], tuple(moved))
    by_pose: dict[int, list[Detection]] = {}
    for message in source.detections:
        by_pose.setdefault(message.pose_index, []).extend(message.detections)
    for c, start in enumerate(starts):
        offset, later = c * last, c * span

        def shifted(detection: Detection, c: int = c) -> Detection:
            truth = detection.truth_landmark_id
            if truth is not None and truth >= 0:
                truth += c * id_shift
            return dataclasses.replace(detection, truth_landmark_id=truth)

        for k in range(1 if c else 0, source.num_poses):
            stamp = stamps[k] + later
            if k:
                odometry = source.odometry[k - 1]
                yield dataclasses.replace(
                    odometry, stamp_ns=stamp, from_index=offset + k - 1, to_index=offset + k
                )
            if k in gt:
                translation, rotation = _pose_parts(start @ gt[k])
                yield GroundTruthPose(stamp, offset + k, translation, rotation)  # type: ignore[arg-type]
            yield Detections(stamp, offset + k, tuple(shifted(d) for d in by_pose.get(k, [])))


def write_long_log(source: Path, out: Path, poses: int) -> int:
    """Write `source` chained to at least `poses` poses to `out`; returns the poses written."""
    log = read_log(source)
    count = 0
    metadata = dataclasses.replace(log.metadata, source=f"{log.metadata.source}; chained")
    with LogWriter(out, metadata, foxglove_mirror) as writer:
        for message in chained(log, poses):
            writer.write(message)
            count += isinstance(message, Odometry)
    return count + 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", type=Path, metavar="LOG.mcap")
    parser.add_argument("--poses", type=int, required=True)
    parser.add_argument("--out", type=Path, required=True, metavar="LONG.mcap")
    args = parser.parse_args(argv)
    written = write_long_log(args.source, args.out, args.poses)
    print(f"{args.out}: {written} poses")
    return 0


if __name__ == "__main__":
    sys.exit(main())
