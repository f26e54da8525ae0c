"""`mmslam inspect`: what a log holds, and whether it is valid.

One streaming pass, so memory stays bounded whatever the log's length: the report keeps counts,
never messages. After the first problem the pass goes on counting, so the topic counts are
the file's whole.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

from pipeline.errors import LogError
from pipeline.log import schemas
from pipeline.log.mcap_stream import McapFile
from pipeline.log.messages import METADATA_NAME
from pipeline.log.reader import log_metadata
from pipeline.log.validate import LogValidator


class _Counts:
    """What the report says of a log's messages, counted as they stream past."""

    def __init__(self) -> None:
        self.detections = 0
        self.by_source: Counter[str] = Counter()
        self.by_class: Counter[int] = Counter()
        self.with_relative_pose = 0
        self.with_truth = 0
        self.ground_truth_poses = 0
        self.ground_truth_landmarks = 0
        self.calibration = False
        self.images: Counter[str] = Counter()

    def add(self, topic: str, msg: Any) -> None:
        if topic == schemas.DETECTIONS:
            for d in msg.detections:
                self.detections += 1
                self.by_source[d.source] += 1
                self.by_class[d.class_id] += 1
                self.with_relative_pose += d.relative_pose is not None
                self.with_truth += d.truth_landmark_id is not None
        elif topic == schemas.GT_POSE:
            self.ground_truth_poses += 1
        elif topic == schemas.GT_LANDMARKS:
            self.ground_truth_landmarks = len(msg.landmarks)
        elif topic == schemas.CALIBRATION:
            self.calibration = True
        elif topic in schemas.IMAGE_TOPICS:
            self.images[topic] += 1


def inspect_log(path: str | Path) -> dict[str, Any]:
    """A report of the log; `valid` is False and `problem` the one-line reason when it is not."""
    report: dict[str, Any] = {"path": str(path), "kind": "log", "valid": False, "problem": None}
    counts = _Counts()
    problem = None  # the first, in reading order: the one `replay` stops at
    try:
        with McapFile(path) as mcap:
            validator = None
            try:
                validator = LogValidator(mcap.path, log_metadata(mcap))
            except LogError as exc:
                problem = str(exc)
            for channel, index, log_time, data in mcap.messages():
                if problem is None and validator is not None:
                    try:
                        msg = validator.message(channel, index, log_time, data)
                    except LogError as exc:
                        problem = str(exc)
                        continue
                    counts.add(channel.topic, msg)
            if problem is None and validator is not None:
                try:
                    validator.finish(mcap.channels.values())
                except LogError as exc:
                    problem = str(exc)
    except LogError as exc:  # the container is broken (maybe past a problem already found)
        report["problem"] = problem if problem is not None else str(exc)
        return report
    report["topics"] = {
        topic: {
            "schema": info.schema_name,
            "schema_encoding": info.schema_encoding,
            "message_encoding": info.message_encoding,
            "messages": info.count,
        }
        for topic, info in sorted(mcap.topics.items())
    }
    stamps = [
        t for info in mcap.topics.values() for t in (info.first_ns, info.last_ns) if t is not None
    ]
    report["time_span_s"] = (max(stamps) - min(stamps)) / 1e9 if stamps else 0.0
    report["metadata"] = next((r for n, r in mcap.metadata if n == METADATA_NAME), None)
    if validator is None:  # no log's metadata: perhaps mmslam's estimate for Foxglove
        from pipeline.foxglove.replay_file import ESTIMATE_METADATA, summarise_estimate

        if any(name == ESTIMATE_METADATA for name, _ in mcap.metadata):
            report.update(kind="estimate", valid=True, estimate=summarise_estimate(path))
            return report
    if problem is not None:
        report["problem"] = problem
        return report
    assert validator is not None
    names = validator.metadata.class_names
    report.update(
        valid=True,
        poses=validator.num_poses,
        detections=counts.detections,
        detections_by_source=dict(sorted(counts.by_source.items())),
        detections_by_class={names[c]: n for c, n in sorted(counts.by_class.items())},
        detections_with_relative_pose=counts.with_relative_pose,
        detections_with_truth=counts.with_truth,
        ground_truth_poses=counts.ground_truth_poses,
        ground_truth_landmarks=counts.ground_truth_landmarks,
        calibration=counts.calibration,
        images=dict(counts.images),
    )
    return report


def render_text(report: dict[str, Any]) -> str:
    lines = [f"log: {report['path']}"]
    if "topics" in report:
        lines.append(f"time span: {report['time_span_s']:.3f} s")
        lines.append("topics:")
        width = max([28, *(len(topic) for topic in report["topics"])])
        for topic, info in report["topics"].items():
            lines.append(f"  {topic:<{width}} {info['schema']:<28} {info['messages']:>7} messages")
        if report.get("metadata"):
            lines.append("metadata:")
            lines += [f"  {k}: {v}" for k, v in sorted(report["metadata"].items())]
    if report["kind"] == "estimate":
        e = report["estimate"]
        lines += [
            f"an estimate: `mmslam replay --mcap` with method {e['method']}, for Foxglove "
            "beside its log (not a detection log: replay and the other commands read logs)",
            f"poses: {e['poses']}",
            f"landmarks: {e['landmarks']}",
            f"keyframes with associations: {e['keyframes']}",
            f"events: {e['switches']} switches, {e['null_wins']} null-hypothesis wins",
        ]
        if e["result"]:
            lines.append(f"result: {e['result']}")
        lines.append("valid: yes (an estimate)")
    elif report["valid"]:
        lines.append(f"poses: {report['poses']}")
        lines.append(f"detections: {report['detections']}")
        for key in ("detections_by_source", "detections_by_class"):
            parts = ", ".join(f"{k} {v}" for k, v in report[key].items())
            lines.append(f"  by {key.split('_by_')[1]}: {parts or '-'}")
        lines.append(f"  with relative pose: {report['detections_with_relative_pose']}")
        lines.append(f"  with truth landmark id: {report['detections_with_truth']}")
        lines.append(
            f"ground truth: {report['ground_truth_poses']} poses, "
            f"{report['ground_truth_landmarks']} landmarks"
        )
        lines.append(f"calibration: {'yes' if report['calibration'] else 'no'}")
        if report["images"]:
            lines.append("images: " + ", ".join(f"{k} {v}" for k, v in report["images"].items()))
        lines.append("valid: yes")
    else:
        lines.append(f"valid: no ({report['problem']})")
    return "\n".join(lines)
