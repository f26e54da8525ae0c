"""`mmslam replay --mcap FILE`: the estimate as Foxglove messages, in an MCAP file of its own
that opens beside the log (both use the frame `world`, pose 0's body frame).

- `/foxglove/estimate/tf` (FrameTransform): `world` to `estimate`, per pose;
- `/foxglove/estimate/pose` (PoseInFrame), per pose; `/foxglove/estimate/path` (PosesInFrame),
  the whole trajectory at the first stamp;
- `/foxglove/estimate/landmarks` (SceneUpdate): a sphere per landmark at its final position,
  coloured and labelled by its MAP class, from the keyframe that first saw it;
- `/foxglove/estimate/associations` (SceneUpdate): per keyframe, a line from the pose to the
  landmark each detection is finally associated with; red to where the detection points
  when the null hypothesis won;
- `/foxglove/estimate/events` (Log): null-hypothesis wins and switches as they happened, and
  the metrics at the end.

The final estimate is known only at the end, so the file is written by `finish`, under a
temporary name renamed into place. Its metadata record `mmslam.estimate` names the method;
`summarise_estimate` reads a file back (`mmslam inspect`).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import foxglove.messages as fg
import numpy as np

from pipeline.backend.hypotheses import NULL
from pipeline.errors import InputError
from pipeline.foxglove import messages as fm
from pipeline.foxglove.channels import FoxgloveChannels
from pipeline.log.writer import mcap_writer
from pipeline.outputs import AtomicFile

if TYPE_CHECKING:
    from pipeline.backend.slam import BackendResult, KeyframeReport
    from pipeline.log.messages import DetectionLog

ESTIMATE = "estimate"
TF = "/foxglove/estimate/tf"
POSE = "/foxglove/estimate/pose"
PATH = "/foxglove/estimate/path"
LANDMARKS = "/foxglove/estimate/landmarks"
ASSOCIATIONS = "/foxglove/estimate/associations"
EVENTS = "/foxglove/estimate/events"
ESTIMATE_METADATA = "mmslam.estimate"  # the file's metadata record: {"method": ...}


def landmark_label(landmark_id: int, class_name: str, probability: float) -> str:
    return f"L{landmark_id} {class_name} {probability:.2f}"


class FoxgloveSink:
    """A results sink (`pipeline/viz/sink.py`) that writes the estimate to an MCAP file."""

    wants_images = False

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if self.path.is_dir():
            raise InputError(f"--mcap {self.path}: is a directory, expected a file name")
        self.stamps: list[int] = []
        self.class_names: tuple[str, ...] = ()
        self.method = ""
        self.events: list[tuple[int, str, bool]] = []  # stamp, text, warning
        self._winners: dict[tuple[int, int], int] = {}

    def start(self, log: DetectionLog, method: str) -> None:
        self.stamps = log.pose_stamps_ns()
        self.class_names = log.metadata.class_names
        self.method = method

    def keyframe(self, report: KeyframeReport, seconds: float) -> None:
        """Null wins and switches, told as they happen (the records change later): every
        switch the back-end counts, an earlier detection's or one of this keyframe's own,
        moved off its first choice by the keyframe's update (that choice is not kept)."""
        stamp = self.stamps[report.pose_index]
        for record in report.switched:
            m = record.measurement
            key = (m.pose_index, m.detection_index)
            previous = self._winners.get(key)
            self._winners[key] = record.landmark_id
            switched = (
                f"switched from {self._name(previous)} to"
                if previous is not None
                else "moved off its first choice by this keyframe's update, to"
            )
            self.events.append(
                (
                    stamp,
                    f"pose {report.pose_index}: detection {m.detection_index} of pose "
                    f"{m.pose_index} {switched} {self._name(record.landmark_id)}",
                    True,
                )
            )
        for record in report.records:
            m = record.measurement
            self._winners[(m.pose_index, m.detection_index)] = record.landmark_id
            if record.landmark_id == NULL:
                self.events.append(
                    (
                        stamp,
                        f"pose {m.pose_index}: detection {m.detection_index} left to the null "
                        "hypothesis",
                        False,
                    )
                )

    @staticmethod
    def _name(landmark_id: int) -> str:
        return "the null hypothesis" if landmark_id == NULL else f"landmark {landmark_id}"

    def finish(self, result: BackendResult, metrics: dict[str, Any] | None) -> None:
        messages = self._messages(result, metrics)
        messages.sort(key=lambda m: m[0])  # stable: in time order, as the log's are
        with AtomicFile(self.path) as out:
            writer = mcap_writer(out.file)
            writer.start(profile="", library="mmslam")
            writer.add_metadata(ESTIMATE_METADATA, {"method": self.method})
            channels = FoxgloveChannels(writer)
            for stamp, topic, message in messages:
                channels.write(topic, stamp, message)
            writer.finish()

    def _messages(
        self, result: BackendResult, metrics: dict[str, Any] | None
    ) -> list[tuple[int, str, Any]]:
        stamps = self.stamps
        poses = [p.matrix() for p in result.poses]
        out: list[tuple[int, str, Any]] = []
        for k, T in enumerate(poses):
            out.append((stamps[k], TF, fm.frame_transform(stamps[k], fm.WORLD, ESTIMATE, T)))
            out.append((stamps[k], POSE, fm.pose_in_frame(stamps[k], fm.pose_of_matrix(T))))
        path = [fm.pose_of_matrix(T) for T in poses]
        out.append((stamps[0], PATH, fm.poses_in_frame(stamps[0], path)))

        positions = {
            i: np.asarray(v.translation() if hasattr(v, "translation") else v, float)
            for i, v in zip(result.landmark_ids, result.landmark_values, strict=True)
        }
        first_seen: dict[int, int] = {}
        by_pose: dict[int, list[Any]] = {}
        for record in result.records:
            m = record.measurement
            by_pose.setdefault(m.pose_index, []).append(record)
            if record.landmark_id != NULL:
                first_seen[record.landmark_id] = min(
                    first_seen.get(record.landmark_id, m.pose_index), m.pose_index
                )
        new_at: dict[int, list[tuple[int, Any, int, str]]] = {}
        for landmark_id, position in positions.items():
            landmark = result.landmarks.landmarks[landmark_id]
            c = int(landmark.map_class)
            probability = float(landmark.class_probabilities[c])
            label = landmark_label(landmark_id, fm.class_name(self.class_names, c), probability)
            new_at.setdefault(first_seen.get(landmark_id, 0), []).append(
                (landmark_id, position, c, label)
            )
        for k, rows in sorted(new_at.items()):
            out.append((stamps[k], LANDMARKS, fm.landmark_update(stamps[k], rows)))

        for k, records in sorted(by_pose.items()):
            T = poses[k]
            segments = []
            for record in records:
                if record.landmark_id == NULL:
                    measured = T[:3, :3] @ record.measurement.body_point + T[:3, 3]
                    segments.append((T[:3, 3], measured, fm.colour(fm.NULL_COLOUR)))
                elif record.landmark_id in positions:
                    c = int(result.landmarks.landmarks[record.landmark_id].map_class)
                    alpha = 0.3 + 0.7 * float(record.weight)
                    segments.append(
                        (T[:3, 3], positions[record.landmark_id], fm.class_colour(c, alpha))
                    )
            entity = fm.lines_entity(stamps[k], "associations", segments)
            out.append((stamps[k], ASSOCIATIONS, fg.SceneUpdate(entities=[entity])))

        for stamp, text, warning in self.events:
            out.append((stamp, EVENTS, fm.event(stamp, text, warning)))
        summary = metrics_summary(self.method, metrics or {})
        if summary:
            out.append((stamps[-1], EVENTS, fm.event(stamps[-1], summary)))
        return out

    def close(self) -> None:
        pass


def metrics_summary(method: str, metrics: dict) -> str | None:
    """The last event's text: the error where the log has ground-truth poses, the association
    counts where its detections carry truth labels; None with neither."""
    parts = []
    if "translation_error_m" in metrics:
        t = metrics["translation_error_m"]
        parts.append(f"translation error rmse {t['rmse']:.3f} m, max {t['max']:.3f} m")
    if "association" in metrics:
        a = metrics["association"]
        parts.append(f"associations {a['correct']} correct, {a['wrong']} wrong, {a['null']} null")
    return f"{method}: " + "; ".join(parts) if parts else None


def summarise_estimate(path: str | Path) -> dict[str, Any]:
    """What an estimate file written by `FoxgloveSink` holds: the method, the poses, the
    landmarks, the keyframes with associations, the switches and null-hypothesis wins told as
    events, and the closing summary (errors and association counts, where the log had truth).
    Messages are decoded with the schemas the file carries."""
    from mcap.reader import make_reader

    counted = {POSE: "poses", ASSOCIATIONS: "keyframes"}
    summary: dict[str, Any] = {"method": None, "poses": 0, "keyframes": 0, "landmarks": 0}
    summary.update(switches=0, null_wins=0, result=None)
    classes: dict[int, Any] = {}
    last_event = None
    with open(path, "rb") as f:
        reader = make_reader(f)
        for record in reader.iter_metadata():
            if record.name == ESTIMATE_METADATA:
                summary["method"] = record.metadata.get("method")
        topics = [POSE, ASSOCIATIONS, LANDMARKS, EVENTS]
        for schema, channel, message in reader.iter_messages(topics=topics):
            if channel.topic in counted:
                summary[counted[channel.topic]] += 1
                continue
            if schema is None:
                continue
            if schema.id not in classes:
                classes[schema.id] = _protobuf_class(schema.name, schema.data)
            decoded = classes[schema.id].FromString(message.data)
            if channel.topic == LANDMARKS:
                summary["landmarks"] += len(decoded.entities)
                continue
            text = decoded.message
            summary["switches"] += " switched " in text or " moved off " in text
            summary["null_wins"] += text.endswith("left to the null hypothesis")
            last_event = text
    if last_event is not None and last_event.startswith(f"{summary['method']}:"):
        summary["result"] = last_event
    return summary


def _protobuf_class(name: str, file_descriptor_set: bytes) -> Any:
    """The message class of `name` built from an MCAP schema's FileDescriptorSet."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    for file in descriptor_pb2.FileDescriptorSet.FromString(file_descriptor_set).file:
        pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
