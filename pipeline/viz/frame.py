"""What a replay's map is laid out around, from the log alone: the reference trajectories the
estimate is shown against (ground truth aligned at pose 0, odometry alone), the legend below
them, and every point the default eye must see: the true path and landmarks where the log has
them (odometry alone drifts far from them: framed on it, the map was a small part of its view),
else the odometry and what its detections saw. Pure; read by a run's sink and by the layout of
a comparison of runs, whose maps must match the runs'."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.geometry import point_from_bearing_elevation_range
from pipeline.log.messages import DetectionLog
from pipeline.viz import draw, legend

# The nearest share of the detections whose points the map's default eye must see.
SEEN_SHARE = 0.99


@dataclass(frozen=True)
class MapFrame:
    alignment: np.ndarray | None  # ground truth into the estimate's frame (pose 0 its origin)
    truth_indices: np.ndarray  # pose indices with a true pose
    truth: np.ndarray  # (N, 3) their positions, aligned at pose 0; empty without ground truth
    odometry: np.ndarray  # (P, 3) dead reckoning from pose 0
    truth_labels: bool  # its detections name their true landmark (wrong associations shown)
    items: list[legend.LegendItem]
    board: legend.Board
    extent: np.ndarray  # (M, 3): what the default eye must see, the legend included
    map_extent: np.ndarray  # (K, 3): the map alone (a layout with the legend elsewhere)

    @property
    def ground_truth(self) -> bool:
        """The log has a true pose 0: a true trajectory to show and measure against."""
        return self.alignment is not None


def board_below(
    reference: np.ndarray, items: list[legend.LegendItem], aspect: float
) -> tuple[legend.Board, np.ndarray]:
    """The legend's board below the reference trajectories (N, 3), and every point the default
    eye must see."""
    board = legend.legend_board(
        len(items), np.min(reference, axis=0), np.max(reference, axis=0), aspect
    )
    return board, np.vstack([reference, board.extent])


def seen_points(
    pose_indices: np.ndarray, measured: np.ndarray, poses: np.ndarray, share: float = SEEN_SHARE
) -> np.ndarray:
    """Where detections put what they saw: each (bearing, elevation, range) row of `measured`
    from the pose (P, 4, 4) its `pose_indices` entry names. The landmarks will be about there.
    The farthest (1 - `share`) of them are left out: a false detection far away should not
    shrink the whole map."""
    if not len(measured):
        return np.zeros((0, 3))
    measured = np.asarray(measured, dtype=float)
    near = measured[:, 2] <= np.quantile(measured[:, 2], share)
    body = point_from_bearing_elevation_range(measured[near])
    frames = poses[np.asarray(pose_indices)[near]]
    return np.einsum("nij,nj->ni", frames[:, :3, :3], body) + frames[:, :3, 3]


def replay_frame(log: DetectionLog, aspect: float) -> MapFrame:
    """The map of a replay of `log`, in a view of this `aspect` (width / height): the legend
    below the map, the default eye on both. The map: the true trajectory and landmarks where
    the log has them, else odometry alone and what the detections saw from it."""
    alignment = draw.ground_truth_alignment(log.ground_truth_poses)
    dead_reckoned = draw.dead_reckoning_poses(log.odometry)
    odometry = dead_reckoned[:, :3, 3]
    indices, truth = np.zeros(0, dtype=int), np.zeros((0, 3))
    true_landmarks = np.zeros((0, 3))
    if alignment is not None:
        indices, truth = draw.aligned_ground_truth(log.ground_truth_poses, alignment)
        if log.ground_truth_landmarks is not None and log.ground_truth_landmarks.landmarks:
            true_landmarks = draw.aligned_points(
                [lm.position for lm in log.ground_truth_landmarks.landmarks], alignment
            )
    truth_labels = any(
        d.truth_landmark_id is not None for m in log.detections for d in m.detections
    )
    items = legend.replay_legend(log.metadata.class_names, alignment is not None, truth_labels)
    if alignment is not None:
        reference = np.vstack([truth, true_landmarks])
    else:
        detections = [(m.pose_index, d) for m in log.detections for d in m.detections]
        seen = seen_points(
            np.array([i for i, _ in detections], dtype=int),
            np.array([(d.bearing, d.elevation, d.range) for _, d in detections]).reshape(-1, 3),
            dead_reckoned,
        )
        reference = np.vstack([odometry, seen])
    board, extent = board_below(reference, items, aspect)
    return MapFrame(
        alignment, indices, truth, odometry, truth_labels, items, board, extent, reference
    )
