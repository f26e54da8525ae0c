"""What the association-event log says: one short line an event, at a level that tells the
method at work (INFO: a detection left to the null hypothesis, an association that changed)
from what needs a look (WARN: many associations changing at once, one that keeps changing).
No Rerun here; the levels are Rerun's `TextLogLevel` names."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from pipeline.backend.hypotheses import NULL

INFO = "INFO"
WARN = "WARN"


@dataclass(frozen=True)
class Event:
    level: str
    text: str


def name(landmark_id: int) -> str:
    return "null" if landmark_id == NULL else f"L{landmark_id}"


def started(method: str, num_poses: int, num_detections: int) -> Event:
    """The first line: what the log will list, so that a run without events reads as such."""
    return Event(
        INFO,
        f"pose 0: {method} over {num_poses} poses, {num_detections} detections; "
        "null-hypothesis wins and changed associations are listed here",
    )


def solver_fallback(at: int, kind: str, reason: str) -> Event:
    """The solver fell back at keyframe `at` (`pipeline/backend/solver.py`): a bug to report."""
    what = "solved the graph again in batch" if kind == "batch" else "went to QR"
    return Event(WARN, f"pose {at}: the solver {what} ({reason})")


def _detection(pose_index: int, detection_index: int, at: int) -> str:
    """A detection as seen from keyframe `at`: its own, or one of an earlier pose."""
    if pose_index == at:
        return f"detection {detection_index}"
    return f"detection {detection_index} of pose {pose_index}"


def null_win(
    at: int,
    detection_index: int,
    candidates: Sequence[tuple[int, float]],
    null_weight: float,
) -> Event:
    """A new detection of keyframe `at` left to the null hypothesis, with the landmarks it was
    weighed against (their association weights, and the null hypothesis's)."""
    rivals = ", ".join(f"{name(j)} {w:.2f}" for j, w in candidates) or "none"
    return Event(
        INFO,
        f"pose {at}: detection {detection_index} → null hypothesis "
        f"(candidates {rivals}; null {null_weight:.2f})",
    )


def changed(
    at: int, pose_index: int, detection_index: int, before: int | None, after: int
) -> Event:
    """An association that changed at keyframe `at`; `before` None: a detection of this
    keyframe, moved off its first choice by the keyframe's own update."""
    detection = _detection(pose_index, detection_index, at)
    if before is None:
        return Event(INFO, f"pose {at}: {detection} → {name(after)} after the update")
    return Event(INFO, f"pose {at}: {detection}, {name(before)} → {name(after)}")


def many_changed(at: int, count: int, threshold: int) -> Event | None:
    """Many earlier associations changing in one keyframe: a large correction of the map (a
    loop closure, right or wrong) worth looking at."""
    if count < threshold:
        return None
    return Event(WARN, f"pose {at}: {count} earlier associations changed: a large correction")


def unsettled(
    at: int, pose_index: int, detection_index: int, changes: int, threshold: int
) -> Event | None:
    """A detection whose association keeps changing: ambiguous between landmarks. Said once,
    when its changes reach the threshold."""
    if changes != threshold:
        return None
    detection = _detection(pose_index, detection_index, at)
    return Event(WARN, f"pose {at}: {detection} has changed {changes} times: ambiguous")
