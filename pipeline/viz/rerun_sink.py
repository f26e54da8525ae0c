"""The Rerun sink: a run streamed to a recording file, a new viewer, or a running one.

What it costs is bounded per keyframe, whatever the size of the map. A keyframe logs at once
what it decided: each new detection's hypothesis lines (weights, winner), the landmarks it
touched (with ellipsoids from iSAM2's marginals), null-hypothesis wins and switches, its image.
What every keyframe adds a row to (the robot's pose, the trajectory since the last refresh, the
time series) is held back and sent as columns every `refresh_every` keyframes: one Rerun call
per entity instead of one per keyframe, since each call costs ~0.1 ms. A refresh also re-logs
the whole trajectory and the landmarks that moved; the end of the run re-logs everything from
the final estimate. Entity paths: `pipeline/viz/entities.py`.
"""

from __future__ import annotations

import logging
import os
import shutil
import socket
import sys
import time
import uuid
import weakref
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import urlparse

import numpy as np
import rerun as rr
from gtsam.symbol_shorthand import L, X

from pipeline.backend.hypotheses import NULL, AssociationRecord
from pipeline.backend.landmarks import LandmarkKind, LandmarkMap
from pipeline.errors import InputError
from pipeline.geometry import point_from_bearing_elevation_range
from pipeline.log.schemas import LEFT_IMAGE
from pipeline.outputs import atomic_output
from pipeline.viz import draw
from pipeline.viz import entities as e
from pipeline.viz.blueprint import frontend_blueprint, replay_blueprint
from pipeline.viz.config import VizConfig, load_viz_config

if TYPE_CHECKING:
    from pipeline.backend.slam import Backend, BackendResult, KeyframeReport
    from pipeline.log.messages import CompressedImage, Detection, DetectionLog, LogMetadata
    from pipeline.viz.frontend import FrontendKeyframe

logger = logging.getLogger(__name__)

DEFAULT_PORT = 9876
VIEWER_WAIT_S = 2.0
# Relative change of a landmark's covariance worth logging again (about 2.5 % in its axes).
ELLIPSOID_TOLERANCE = 0.05
MEDIA_TYPES = {"jpeg": "image/jpeg", "jpg": "image/jpeg", "png": "image/png"}
TRAJECTORY_RGB = (40, 200, 110)
TRUTH_RGB = (120, 120, 120)
ODOMETRY_RGB = (200, 120, 40)


def viewer_url(address: str) -> str:
    """A gRPC URL from `--connect`: a URL as Rerun takes it, `HOST:PORT`, or a bare port."""
    address = address.strip()
    if address.isdigit():
        address = f"127.0.0.1:{address}"
    if "://" not in address:
        address = f"rerun+http://{address}/proxy"
    parsed = urlparse(address)
    if parsed.scheme not in ("rerun", "rerun+http", "rerun+https") or not parsed.hostname:
        raise InputError(f"--connect {address}: expected HOST:PORT or rerun+http://HOST:PORT/proxy")
    try:
        parsed.port  # noqa: B018 - raises on a port that is not a number
    except ValueError:
        raise InputError(f"--connect {address}: the port is not a number") from None
    return address


def _listening(url: str, timeout_s: float) -> bool:
    parsed = urlparse(url)
    default = 443 if parsed.scheme == "rerun+https" else DEFAULT_PORT
    try:
        with socket.create_connection((parsed.hostname, parsed.port or default), timeout_s):
            return True
    except OSError:
        return False


def _rerun_executable() -> str | None:
    """The viewer of this environment, found even when its bin/ is not on PATH."""
    beside = Path(sys.executable).parent / "rerun"
    return str(beside) if beside.exists() else shutil.which("rerun")


def _discard(path: Path) -> None:
    path.unlink(missing_ok=True)


def _differs(covariance: np.ndarray | None, shown: np.ndarray | None) -> bool:
    """Whether an ellipsoid would visibly change: its covariance by more than a few percent."""
    if covariance is None or shown is None:
        return covariance is not shown
    scale = np.linalg.norm(shown)
    return bool(np.linalg.norm(covariance - shown) > ELLIPSOID_TOLERANCE * scale)


def _name(landmark_id: int) -> str:
    return "null" if landmark_id == NULL else f"L{landmark_id}"


def _row(value: Any) -> np.ndarray:
    """A Pose3 or a point as a flat row [R (9, row-major), t (3)], as the solver gives them."""
    if hasattr(value, "translation"):
        return np.concatenate([value.rotation().matrix().ravel(), value.translation()])
    return np.concatenate([np.zeros(9), np.asarray(value, dtype=float)])


@dataclass
class _Shown:
    """A landmark as last logged."""

    position: np.ndarray
    label: str
    class_id: int
    covariance: np.ndarray | None  # world frame, of its position


class _HeldRows:
    """Rows of per-keyframe entities held back, then sent as one column per entity."""

    def __init__(self) -> None:
        self.scalars: dict[str, list[tuple[int, int, float]]] = defaultdict(list)
        self.poses: list[tuple[int, int, np.ndarray]] = []  # (pose, stamp, 4x4)
        self.strips: dict[str, list[tuple[int, int, np.ndarray]]] = defaultdict(list)

    def send(self, rec: rr.RecordingStream, robot_path: str) -> None:
        def times(rows: list) -> list[rr.TimeColumn]:
            return [
                rr.TimeColumn(e.POSE_TIMELINE, sequence=[r[0] for r in rows]),
                rr.TimeColumn(
                    e.TIME_TIMELINE, timestamp=np.array([r[1] for r in rows], "datetime64[ns]")
                ),
            ]

        for path, rows in self.scalars.items():
            if rows:
                scalars = rr.Scalars.columns(scalars=[r[2] for r in rows])
                rec.send_columns(path, indexes=times(rows), columns=scalars)
        if self.poses:
            matrices = np.array([r[2] for r in self.poses])
            rec.send_columns(
                robot_path,
                indexes=times(self.poses),
                columns=rr.Transform3D.columns(
                    translation=matrices[:, :3, 3], mat3x3=matrices[:, :3, :3]
                ),
            )
        for path, rows in self.strips.items():
            if rows:
                strips = rr.LineStrips3D.columns(strips=[r[2] for r in rows])
                rec.send_columns(
                    path, indexes=times(rows), columns=strips.partition([1] * len(rows))
                )
        self.scalars.clear()
        self.poses.clear()
        self.strips.clear()


class RerunSink:
    """Implements `pipeline.viz.sink.Sink` (replay) and `pipeline.viz.frontend.FrontendSink`."""

    def __init__(
        self,
        recording: rr.RecordingStream,
        config: VizConfig,
        *,
        target: Path | None = None,
        temporary: Path | None = None,
    ):
        self.rec = recording
        self.config = config
        self.wants_images = config.image_every > 0
        self.target = target  # the .rrd, renamed into place on a finished run's close
        self.temporary = temporary
        # A run that fails before `close` (or never reaches it) leaves no temporary behind.
        self._discard_at_exit = (
            weakref.finalize(self, _discard, temporary) if temporary is not None else None
        )
        self._started = self._finished = self._closed = False
        self._held = _HeldRows()
        self._class_names: tuple[str, ...] = ()
        self._colours = draw.packed_rgba(draw.class_colors(1))
        self._stamps_ns = np.zeros(0, dtype=np.int64)
        self._truth: dict[int, np.ndarray] = {}  # pose index -> aligned true position
        self._images: dict[int, CompressedImage] = {}  # stamp -> left image
        self._shown: set[str] = set()  # per-keyframe entities that hold something now
        self._refreshed_at = 0  # pose index of the last full trajectory
        self._positions: list[np.ndarray] = []  # pose positions as estimated when added
        self._landmarks: dict[int, _Shown] = {}  # each landmark as last logged
        self._landmark_total = 0  # landmarks before the current keyframe
        self._winners: dict[tuple[int, int], int] = {}  # (pose, detection) -> landmark shown
        self._null_count = 0
        self._backend: Backend | None = None

    # ----------------------------------------------------------------------------------- open
    @classmethod
    def open(
        cls,
        application: str,
        *,
        rrd: str | Path | None = None,
        spawn: bool = False,
        connect: str | None = None,
        config: VizConfig | None = None,
    ) -> RerunSink:
        """A sink for exactly one of: a recording file, a new viewer, a running viewer."""
        if (rrd is not None) + bool(spawn) + (connect is not None) != 1:
            raise InputError("choose one of --rrd FILE, --spawn, --connect ADDR")
        config = config or load_viz_config()
        # Rerun's own switch: a stream it disables would write an empty file (and say so at
        # exit). Read as Rerun reads it.
        if os.environ.get("RERUN", "").strip().lower() in ("0", "false", "off", "no"):
            raise InputError("Rerun is turned off by the environment variable RERUN: unset it")
        recording = rr.RecordingStream(application, recording_id=uuid.uuid4())
        # The log's own stamps make the `log_time` timeline; no wall-clock time, no ticks.
        recording.set_log_time_enabled(False)
        recording.set_log_tick_enabled(False)
        if rrd is not None:
            target = Path(rrd)
            if target.is_dir():
                raise InputError(f"--rrd {target}: is a directory")
            try:
                fd, temporary = atomic_output(target)
            except OSError as exc:
                raise InputError(f"--rrd {target}: cannot be written ({exc.strerror})") from None
            os.close(fd)
            return cls(recording, config, target=target, temporary=temporary)
        if spawn:
            url = f"rerun+http://127.0.0.1:{DEFAULT_PORT}/proxy"
            if not _listening(url, VIEWER_WAIT_S):  # else a viewer is there already: use it
                executable = _rerun_executable()
                if executable is None:
                    raise InputError("--spawn: no `rerun` viewer executable found")
                rr.spawn(port=DEFAULT_PORT, connect=False, executable_path=executable)
                if not _listening(url, VIEWER_WAIT_S):
                    raise InputError(
                        "--spawn: the Rerun viewer did not start (no display?); "
                        "use --rrd FILE, or --connect to a viewer elsewhere"
                    )
            recording.connect_grpc(url)
            return cls(recording, config)
        url = viewer_url(connect or "")
        # Without a viewer Rerun buffers and retries, and every log call slows to a crawl.
        if not _listening(url, VIEWER_WAIT_S):
            raise InputError(f"--connect {connect}: no Rerun viewer listening at {url}")
        recording.connect_grpc(url)
        return cls(recording, config)

    def _begin(self, blueprint: Any, name: str, class_names: tuple[str, ...]) -> None:
        if self._started:
            raise RuntimeError("a RerunSink records one run")
        self._started = True
        if self.temporary is not None:
            self.rec.save(self.temporary)
        self.rec.send_blueprint(blueprint)
        self.rec.send_recording_name(name)
        self.rec.log(e.WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.rec.log(e.ROBOT, rr.TransformAxes3D(self.config.robot_axis_length_m), static=True)
        self._class_names = class_names
        rgb = draw.class_colors(len(class_names))
        self._colours = draw.packed_rgba(rgb)
        self.rec.log(
            "/",
            rr.AnnotationContext(
                [
                    rr.ClassDescription(info=(c, name, tuple(int(v) for v in rgb[c])))
                    for c, name in enumerate(class_names)
                ]
            ),
            static=True,
        )

    def _set_time(self, pose_index: int, stamp_ns: int) -> None:
        self.rec.set_time(e.POSE_TIMELINE, sequence=pose_index)
        self.rec.set_time(e.TIME_TIMELINE, timestamp=np.datetime64(int(stamp_ns), "ns"))

    def _series(self, path: str, name: str, colour: tuple[int, int, int]) -> None:
        self.rec.log(path, rr.SeriesLines(names=name, colors=colour), static=True)

    def _trail_style(self, path: str) -> None:
        """Colour and width of a trail whose strips are sent as columns (strips only)."""
        style = rr.LineStrips3D.from_fields(
            colors=draw.packed_rgba(TRAJECTORY_RGB)[None], radii=rr.Radius.ui_points(2.0)
        )
        self.rec.log(path, style, static=True)

    def _clear_unless(self, path: str, logged: bool) -> None:
        """Per-keyframe entities show this keyframe's items only: clear what an earlier one
        left when this one has nothing (once, not every keyframe)."""
        if logged:
            self._shown.add(path)
        elif path in self._shown:
            self.rec.log(path, rr.Clear(recursive=False))
            self._shown.discard(path)

    def _stamp(self, pose_index: int) -> int:
        return int(self._stamps_ns[pose_index]) if pose_index < len(self._stamps_ns) else 0

    @staticmethod
    def _trajectory(positions: Any, rgb: tuple[int, int, int], label: str) -> rr.LineStrips3D:
        return rr.LineStrips3D(
            [np.asarray(positions, dtype=float)],
            colors=draw.packed_rgba(rgb)[None],
            radii=rr.Radius.ui_points(2.0),
            labels=[label],
            show_labels=False,
        )

    # --------------------------------------------------------------------------------- replay
    def start(self, log: DetectionLog, method: str) -> None:
        left_images = log.images.get(LEFT_IMAGE, []) if self.wants_images else []
        alignment = draw.ground_truth_alignment(log.ground_truth_poses)
        self._begin(
            replay_blueprint(images=bool(left_images), ground_truth=alignment is not None),
            f"mmslam replay {method}",
            log.metadata.class_names,
        )
        self._stamps_ns = np.array(log.pose_stamps_ns(), dtype=np.int64)
        self._images = {image.stamp_ns: image for image in left_images}
        self.rec.send_property(
            "run",
            rr.AnyValues(
                method=method,
                log_source=log.metadata.source,
                poses=log.num_poses,
                detections=log.num_detections,
                classes=", ".join(log.metadata.class_names),
            ),
        )
        self.rec.log(
            e.ODOMETRY_TRAJECTORY,
            self._trajectory(draw.dead_reckoning(log.odometry), ODOMETRY_RGB, "dead reckoning"),
            static=True,
        )
        if alignment is not None:
            indices, positions = draw.aligned_ground_truth(log.ground_truth_poses, alignment)
            self._truth = {int(i): p for i, p in zip(indices, positions, strict=True)}
            self.rec.log(
                e.GROUND_TRUTH_TRAJECTORY,
                self._trajectory(positions, TRUTH_RGB, "ground truth"),
                static=True,
            )
            truth = log.ground_truth_landmarks
            if truth is not None and truth.landmarks:
                points = np.array([lm.position for lm in truth.landmarks], dtype=float)
                self.rec.log(
                    e.GROUND_TRUTH_LANDMARKS,
                    rr.Points3D(
                        points @ alignment[:3, :3].T + alignment[:3, 3],
                        class_ids=[lm.class_id for lm in truth.landmarks],
                        labels=[f"true {lm.id}" for lm in truth.landmarks],
                        radii=rr.Radius.ui_points(2.0),
                        show_labels=False,
                    ),
                    static=True,
                )
            self._series(e.ERROR_ONLINE, "newest pose", (230, 80, 60))
            self._series(e.ERROR_FINAL, "final estimate", (60, 120, 230))
        self._trail_style(e.TRAJECTORY_RECENT)
        self._series(e.LANDMARK_COUNT, "landmarks", (31, 119, 180))
        self._series(e.SWITCH_COUNT, "switches (total)", (255, 170, 0))
        self._series(e.NULL_RATE, "null-hypothesis rate", (235, 50, 50))
        self._series(e.STEP_MS, "back-end", (90, 90, 90))
        self._series(e.VIZ_MS, "recording", (148, 103, 189))

    def _fetch(
        self, backend: Backend, pose_indices: set[int], landmark_ids: set[int]
    ) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]]:
        """Estimates as rows [R (9), t (3)], in one iSAM2 call."""
        landmarks = backend.landmarks.landmarks
        keyed = {X(i): (True, i) for i in pose_indices}
        keyed.update({L(j): (False, j) for j in landmark_ids})
        keys = sorted(keyed)
        is_pose3 = np.array(
            [keyed[k][0] or landmarks[keyed[k][1]].kind is LandmarkKind.POSE for k in keys],
            dtype=bool,
        )
        rows = backend.solver.flat_estimates(keys, is_pose3)
        poses, points = {}, {}
        for key, row in zip(keys, rows, strict=True):
            is_robot, index = keyed[key]
            (poses if is_robot else points)[index] = row
        return poses, points

    def _landmark_label(self, landmarks: LandmarkMap, landmark_id: int) -> tuple[int, str]:
        landmark = landmarks.landmarks[landmark_id]
        c = landmark.map_class
        probability = float(landmark.class_probabilities[c])
        return c, draw.landmark_label(landmark_id, self._class_names[c], probability)

    def _log_landmark(
        self,
        landmarks: LandmarkMap,
        landmark_id: int,
        row: np.ndarray,
        covariance: np.ndarray | None,
        *,
        unless_unchanged: bool = False,
    ) -> None:
        """A landmark's point, coloured and labelled by its MAP class, with its ellipsoid. A
        `covariance` of None keeps the one last shown, moved with the landmark. Only what
        changed since the landmark was last shown is logged (Rerun keeps the rest), and with
        `unless_unchanged` nothing if nothing visibly changed."""
        position = row[9:].copy()
        c, label = self._landmark_label(landmarks, landmark_id)
        shown = self._landmarks.get(landmark_id)
        world = None if shown is None else shown.covariance
        if covariance is not None:
            is_pose = landmarks.landmarks[landmark_id].kind is LandmarkKind.POSE
            world = draw.position_covariance(covariance, row[:9].reshape(3, 3) if is_pose else None)
        if (
            unless_unchanged
            and shown is not None
            and shown.label == label
            and np.linalg.norm(position - shown.position) <= self.config.refresh_move_m
            and not _differs(world, shown.covariance)
        ):
            return
        new_class = shown is None or shown.class_id != c
        point: dict[str, Any] = {"positions": position[None]}
        if new_class:
            point.update(colors=self._colours[c : c + 1], class_ids=[c])
        if shown is None:
            point["radii"] = rr.Radius.ui_points(5.0)
        if shown is None or shown.label != label:
            point["labels"] = [label]
        parts: list[Any] = [rr.Points3D.from_fields(**point)]
        if world is not None:
            shape: dict[str, Any] = {"centers": position[None]}
            if covariance is not None or shown is None or shown.covariance is None:
                half_sizes, quaternion = draw.ellipsoid(world, self.config.ellipsoid_confidence)
                shape.update(half_sizes=half_sizes[None], quaternions=quaternion[None])
            if new_class or shown.covariance is None:
                shape.update(colors=self._colours[c : c + 1], fill_mode="MajorWireframe")
            parts.append(rr.Ellipsoids3D.from_fields(**shape))
        self.rec.log(e.landmark_path(landmark_id), *parts)
        self._landmarks[landmark_id] = _Shown(position, label, c, world)

    def _refresh(self, backend: Backend, pose_index: int) -> None:
        """Send the held rows; then the whole trajectory, and every landmark that moved or
        changed class since it was shown."""
        self._held.send(self.rec, e.ROBOT)
        ids = set(backend.landmarks.landmarks)
        poses, points = self._fetch(backend, set(range(pose_index + 1)), ids)
        positions = [poses[i][9:] for i in range(pose_index + 1)]
        self.rec.log(e.TRAJECTORY, self._trajectory(positions, TRAJECTORY_RGB, "estimate"))
        self.rec.log(e.TRAJECTORY_RECENT, rr.Clear(recursive=False))
        self._positions = positions
        self._refreshed_at = pose_index
        # Class labels change only where a detection weighed the landmark, and those were
        # logged then: here only movement matters.
        shown = sorted(j for j in ids if j in self._landmarks)
        if shown:
            now = np.array([points[j][9:] for j in shown])
            before = np.array([self._landmarks[j].position for j in shown])
            moved = np.linalg.norm(now - before, axis=1) > self.config.refresh_move_m
            for j in np.array(shown)[moved]:
                self._log_landmark(backend.landmarks, int(j), points[int(j)], None)
        for j in sorted(ids - set(shown)):
            self._log_landmark(backend.landmarks, j, points[j], None)

    def keyframe(self, report: KeyframeReport, backend: Backend) -> None:
        started = time.perf_counter()
        self._backend = backend
        i = report.pose_index
        stamp = self._stamp(i)
        self._set_time(i, stamp)
        # Landmark ids are consecutive: ids from the count before this keyframe are new ones.
        hypotheses = [
            draw.detection_hypotheses(r, c, r.landmark_id >= self._landmark_total)
            for r, c in zip(report.records, report.candidates, strict=True)
        ]
        self._landmark_total = len(backend.landmarks)
        touched = {h.landmark_id for hs in hypotheses for h in hs if h.landmark_id != NULL}
        for record in report.switched:
            touched.update(record.landmark_ids)
        pose_indices = {i} | {r.measurement.pose_index for r in report.switched}
        poses, points = self._fetch(backend, pose_indices, touched)

        row = poses[i]
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = row[:9].reshape(3, 3), row[9:]
        self._held.poses.append((i, stamp, pose))
        self._positions.append(row[9:].copy())
        if i - self._refreshed_at >= self.config.refresh_every:
            self._refresh(backend, i)
        elif i > self._refreshed_at:
            recent = np.array(self._positions[self._refreshed_at :])
            self._held.strips[e.TRAJECTORY_RECENT].append((i, stamp, recent))

        for j in sorted(touched):
            # The association step computed the marginal of every candidate it weighed with
            # joint marginals this keyframe (before the update); otherwise its last one, an
            # upper bound. A new landmark has none yet.
            covariance = backend.landmarks.landmarks[j].covariance_bound
            if self.config.keyframe_marginals or covariance is None:
                covariance = backend.solver.marginal_covariance(L(j))
            self._log_landmark(backend.landmarks, j, points[j], covariance, unless_unchanged=True)

        self._log_hypotheses(report.records, hypotheses, row, points)
        self._log_associations(report, poses, points)
        self._log_image(i, [(r.measurement.detection, r.landmark_id) for r in report.records])

        held = self._held.scalars
        if i in self._truth:
            held[e.ERROR_ONLINE].append((i, stamp, float(np.linalg.norm(row[9:] - self._truth[i]))))
        held[e.LANDMARK_COUNT].append((i, stamp, len(backend.landmarks)))
        held[e.SWITCH_COUNT].append((i, stamp, backend.switches))
        if self._winners:
            held[e.NULL_RATE].append((i, stamp, self._null_count / len(self._winners)))
        held[e.STEP_MS].append((i, stamp, 1e3 * report.seconds))
        held[e.VIZ_MS].append((i, stamp, 1e3 * (time.perf_counter() - started)))

    def _log_hypotheses(
        self,
        records: list[AssociationRecord],
        hypotheses: list[list[draw.Hypothesis]],
        pose_row: np.ndarray,
        points: dict[int, np.ndarray],
    ) -> None:
        """Per detection, a line from the pose to every landmark it may be, or to where it puts
        its landmark for the null hypothesis; width by weight, the winner bright. The measured
        points are drawn too, coloured by reported class."""
        strips, colours, widths, labels, flat = [], [], [], [], []
        origin = pose_row[9:]
        measured = np.zeros((len(records), 3))
        for k, (record, hs) in enumerate(zip(records, hypotheses, strict=True)):
            measured[k] = draw.body_to_world(pose_row, record.measurement.body_point)[0]
            for h in hs:
                end = measured[k] if h.landmark_id == NULL else points[h.landmark_id][9:]
                colour, width = draw.hypothesis_style(h)
                strips.append(np.array([origin, end]))
                colours.append(colour)
                widths.append(rr.Radius.ui_points(width))
                labels.append(draw.hypothesis_label(h))
                flat.append(h)
        if flat:
            classes = [r.measurement.detection.class_id for r in records]
            self.rec.log(
                e.HYPOTHESES,
                rr.LineStrips3D(
                    strips, colors=draw.packed_rgba(colours), radii=widths, labels=labels
                ),
                rr.Points3D(
                    measured,
                    colors=self._colours[classes],
                    class_ids=classes,
                    radii=rr.Radius.ui_points(3.0),
                ),
                # One value per line: for the selection panel, and for reading the recording.
                rr.AnyValues(
                    detection=[h.detection_index for h in flat],
                    landmark=[h.landmark_id for h in flat],
                    weight=[h.weight for h in flat],
                    winner=[h.winner for h in flat],
                ),
            )
        self._clear_unless(e.HYPOTHESES, bool(flat))

    def _log_associations(
        self,
        report: KeyframeReport,
        poses: dict[int, np.ndarray],
        points: dict[int, np.ndarray],
    ) -> None:
        """Null-hypothesis wins and switches: marked in the map and told in the event log."""
        i = report.pose_index
        null_points, null_labels = [], []
        strips, strip_labels = [], []
        # Switches first: they change what was shown for detections of earlier keyframes.
        for record in report.switched:
            m = record.measurement
            key = (m.pose_index, m.detection_index)
            winner = record.landmark_id
            previous = self._winners.get(key)  # None: the detection is this keyframe's own
            if previous is not None:
                self._null_count += (winner == NULL) - (previous == NULL)
                self._winners[key] = winner
            pose_row = poses[m.pose_index]
            measured = draw.body_to_world(pose_row, m.body_point)[0]
            strips.append(
                np.array([pose_row[9:], measured if winner == NULL else points[winner][9:]])
            )
            was = "" if previous is None else _name(previous)
            strip_labels.append(f"p{m.pose_index} d{m.detection_index}: {was}→{_name(winner)}")
            if winner == NULL and previous is not None:
                null_points.append(measured)
                null_labels.append(f"p{m.pose_index} d{m.detection_index}")
            when = "within its keyframe" if previous is None else f"from {was}"
            self.rec.log(
                e.EVENTS,
                rr.TextLog(
                    f"pose {i}: detection {m.detection_index} of pose {m.pose_index} switched "
                    f"{when} to {_name(winner)} (switch {record.switches})",
                    level="WARN",
                ),
            )
        for record in report.records:
            m = record.measurement
            self._winners[(m.pose_index, m.detection_index)] = record.landmark_id
            if record.landmark_id != NULL:
                continue
            self._null_count += 1
            null_points.append(draw.body_to_world(poses[i], m.body_point)[0])
            null_labels.append(f"p{m.pose_index} d{m.detection_index}")
            rivals = ", ".join(
                f"L{j} {w:.2f}" for j, w in zip(record.landmark_ids, record.weights, strict=True)
            )
            self.rec.log(
                e.EVENTS,
                rr.TextLog(
                    f"pose {i}: detection {m.detection_index} went to the null hypothesis "
                    f"(weight {record.null_weight:.2f}; candidates {rivals or 'none'})",
                    level="WARN",
                ),
            )
        if null_points:
            self.rec.log(
                e.NULL_WINS,
                rr.Points3D(
                    null_points,
                    colors=draw.packed_rgba(draw.NULL_WINNER_RGB)[None],
                    radii=rr.Radius.ui_points(7.0),
                    labels=null_labels,
                ),
            )
        self._clear_unless(e.NULL_WINS, bool(null_points))
        if strips:
            self.rec.log(
                e.SWITCHES,
                rr.LineStrips3D(
                    strips,
                    colors=draw.packed_rgba(draw.SWITCH_RGB)[None],
                    radii=rr.Radius.ui_points(4.0),
                    labels=strip_labels,
                ),
            )
        self._clear_unless(e.SWITCHES, bool(strips))

    def _log_image(self, pose_index: int, detections: list[tuple[Detection, int | None]]) -> None:
        """The log's left image at this pose, each detection's box labelled with its reported
        class, score and the landmark it went to."""
        every = self.config.image_every
        if not self._images or every == 0 or pose_index % every:
            return
        image = self._images.get(self._stamp(pose_index))
        if image is None:
            return
        media_type = MEDIA_TYPES.get(image.format.lower())
        self.rec.log(e.CAMERA, rr.EncodedImage(contents=image.data, media_type=media_type))
        self._log_boxes([(d, winner) for d, winner in detections if d.bbox is not None])

    def _log_boxes(self, boxes: list[tuple[Detection, int | None]]) -> None:
        if boxes:
            labels = []
            for detection, winner in boxes:
                label = f"{self._class_names[detection.class_id]} {detection.score:.2f}"
                labels.append(label if winner is None else f"{label} → {_name(winner)}")
            self.rec.log(
                e.CAMERA_DETECTIONS,
                rr.Boxes2D(
                    array=[d.bbox for d, _ in boxes],
                    array_format=rr.Box2DFormat.XYXY,
                    class_ids=[d.class_id for d, _ in boxes],
                    labels=labels,
                ),
            )
        self._clear_unless(e.CAMERA_DETECTIONS, bool(boxes))

    def finish(self, result: BackendResult, metrics: dict[str, Any] | None) -> None:
        """The final estimate at the last pose: trajectory, every landmark (with fresh
        marginals if configured), every pose's error, the detections left to the null
        hypothesis, the metrics."""
        self._held.send(self.rec, e.ROBOT)
        last = len(result.poses) - 1
        self._set_time(last, self._stamp(last))
        rows = np.array([_row(p) for p in result.poses])
        self.rec.log(e.TRAJECTORY, self._trajectory(rows[:, 9:], TRAJECTORY_RGB, "estimate"))
        self.rec.log(e.TRAJECTORY_RECENT, rr.Clear(recursive=False))
        fresh = self.config.final_marginals and self._backend is not None
        for j, value in zip(result.landmark_ids, result.landmark_values, strict=True):
            covariance = self._backend.solver.marginal_covariance(L(j)) if fresh else None
            self._log_landmark(result.landmarks, j, _row(value), covariance)

        indices = np.array(sorted(k for k in self._truth if k <= last), dtype=int)
        if len(indices):
            errors = np.linalg.norm(rows[indices, 9:] - [self._truth[k] for k in indices], axis=1)
            self.rec.send_columns(
                e.ERROR_FINAL,
                indexes=[
                    rr.TimeColumn(e.POSE_TIMELINE, sequence=indices),
                    rr.TimeColumn(
                        e.TIME_TIMELINE, timestamp=self._stamps_ns[indices].astype("datetime64[ns]")
                    ),
                ],
                columns=rr.Scalars.columns(scalars=errors),
            )

        rejected = [r.measurement for r in result.records if r.landmark_id == NULL]
        if rejected:
            self.rec.log(
                e.REJECTED,
                rr.Points3D(
                    [draw.body_to_world(rows[m.pose_index], m.body_point)[0] for m in rejected],
                    colors=draw.packed_rgba(draw.NULL_WINNER_RGB)[None],
                    radii=rr.Radius.ui_points(5.0),
                    labels=[f"p{m.pose_index} d{m.detection_index}" for m in rejected],
                ),
            )
        summary = _summary(result, metrics)
        self.rec.log(e.SUMMARY, rr.TextDocument(summary, media_type="text/markdown"))
        self._finished = True

    # ------------------------------------------------------------------------------- frontend
    def frontend_start(self, metadata: LogMetadata) -> None:
        self._begin(frontend_blueprint(), "mmslam frontend", metadata.class_names)
        self._trail_style(e.VO_TRAJECTORY_RECENT)
        self._series(e.TAG_COUNT, "tags", (31, 119, 180))
        self._series(e.BOX_COUNT, "boxes", (255, 127, 14))
        self._series(e.VO_INLIERS, "inliers", (44, 160, 44))

    def frontend_keyframe(self, keyframe: FrontendKeyframe) -> None:
        i, stamp = keyframe.pose_index, keyframe.stamp_ns
        self._set_time(i, stamp)
        self._held.poses.append((i, stamp, keyframe.body_pose))
        self._positions.append(keyframe.body_pose[:3, 3].copy())
        if i - self._refreshed_at >= self.config.refresh_every:
            self._held.send(self.rec, e.ROBOT)
            self.rec.log(e.VO_TRAJECTORY, self._trajectory(self._positions, TRAJECTORY_RGB, "VO"))
            self.rec.log(e.VO_TRAJECTORY_RECENT, rr.Clear(recursive=False))
            self._refreshed_at = i
        elif i > self._refreshed_at:
            recent = np.array(self._positions[self._refreshed_at :])
            self._held.strips[e.VO_TRAJECTORY_RECENT].append((i, stamp, recent))
        self._log_body_detections(keyframe.detections)

        every = self.config.image_every
        if every and i % every == 0:
            self._log_frontend_image(keyframe)
        detections = keyframe.detections
        held = self._held.scalars
        held[e.TAG_COUNT].append((i, stamp, sum(d.source == "apriltag" for d in detections)))
        held[e.BOX_COUNT].append((i, stamp, sum(d.source == "bbox" for d in detections)))
        if keyframe.step is not None:
            held[e.VO_INLIERS].append((i, stamp, keyframe.step.inliers))

    def _log_body_detections(self, detections: list[Detection]) -> None:
        """A keyframe's detections in the body frame: children of the robot."""
        if detections:
            body = point_from_bearing_elevation_range(
                np.array([[d.bearing, d.elevation, d.range] for d in detections])
            )
            classes = [d.class_id for d in detections]
            self.rec.log(
                e.ROBOT_DETECTIONS,
                rr.Points3D(
                    body,
                    colors=self._colours[classes],
                    class_ids=classes,
                    labels=[f"d{k}" for k in range(len(detections))],
                    radii=rr.Radius.ui_points(3.0),
                ),
            )
        self._clear_unless(e.ROBOT_DETECTIONS, bool(detections))

    def _log_frontend_image(self, keyframe: FrontendKeyframe) -> None:
        import cv2

        quality = [cv2.IMWRITE_JPEG_QUALITY, self.config.jpeg_quality]
        ok, data = cv2.imencode(".jpg", keyframe.left, quality)
        if ok:
            self.rec.log(
                e.CAMERA, rr.EncodedImage(contents=data.tobytes(), media_type="image/jpeg")
            )
        outlines = [np.vstack([t.corners, t.corners[:1]]) for t in keyframe.tags]
        if outlines:
            self.rec.log(
                e.CAMERA_TAGS,
                rr.LineStrips2D(
                    outlines,
                    labels=[f"tag {t.tag_id}" for t in keyframe.tags],
                    colors=draw.packed_rgba((255, 60, 200))[None],
                ),
            )
        self._clear_unless(e.CAMERA_TAGS, bool(outlines))
        # Tags are drawn by their outlines where the front-end gave them; boxes for the rest.
        outlined = "apriltag" if keyframe.tags else None
        self._log_boxes(
            [(d, None) for d in keyframe.detections if d.bbox is not None and d.source != outlined]
        )

    def frontend_finish(self) -> None:
        self._held.send(self.rec, e.ROBOT)
        if self._positions:
            self.rec.log(e.VO_TRAJECTORY, self._trajectory(self._positions, TRAJECTORY_RGB, "VO"))
            self.rec.log(e.VO_TRAJECTORY_RECENT, rr.Clear(recursive=False))
        self._finished = True

    # ---------------------------------------------------------------------------------- close
    def close(self) -> None:
        """Flush and disconnect; a recording file is renamed into place only if its run
        finished, so a failed run leaves an earlier recording as it was."""
        if self._closed:
            return
        self._closed = True
        try:
            self.rec.flush()
            self.rec.disconnect()
        except RuntimeError as exc:  # a viewer that went away: nothing more to send
            logger.warning("rerun: %s", exc)
        if self.temporary is None or self.target is None:
            return
        if self._finished:
            os.replace(self.temporary, self.target)
            logger.info("wrote recording %s", self.target)
        else:
            self.temporary.unlink(missing_ok=True)
            logger.info("the run did not finish: no recording written to %s", self.target)
        if self._discard_at_exit is not None:
            self._discard_at_exit.detach()


def _summary(result: BackendResult, metrics: dict[str, Any] | None) -> str:
    lines = [
        "# Run summary",
        "",
        f"- poses: {len(result.poses)}",
        f"- detections: {len(result.records)}",
        f"- landmarks: {len(result.landmark_ids)}",
        f"- association switches: {result.switches}",
        f"- left to the null hypothesis: {sum(r.landmark_id == NULL for r in result.records)}",
    ]
    if metrics:
        t, r = metrics["translation_error_m"], metrics["rotation_error_rad"]
        a = metrics["association"]
        lines += [
            "",
            "| error | max | mean | median | rmse |",
            "|---|---|---|---|---|",
            f"| translation (m) | {t['max']:.3f} | {t['mean']:.3f} | {t['median']:.3f} "
            f"| {t['rmse']:.3f} |",
            f"| rotation (rad) | {r['max']:.4f} | {r['mean']:.4f} | {r['median']:.4f} "
            f"| {r['rmse']:.4f} |",
            "",
            f"Associations: {a['correct']} correct, {a['wrong']} wrong, {a['null']} null.",
        ]
    return "\n".join(lines)
