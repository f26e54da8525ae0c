"""The back-end's map in the Rerun sink: landmarks (point, label, class colour, uncertainty
ellipsoid), each keyframe's hypotheses (a line from the pose to every landmark a detection may
be, the winner bright), null-hypothesis wins, switches, merges and the associations judged
wrong. Only what changed since it was last shown is logged again.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import rerun as rr
from gtsam.symbol_shorthand import L, X

from pipeline.backend.hypotheses import NULL, AssociationRecord
from pipeline.backend.landmarks import LandmarkKind, LandmarkMap
from pipeline.viz import draw, events, labels, marks
from pipeline.viz import entities as e
from pipeline.viz.correctness import WRONG, verdicts

if TYPE_CHECKING:
    from pipeline.backend.slam import BackendResult, KeyframeReport
    from pipeline.backend.view import ReadOnlyMap

# Relative change of a landmark's covariance worth logging again (about 2.5 % in its axes).
ELLIPSOID_TOLERANCE = 0.05
# Every landmark's uncertainty ellipsoid: thin (hundreds of them, when shown).
ELLIPSOID_LINE_PT = 0.5


def _differs(covariance: np.ndarray | None, shown: np.ndarray | None) -> bool:
    """Whether an ellipsoid would visibly change: its covariance by more than a few percent."""
    if covariance is None or shown is None:
        return covariance is not shown
    scale = np.linalg.norm(shown)
    return bool(np.linalg.norm(covariance - shown) > ELLIPSOID_TOLERANCE * scale)


def flat_row(value: Any) -> np.ndarray:
    """A Pose3 or a point as a flat row [R (9, row-major), t (3)], as the solver gives them."""
    if hasattr(value, "translation"):
        return np.concatenate([value.rotation().matrix().ravel(), value.translation()])
    return np.concatenate([np.zeros(9), np.asarray(value, dtype=float)])


@dataclass
class ShownLandmark:
    """A landmark as last logged."""

    position: np.ndarray
    label: str
    class_id: int
    covariance: np.ndarray | None  # world frame, of its position
    ellipsoid: tuple[np.ndarray, np.ndarray] | None  # half sizes, quaternion


class MapView:
    """The map's part of `RerunSink` (its state is the sink's)."""

    def _fetch(
        self, view: ReadOnlyMap, pose_indices: set[int], landmark_ids: set[int]
    ) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]]:
        """Estimates as rows [R (9), t (3)], in one iSAM2 call."""
        landmarks = view.landmarks.landmarks
        keyed = {X(i): (True, i) for i in pose_indices}
        keyed.update({L(j): (False, j) for j in landmark_ids})
        keys = sorted(keyed)
        is_pose3 = np.array(
            [keyed[k][0] or landmarks[keyed[k][1]].kind is LandmarkKind.POSE for k in keys],
            dtype=bool,
        )
        rows = view.flat_estimates(keys, is_pose3)
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
        """A landmark's point, coloured and labelled by its MAP class; its ellipsoid is kept for
        `CANDIDATES` and `UNCERTAINTY`. A `covariance` of None keeps the one last shown, moved
        with the landmark. Only what changed since the landmark was last shown is logged (Rerun
        keeps the rest), and with `unless_unchanged` nothing if nothing visibly changed."""
        position = row[9:].copy()
        c, label = self._landmark_label(landmarks, landmark_id)
        shown = self._landmarks.get(landmark_id)
        world = None if shown is None else shown.covariance
        if covariance is not None:
            is_pose = landmarks.landmarks[landmark_id].kind is LandmarkKind.POSE
            world = draw.position_covariance(covariance, row[:9].reshape(3, 3) if is_pose else None)
        point_changed = (
            not unless_unchanged
            or shown is None
            or shown.label != label
            or np.linalg.norm(position - shown.position) > self.config.refresh_move_m
        )
        if not point_changed and not _differs(world, shown.covariance):
            return
        if point_changed:
            point: dict[str, Any] = {"positions": position[None]}
            if shown is None or shown.class_id != c:  # coloured by the annotation context
                point["class_ids"] = [c]
            if shown is None:
                # The label is for hovering and selecting: hundreds of them hide the map. The
                # landmarks a keyframe weighs are labelled by `CANDIDATES`.
                point.update(radii=rr.Radius.ui_points(5.0), show_labels=False)
            if shown is None or shown.label != label:
                point["labels"] = [label]
            self.rec.log(e.landmark_path(landmark_id), rr.Points3D.from_fields(**point))
        else:
            position = shown.position
        ellipsoid = None if shown is None else shown.ellipsoid
        if world is not None and (covariance is not None or ellipsoid is None):
            ellipsoid = draw.ellipsoid(world, self.config.ellipsoid_confidence)
        self._landmarks[landmark_id] = ShownLandmark(position, label, c, world, ellipsoid)

    def _log_uncertainty(self) -> None:
        """Every landmark's ellipsoid as last shown, in one entity (a layer hidden by default,
        so one call a refresh rather than one a landmark a keyframe)."""
        shown = [(j, s) for j, s in sorted(self._landmarks.items()) if s.ellipsoid is not None]
        if not shown:
            return
        self.rec.log(
            e.UNCERTAINTY,
            rr.Ellipsoids3D(
                centers=[s.position for _, s in shown],
                half_sizes=[s.ellipsoid[0] for _, s in shown],
                quaternions=[s.ellipsoid[1] for _, s in shown],
                colors=self._colours[[s.class_id for _, s in shown]],
                labels=[f"L{j}" for j, _ in shown],
                show_labels=False,
                fill_mode="MajorWireframe",
                line_radii=rr.Radius.ui_points(ELLIPSOID_LINE_PT),
            ),
        )

    def _refresh(self, view: ReadOnlyMap, pose_index: int) -> None:
        """Send the held rows; then the whole trajectory, and every landmark that moved or
        changed class since it was shown."""
        self._held.send(self.rec, e.ROBOT)
        ids = set(view.landmarks.landmarks)
        poses, points = self._fetch(view, set(range(pose_index + 1)), ids)
        positions = [poses[i][9:] for i in range(pose_index + 1)]
        self.rec.log(e.TRAJECTORY, self._trajectory(positions, draw.ESTIMATE_RGB, "estimate"))
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
                self._log_landmark(view.landmarks, int(j), points[int(j)], None)
        for j in sorted(ids - set(shown)):
            self._log_landmark(view.landmarks, j, points[j], None)
        self._log_uncertainty()
        if self._tally is not None:
            resolve = view.landmarks.resolve
            self._log_wrong(
                [(key, resolve(j)) for key, j in self._tally.wrong()],
                lambda k: poses[k][9:],
                lambda j: points[j][9:],
            )

    def _judge(self, report: KeyframeReport, resolve: Any) -> None:
        """Bring the verdicts up to date with this keyframe: its detections, the earlier ones
        whose association changed, the landmarks merged."""
        if self._tally is None:
            return
        for record in [*report.records, *report.switched]:
            m = record.measurement
            j = record.landmark_id
            truth = m.detection.truth_landmark_id
            self._tally.assign(
                (m.pose_index, m.detection_index), truth, resolve(j) if j != NULL else j
            )
        for duplicate, survivor in report.merged:
            self._tally.merge(duplicate, resolve(survivor))

    def _log_wrong(
        self, wrong: list[tuple[tuple[int, int], int]], pose_at: Any, landmark_at: Any
    ) -> None:
        """Every detection judged wrong now, a red line from its pose to its landmark;
        `pose_at(k)` and `landmark_at(j)` give positions."""
        if wrong:
            self.rec.log(
                e.WRONG,
                *marks.wrong_lines(
                    np.array([pose_at(k) for (k, _), _ in wrong]),
                    np.array([landmark_at(j) for _, j in wrong]),
                    [f"p{k} d{d} → L{j}" for (k, d), j in wrong],
                ),
            )
        self._clear_unless(e.WRONG, bool(wrong))

    def _log_merges(
        self,
        merged: list[tuple[int, int]],
        merged_from: dict[int, np.ndarray],
        points: dict[int, np.ndarray],
        resolve: Any,
    ) -> None:
        """Each merge where it happened: a line from the duplicate to its survivor, kept in
        the history (shown up to the time cursor)."""
        drawn = [(d, resolve(s)) for d, s in merged if d in merged_from]
        if drawn:
            self.rec.log(
                e.MERGES,
                marks.merges(
                    np.array([merged_from[d] for d, _ in drawn]),
                    np.array([points[s][9:] for _, s in drawn]),
                    [f"L{d} → L{s}" for d, s in drawn],
                ),
            )

    def _log_hypotheses(
        self,
        records: list[AssociationRecord],
        hypotheses: list[list[draw.Hypothesis]],
        pose_row: np.ndarray,
        points: dict[int, np.ndarray],
        landmarks: LandmarkMap,
    ) -> None:
        """Per detection, a line from the pose to every landmark it may be, or to where it puts
        its landmark for the null hypothesis; width by weight, the winner bright (red if wrong),
        the winner's labelled with its weight. The measured points are drawn too, coloured by
        reported class, and the landmarks weighed are labelled with their id, class and its
        probability. Labels that would cover others at the default eye are left out: the
        winners' landmarks first, then the winners' lines, then the other candidates."""
        strips, colours, widths, texts, flat = [], [], [], [], []
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
                texts.append(draw.hypothesis_label(h))
                flat.append(h)
        weighed = sorted({h.landmark_id for h in flat if h.landmark_id != NULL})
        named = [self._landmark_label(landmarks, j) for j in weighed]
        centres = [points[j][9:] for j in weighed]
        landmarks_shown, lines_shown = labels.keyframe_labels(
            flat, strips, weighed, centres, self._label_box
        )
        if flat:
            classes = [r.measurement.detection.class_id for r in records]
            self.rec.log(
                e.HYPOTHESES,
                rr.LineStrips3D(
                    strips,
                    colors=draw.packed_rgba(colours),
                    radii=widths,
                    labels=[t if ok else "" for t, ok in zip(texts, lines_shown, strict=True)],
                ),
                rr.Points3D(
                    measured,
                    class_ids=classes,
                    radii=rr.Radius.ui_points(3.0),
                    show_labels=False,  # else each would carry its class name
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
        if weighed:
            classes = [c for c, _ in named]
            parts: list[Any] = [
                rr.Points3D(
                    centres,
                    class_ids=classes,
                    labels=[
                        label if ok else ""
                        for (_, label), ok in zip(named, landmarks_shown, strict=True)
                    ],
                    radii=rr.Radius.ui_points(6.0),
                    show_labels=True,
                )
            ]
            # Their uncertainty, as the association step saw it: only these, so that the map
            # stays readable (every landmark's is in `UNCERTAINTY`, hidden by default).
            shaped = [
                (centre, self._landmarks[j].ellipsoid, c)
                for j, centre, c in zip(weighed, centres, classes, strict=True)
                if self._landmarks[j].ellipsoid is not None
            ]
            if shaped:
                parts.append(
                    rr.Ellipsoids3D(
                        centers=[centre for centre, _, _ in shaped],
                        half_sizes=[shape[0] for _, shape, _ in shaped],
                        quaternions=[shape[1] for _, shape, _ in shaped],
                        colors=self._colours[[c for _, _, c in shaped]],
                        fill_mode="MajorWireframe",
                        line_radii=rr.Radius.ui_points(1.0),
                    )
                )
            self.rec.log(e.CANDIDATES, *parts)
        self._clear_unless(e.CANDIDATES, bool(weighed))

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
        earlier = 0
        # Switches first: they change what was shown for detections of earlier keyframes.
        for record in report.switched:
            m = record.measurement
            key = (m.pose_index, m.detection_index)
            winner = record.landmark_id
            previous = self._winners.get(key)  # None: the detection is this keyframe's own
            self._changes[key] += 1
            if previous is None:
                # Its hypothesis lines show where it went; one gone to the null hypothesis is
                # told below.
                if winner != NULL:
                    self._event(events.changed(i, *key, None, winner))
                continue
            earlier += 1
            self._null_count += (winner == NULL) - (previous == NULL)
            self._winners[key] = winner
            pose_row = poses[m.pose_index]
            measured = draw.body_to_world(pose_row, m.body_point)[0]
            strips.append(
                np.array([pose_row[9:], measured if winner == NULL else points[winner][9:]])
            )
            strip_labels.append(
                f"p{key[0]} d{key[1]}: {events.name(previous)}→{events.name(winner)}"
            )
            if winner == NULL:
                null_points.append(measured)
                null_labels.append(f"p{m.pose_index} d{m.detection_index}")
            self._event(events.changed(i, *key, previous, winner))
            limit = self.config.warn_changes_per_detection
            self._event(events.unsettled(i, *key, self._changes[key], limit))
        self._event(events.many_changed(i, earlier, self.config.warn_changes_at_once))
        for record in report.records:
            m = record.measurement
            self._winners[(m.pose_index, m.detection_index)] = record.landmark_id
            if record.landmark_id != NULL:
                continue
            self._null_count += 1
            null_points.append(draw.body_to_world(poses[i], m.body_point)[0])
            null_labels.append(f"p{m.pose_index} d{m.detection_index}")
            candidates = list(zip(record.landmark_ids, record.weights, strict=True))
            self._event(events.null_win(i, m.detection_index, candidates, record.null_weight))
        if null_points:
            found = np.array(null_points)
            self.rec.log(e.NULL_WINS, marks.null_decisions(found, null_labels, radius_ui=7.0))
            # and kept where they happened, shown up to the time cursor
            self.rec.log(e.NULL_DECISIONS, marks.null_decisions(found, null_labels))
        self._clear_unless(e.NULL_WINS, bool(null_points))
        if strips:
            self.rec.log(e.SWITCHES, marks.switches(strips, strip_labels))
        self._clear_unless(e.SWITCHES, bool(strips))

    def _log_final_wrong(self, result: BackendResult, rows: np.ndarray, last: int) -> None:
        """The final associations judged as `metrics.json` judges them: red lines, and the
        count at the last pose."""
        records = result.records
        keys = [(r.measurement.pose_index, r.measurement.detection_index) for r in records]
        resolve = result.landmarks.resolve
        chosen = [resolve(r.landmark_id) if r.landmark_id != NULL else NULL for r in records]
        judged = verdicts([r.measurement.detection.truth_landmark_id for r in records], chosen)
        where = {
            j: flat_row(v)[9:]
            for j, v in zip(result.landmark_ids, result.landmark_values, strict=True)
        }
        wrong = [(k, j) for k, j, v in zip(keys, chosen, judged, strict=True) if v == WRONG]
        self._log_wrong(wrong, lambda k: rows[k, 9:], where.__getitem__)
        self.rec.log(e.WRONG_COUNT, rr.Scalars(len(wrong)))
