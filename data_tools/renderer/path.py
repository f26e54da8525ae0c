"""The path: laps of a rounded rectangle around a block, with gentle weaving and body motion.

The vehicle drives counter-clockwise (the block on its left), slows for the corners to keep
its yaw rate bounded, and drives more than one lap so that it sees the start again: the loop
closures SLAM is there to find. Poses are world-from-body (x forward, y left, z up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from data_tools.renderer.config import PathConfig
from data_tools.renderer.geometry import make_transform, rotation_from_yaw_pitch_roll


@dataclass(frozen=True)
class Segment:
    """A piece of planar path: start point and heading, length, constant curvature (1/m)."""

    start: tuple[float, float]
    heading: float
    length: float
    curvature: float

    def at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions (N, 2) and headings (N,) at arc lengths `s` from the segment's start."""
        x0, y0 = self.start
        heading = self.heading + self.curvature * s
        if self.curvature == 0.0:
            x = x0 + s * math.cos(self.heading)
            y = y0 + s * math.sin(self.heading)
        else:
            r = 1.0 / self.curvature
            x = x0 + r * (np.sin(heading) - math.sin(self.heading))
            y = y0 - r * (np.cos(heading) - math.cos(self.heading))
        return np.stack([x, y], axis=-1), heading


def rounded_rectangle(half_length: float, half_width: float, radius: float) -> list[Segment]:
    """A counter-clockwise rounded rectangle centred at the origin, starting at the middle of
    its lower side heading +x."""
    if not 0.0 < radius <= min(half_length, half_width):
        raise ValueError("corner radius must be positive and fit the rectangle")
    straight_x, straight_y = 2 * (half_length - radius), 2 * (half_width - radius)
    quarter = math.pi / 2 * radius
    pieces = [(straight_x / 2, 0.0)]
    for straight in (straight_y, straight_x, straight_y):
        pieces += [(quarter, 1.0 / radius), (straight, 0.0)]
    pieces += [(quarter, 1.0 / radius), (straight_x / 2, 0.0)]
    segments = []
    point, heading = (0.0, -half_width), 0.0
    for length, curvature in pieces:
        segment = Segment(point, heading, length, curvature)
        segments.append(segment)
        end, end_heading = segment.at(np.array([length]))
        point, heading = (float(end[0, 0]), float(end[0, 1])), float(end_heading[0])
    return segments


def evaluate(segments: list[Segment], s: np.ndarray):
    """Position (N, 2), heading (N,) and curvature (N,) at arc lengths `s` (wrapping laps)."""
    lengths = np.array([seg.length for seg in segments])
    starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    s = np.mod(s, lengths.sum())
    index = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(segments) - 1)
    position = np.empty((s.size, 2))
    heading = np.empty(s.size)
    curvature = np.empty(s.size)
    for i, segment in enumerate(segments):
        chosen = index == i
        if chosen.any():
            position[chosen], heading[chosen] = segment.at(s[chosen] - starts[i])
            curvature[chosen] = segment.curvature
    return position, heading, curvature


def speed_profile(
    curvature: np.ndarray, step: float, speed: float, max_yaw_rate: float, max_acceleration: float
) -> np.ndarray:
    """Speeds along a path sampled every `step` metres: at most `speed`, at most
    `max_yaw_rate / |curvature|`, changing by at most `max_acceleration` (forward and backward
    passes: braking starts before a corner)."""
    with np.errstate(divide="ignore"):
        limit = np.minimum(speed, max_yaw_rate / np.abs(curvature))
    v = limit.copy()
    for i in range(1, v.size):
        v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2 * max_acceleration * step))
    for i in range(v.size - 2, -1, -1):
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2 * max_acceleration * step))
    return v


@dataclass(frozen=True)
class Motion:
    """How the vehicle drives the loop: the half sizes of the loop's centre line, and the
    drive's own settings (`PathConfig`; see configs/renderer/*.toml for their meaning)."""

    half_length: float
    half_width: float
    drive: PathConfig


def body_poses(motion: Motion, frame_rate: float) -> np.ndarray:
    """World-from-body poses (N, 4, 4), one a frame at `frame_rate`, along the whole drive."""
    drive = motion.drive
    segments = rounded_rectangle(motion.half_length, motion.half_width, drive.corner_radius)
    total = drive.laps * sum(seg.length for seg in segments)
    step = 0.05
    s = np.arange(0.0, total + step, step)
    _, _, curvature = evaluate(segments, s)
    v = speed_profile(curvature, step, drive.speed, drive.max_yaw_rate, drive.max_acceleration)
    elapsed = np.concatenate([[0.0], np.cumsum(2 * step / (v[1:] + v[:-1]))])
    frame_times = np.arange(0.0, elapsed[-1], 1.0 / frame_rate)
    return poses_at(segments, motion, np.interp(frame_times, elapsed, s))


def poses_at(segments: list[Segment], motion: Motion, s: np.ndarray) -> np.ndarray:
    """Poses at arc lengths `s`: the centre line shifted sideways by a slow weave, heading
    along the shifted line, with small pitch and roll (a vehicle's sway) and constant height."""
    position, heading, curvature = evaluate(segments, s)
    drive = motion.drive
    phase = 2 * math.pi * s / drive.weave_wavelength
    offset = drive.weave_amplitude * np.sin(phase)
    offset_rate = drive.weave_amplitude * 2 * math.pi / drive.weave_wavelength * np.cos(phase)
    left = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
    position = position + offset[:, None] * left
    # d/ds of (centre + offset * left) = tangent * (1 - curvature * offset) + offset' * left.
    yaw = heading + np.arctan2(offset_rate, 1.0 - curvature * offset)
    pitch = drive.sway_amplitude * np.sin(2 * math.pi * s / 7.3)
    roll = drive.sway_amplitude * np.sin(2 * math.pi * s / 11.9)
    poses = np.empty((s.size, 4, 4))
    for i in range(s.size):
        rotation = rotation_from_yaw_pitch_roll(yaw[i], pitch[i], roll[i])
        poses[i] = make_transform(rotation, [position[i, 0], position[i, 1], drive.camera_height])
    return poses
