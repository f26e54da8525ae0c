"""`mmslam inspect`: what a log holds, and whether it is valid."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

from pipeline.errors import LogError
from pipeline.log import decode_log, scan_log
from pipeline.log.messages import METADATA_NAME


def inspect_log(path: str | Path) -> dict[str, Any]:
    """A report of the log; `valid` is False and `problem` the one-line reason when it is not."""
    report: dict[str, Any] = {"path": str(path), "valid": False, "problem": None}
    try:
        raw = scan_log(path)
    except LogError as exc:
        report["problem"] = str(exc)
        return report
    report["topics"] = {
        topic: {
            "schema": info.schema_name,
            "schema_encoding": info.schema_encoding,
            "message_encoding": info.message_encoding,
            "messages": info.count,
        }
        for topic, info in sorted(raw.topics.items())
    }
    stamps = [
        t for info in raw.topics.values() for t in (info.first_ns, info.last_ns) if t is not None
    ]
    report["time_span_s"] = (max(stamps) - min(stamps)) / 1e9 if stamps else 0.0
    report["metadata"] = raw.metadata.get(METADATA_NAME)
    try:
        log = decode_log(raw)
    except LogError as exc:
        report["problem"] = str(exc)
        return report
    detections = [d for message in log.detections for d in message.detections]
    names = log.metadata.class_names
    report.update(
        valid=True,
        poses=log.num_poses,
        detections=len(detections),
        detections_by_source=dict(sorted(Counter(d.source for d in detections).items())),
        detections_by_class={
            names[c]: n for c, n in sorted(Counter(d.class_id for d in detections).items())
        },
        detections_with_relative_pose=sum(d.relative_pose is not None for d in detections),
        detections_with_truth=sum(d.truth_landmark_id is not None for d in detections),
        ground_truth_poses=len(log.ground_truth_poses),
        ground_truth_landmarks=(
            len(log.ground_truth_landmarks.landmarks) if log.ground_truth_landmarks else 0
        ),
        calibration=log.calibration is not None,
        images=log.image_counts,
    )
    return report


def render_text(report: dict[str, Any]) -> str:
    lines = [f"log: {report['path']}"]
    if "topics" in report:
        lines.append(f"time span: {report['time_span_s']:.3f} s")
        lines.append("topics:")
        for topic, info in report["topics"].items():
            lines.append(f"  {topic:<28} {info['schema']:<28} {info['messages']:>7} messages")
        if report.get("metadata"):
            lines.append("metadata:")
            lines += [f"  {k}: {v}" for k, v in sorted(report["metadata"].items())]
    if report["valid"]:
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
