"""Routes through a grid of streets or corridors, driven as keyframed planar poses.

Shared by the scenarios whose worlds are grids (`indoor-tags`, `city-grid`): a junction walk
that covers every street and then drives them again (the loops of a run), and a smooth drive
along it at constant speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np

from data_tools.scenarios.config import Distance, Length, Spread
from data_tools.scenarios.geometry import pose_from_rotation_translation, yaw_rotation
from pipeline.errors import InputError
from pipeline.settings import positive

DENSE_STEP_M = 0.05  # resolution of the route before smoothing


@dataclass(frozen=True)
class RouteConfig:
    length_m: Length
    speed_mps: Annotated[float, positive(100.0)]
    keyframe_period_s: Annotated[float, positive(3600.0)]
    corner_smoothing_m: Distance
    wander_amplitude_m: Spread
    wander_wavelength_m: Length


def junction_route(
    xs: tuple[float, ...], ys: tuple[float, ...], length: float, rng: np.random.Generator
) -> np.ndarray:
    """Junctions of the grid `xs` x `ys` visited, (K, 2), until the route is at least `length`
    long.

    At each junction the robot takes one of the streets it has driven least (never straight
    back), so all streets are covered and then driven again: the loops of the run.
    """
    node, previous = (0, 0), None
    driven: dict[frozenset, int] = {}
    route = [node]
    total = 0.0
    while total < length:
        i, j = node
        neighbours = [
            (a, b)
            for a, b in ((i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1))
            if 0 <= a < len(xs) and 0 <= b < len(ys) and (a, b) != previous
        ]
        counts = [driven.get(frozenset((node, n)), 0) for n in neighbours]
        least = [n for n, c in zip(neighbours, counts, strict=True) if c == min(counts)]
        step = least[int(rng.integers(len(least)))]
        driven[frozenset((node, step))] = driven.get(frozenset((node, step)), 0) + 1
        total += abs(xs[step[0]] - xs[i]) + abs(ys[step[1]] - ys[j])
        previous, node = node, step
        route.append(node)
    return np.array([[xs[i], ys[j]] for i, j in route])


def resample_polyline(vertices: np.ndarray, step: float) -> np.ndarray:
    """Points every `step` metres along a polyline."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(vertices, axis=0), axis=1))])
    grid = np.arange(0.0, s[-1], step)
    return np.stack([np.interp(grid, s, vertices[:, k]) for k in range(vertices.shape[1])], -1)


def smooth_path(points: np.ndarray, window: int) -> np.ndarray:
    """Moving average over `window` points: rounds the corners as a driven robot would."""
    if window <= 1:
        return points
    kernel = np.ones(window) / window
    padded = np.pad(points, ((window // 2, window - 1 - window // 2), (0, 0)), mode="edge")
    return np.stack([np.convolve(padded[:, k], kernel, mode="valid") for k in range(2)], -1)


def arc_length(points: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])


def drive(vertices: np.ndarray, route: RouteConfig, scenario: str) -> tuple[np.ndarray, np.ndarray]:
    """Keyframe times (ns) and planar body poses (N, 4, 4) along a polyline of vertices."""
    dense = resample_polyline(vertices, DENSE_STEP_M)
    dense = smooth_path(dense, round(route.corner_smoothing_m / DENSE_STEP_M))
    tangent = np.gradient(dense, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    s = arc_length(dense)
    weave = route.wander_amplitude_m * np.sin(2 * np.pi * s / route.wander_wavelength_m)
    dense = dense + weave[:, None] * np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    s = arc_length(dense)
    heading = np.unwrap(np.arctan2(*np.gradient(dense, axis=0)[:, ::-1].T))
    step = route.speed_mps * route.keyframe_period_s
    if s[-1] < route.length_m:
        raise InputError(f"{scenario} config: the route is shorter than route.length_m")
    count = math.floor(route.length_m / step + 1e-9) + 1
    s_key = np.arange(count) * step
    xy = np.stack([np.interp(s_key, s, dense[:, 0]), np.interp(s_key, s, dense[:, 1])], -1)
    yaw = np.interp(s_key, s, heading)
    translation = np.concatenate([xy, np.zeros((count, 1))], axis=1)
    poses = pose_from_rotation_translation(yaw_rotation(yaw), translation)
    times_ns = np.round(np.arange(count) * route.keyframe_period_s * 1e9).astype(np.int64)
    return times_ns, poses


MAX_KEYFRAMES = 10**6  # a route's keyframes at the most: a log of them is about 1 GB


def check_route(r: RouteConfig, path, require) -> None:
    """What the keys' own ranges cannot say: the keyframes the route makes."""
    keyframes = r.length_m / (r.speed_mps * r.keyframe_period_s)
    require(
        keyframes <= MAX_KEYFRAMES,
        path,
        f"route.length_m / (speed_mps * keyframe_period_s) must be <= {MAX_KEYFRAMES} keyframes,"
        f" got {keyframes:.3g} ({r.length_m:g} m at {r.speed_mps:g} m/s every"
        f" {r.keyframe_period_s:g} s)",
    )
