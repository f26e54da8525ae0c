"""`mmslam export`: a log's ground truth in the formats other tools read: the trajectory as
TUM (evo's `--ref`) and the landmarks as CSV."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline import outputs
from pipeline.errors import InputError
from pipeline.geometry import rotation_from_quaternion
from pipeline.log import DetectionLog, read_log

LANDMARKS_HEADER = "id,x,y,z,class_id"


def ground_truth_tum(log: DetectionLog) -> str:
    """The ground-truth poses as TUM lines, stamped like the replay's `trajectory.tum`."""
    if not log.has_ground_truth:
        raise InputError("the log has no /ground_truth/pose messages")
    stamps = log.pose_stamps_ns()
    poses = []
    for message in log.ground_truth_poses:
        pose = np.eye(4)
        pose[:3, :3] = rotation_from_quaternion(np.asarray(message.rotation, float))
        pose[:3, 3] = message.translation
        poses.append(pose)
    return outputs.trajectory_tum([stamps[m.pose_index] for m in log.ground_truth_poses], poses)


def ground_truth_landmarks_csv(log: DetectionLog) -> str:
    if log.ground_truth_landmarks is None:
        raise InputError("the log has no /ground_truth/landmarks message")
    lines = [LANDMARKS_HEADER]
    for landmark in log.ground_truth_landmarks.landmarks:
        x, y, z = landmark.position
        lines.append(f"{landmark.id},{x:.6f},{y:.6f},{z:.6f},{landmark.class_id}")
    return "\n".join(lines) + "\n"


def export_ground_truth(
    log_path: str | Path, trajectory: Path | None = None, landmarks: Path | None = None
) -> list[Path]:
    """Write what is asked of the log's ground truth (under temporary names, renamed into place
    once all are complete). Returns the files written."""
    if trajectory is None and landmarks is None:
        raise InputError("nothing to export: give --ground-truth FILE.tum or --landmarks FILE.csv")
    log = read_log(log_path)
    texts: dict[Path, str] = {}
    try:
        if trajectory is not None:
            texts[Path(trajectory)] = ground_truth_tum(log)
        if landmarks is not None:
            texts[Path(landmarks)] = ground_truth_landmarks_csv(log)
    except InputError as exc:
        raise InputError(f"{log_path}: {exc}") from None
    for path in texts:
        if path.is_dir():
            raise InputError(f"{path}: is a directory, expected a file name")
    files: list[outputs.AtomicFile] = []
    try:
        for path, text in texts.items():
            files.append(outputs.AtomicFile(path, "w", encoding="utf-8", newline=""))
            files[-1].file.write(text)
        for out in files:
            out.commit()
    except BaseException:
        for out in files:
            out.discard()
        raise
    return list(texts)
