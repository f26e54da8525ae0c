"""The run's summary as Markdown: short enough to read at a glance beside the map, updated as
the run goes and completed with the metrics at the end. No Rerun here."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class RunState:
    """The run at one keyframe (or at its end)."""

    method: str
    pose_index: int
    num_poses: int  # in the log
    detections: int  # so far
    landmarks: int
    switches: int
    nulls: int  # detections left to the null hypothesis now
    error_m: float | None = None  # the newest pose's distance to ground truth, when known


def summary_markdown(state: RunState, metrics: dict[str, Any] | None = None) -> str:
    """While the run goes: where it is and its counts. At the last pose: the counts, and with
    `metrics` the errors and association counts against ground truth."""
    done = state.pose_index >= state.num_poses - 1
    where = (
        f"{state.num_poses} poses, done"
        if done
        else (f"pose {state.pose_index} of {state.num_poses - 1}")
    )
    lines = [
        f"**{state.method}**: {where}",
        "",
        "| detections | landmarks | switches | null hypothesis |",
        "|---|---|---|---|",
        f"| {state.detections} | {state.landmarks} | {state.switches} | {state.nulls} |",
    ]
    if not metrics or "translation_error_m" not in metrics:
        if state.error_m is not None:
            lines += ["", f"Newest pose: {state.error_m:.2f} m from ground truth."]
        return "\n".join(lines)
    t, r = metrics["translation_error_m"], metrics["rotation_error_rad"]
    lines += [
        "",
        "| error | max | mean | median | RMSE |",
        "|---|---|---|---|---|",
        f"| translation (m) | {t['max']:.3f} | {t['mean']:.3f} | {t['median']:.3f} "
        f"| {t['rmse']:.3f} |",
        f"| rotation (rad) | {r['max']:.4f} | {r['mean']:.4f} | {r['median']:.4f} "
        f"| {r['rmse']:.4f} |",
    ]
    a = metrics.get("association")  # only where the log's detections carry truth labels
    if a is not None:
        lines += [
            "",
            f"Associations: {a['correct']} correct, {a['wrong']} wrong, {a['null']} null.",
        ]
    return "\n".join(lines)


def comparison_markdown(results: Sequence[Any]) -> str:
    """A table of several runs of one log (`pipeline.replay.ReplayResult`s), a row a method:
    the error (RMSE, max) where the log has ground-truth poses, the associations where it
    has truth labels, landmarks, the back-end's time; what tells methods apart first (a
    narrow view cuts the last columns). metrics.json holds the errors and the association
    counts only where the log has what they are measured against."""

    def of(r: Any, key: str) -> dict[str, Any] | None:
        return (r.metrics or {}).get(key)

    errors = any(of(r, "translation_error_m") for r in results)
    associations = any(of(r, "association") for r in results)
    head, rule = "| method |", "|---|"
    if errors:
        head, rule = head + " RMSE (m) | max (m) |", rule + "---|---|"
    if associations:
        head, rule = head + " wrong | null | correct |", rule + "---|---|---|"
    lines = [head + " landmarks | time (s) |", rule + "---|---|"]
    for r in results:
        t, a = of(r, "translation_error_m"), of(r, "association")
        row = f"| **{r.method}** |"
        if errors:
            row += f" {t['rmse']:.3f} | {t['max']:.3f} |" if t else " – | – |"
        if associations:
            row += f" {a['wrong']} | {a['null']} | {a['correct']} |" if a else " – | – | – |"
        lines.append(row + f" {r.num_landmarks} | {r.runtime_s:.1f} |")
    return "\n".join(lines)
