"""What a replay's map is laid out around, from the log alone: the reference trajectories the
estimate is shown against (ground truth aligned at pose 0, odometry alone), the legend below
them, and every point the default eye must see. Pure; read by a run's sink and by the layout of
a comparison of runs, whose maps must match the runs'."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.log.messages import DetectionLog
from pipeline.viz import draw, legend


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


def replay_frame(log: DetectionLog, aspect: float) -> MapFrame:
    """The map of a replay of `log`, in a view of this `aspect` (width / height)."""
    alignment = draw.ground_truth_alignment(log.ground_truth_poses)
    odometry = draw.dead_reckoning(log.odometry)
    indices, truth = np.zeros(0, dtype=int), np.zeros((0, 3))
    if alignment is not None:
        indices, truth = draw.aligned_ground_truth(log.ground_truth_poses, alignment)
    truth_labels = any(
        d.truth_landmark_id is not None for m in log.detections for d in m.detections
    )
    items = legend.replay_legend(log.metadata.class_names, alignment is not None, truth_labels)
    board, extent = board_below(np.vstack([odometry, truth]), items, aspect)
    return MapFrame(alignment, indices, truth, odometry, truth_labels, items, board, extent)
