"""Where the object in a box is, from stereo: range, bearing and elevation with a covariance.

Matching is restricted to the box's central part (background and ground show at a box's
edges): semi-global matching (OpenCV's SGBM, 3-way) on crops of both images that hold it, a
margin, and `max_disparity` columns to its left (where the right image's matches lie). Dense
matching of whole frames does not fit the frame budget (~174 ms for 1280x720 at 128
disparities, measured). A disparity is kept only where matching back, right image to left,
gives the same one: SGBM's own check does not search the right image, and near the left border,
where the left image sees what the right one does not, it lets through wrong matches of a few
pixels, which put objects 20 times too far. The box's disparity is the median of the valid
ones; the box centre and that disparity make one stereo pixel `(u, v, d)`, triangulated in the
camera optical frame (x right, y down, z forward). A box whose central part would lie left of
the right image at that disparity gets no range: its object cannot be seen by both cameras.

Covariance: `(u, v, d)` independent, with `sigma_u = hypot(center_sigma, center_sigma_fraction *
box width)` (boxes are drawn less precisely the larger they are), likewise `sigma_v` with the
height, and `sigma_d = hypot(disparity_sigma, spread)`, the spread being that of the central
part's disparities (interquartile range over 1.349, a Gaussian's sigma): a second surface in a
quarter of the part or more, or a slanted one, makes the median's meaning uncertain, an occluder
in a few of its pixels does not. Propagated to first order, so the depth's standard deviation
is `z^2 sigma_d / (f b)`. `body_measurement` turns the camera-frame point into the contract's
(bearing, elevation, range) in the body frame (x forward, y left, z up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.datasets.camera import BODY_FROM_CAMERA, StereoIntrinsics
from pipeline.frontend.config import StereoRangeConfig
from pipeline.frontend.geometry import (
    camera_point_measurement,
    triangulate,
    triangulation_jacobian,
)

BODY_FROM_CAMERA_ROTATION = BODY_FROM_CAMERA[:3, :3]
BBox = tuple[float, float, float, float]  # u_min, v_min, u_max, v_max (pixels)
# Matching back from the right image must land within this of the left pixel (px): SGBM's own
# tolerance (disp12MaxDiff).
LEFT_RIGHT_PX = 1.0


# --- pure math -------------------------------------------------------------------------------


def depth_from_disparity(disparity: float, fx: float, baseline: float) -> float:
    """Depth along the optical axis (m) of a disparity (px): `z = f b / d`."""
    return fx * baseline / disparity


def depth_sigma(depth: float, disparity_sigma: float, fx: float, baseline: float) -> float:
    """Standard deviation of the depth from that of the disparity: `z^2 sigma_d / (f b)`."""
    return depth**2 * disparity_sigma / (fx * baseline)


def pixel_bearing_elevation(
    u: float, v: float, intrinsics: StereoIntrinsics
) -> tuple[float, float]:
    """Bearing and elevation in the body frame of the ray through left-image pixel (u, v): they
    do not depend on the depth. Right of the principal point is a negative bearing, below it a
    negative elevation."""
    ray_body = BODY_FROM_CAMERA_ROTATION @ np.array(
        [(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy, 1.0]
    )
    bearing = math.atan2(ray_body[1], ray_body[0])
    elevation = math.atan2(ray_body[2], math.hypot(ray_body[0], ray_body[1]))
    return bearing, elevation


def box_pixel_covariance(bbox: BBox, config: StereoRangeConfig, spread: float = 0.0) -> np.ndarray:
    """Covariance of the box's stereo pixel (u, v, d): centre noise grows with the box, and
    the disparity's with the spread of the box's disparities."""
    width, height = bbox[2] - bbox[0], bbox[3] - bbox[1]
    sigma_u = math.hypot(config.center_sigma, config.center_sigma_fraction * width)
    sigma_v = math.hypot(config.center_sigma, config.center_sigma_fraction * height)
    sigma_d = math.hypot(config.disparity_sigma, spread)
    return np.diag([sigma_u**2, sigma_v**2, sigma_d**2])


def stereo_point(
    uvd: np.ndarray, uvd_covariance: np.ndarray, intrinsics: StereoIntrinsics
) -> tuple[np.ndarray, np.ndarray]:
    """A stereo pixel and its covariance to a camera-frame point and its 3x3 covariance."""
    uvd = np.asarray(uvd, float)
    jacobian = triangulation_jacobian(uvd, intrinsics)
    covariance = jacobian @ np.asarray(uvd_covariance, float) @ jacobian.T
    return triangulate(uvd, intrinsics), 0.5 * (covariance + covariance.T)


def camera_to_body(point: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A camera-frame point and covariance in the body frame (rotation only: same origin)."""
    r = BODY_FROM_CAMERA_ROTATION
    return r @ np.asarray(point, float), r @ np.asarray(covariance, float) @ r.T


def body_measurement(point: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The contract's (bearing, elevation, range) in the body frame and its 3x3 covariance, from
    a camera-frame point and covariance."""
    return camera_point_measurement(point, covariance)


# --- matching inside a box -------------------------------------------------------------------


def _gray(image: np.ndarray) -> np.ndarray:
    import cv2

    if image.ndim == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return image


def _matcher(config: StereoRangeConfig):
    import cv2

    return cv2.StereoSGBM.create(
        minDisparity=0,
        numDisparities=config.max_disparity,
        blockSize=config.block_size,
        P1=8 * config.block_size**2,
        P2=32 * config.block_size**2,
        disp12MaxDiff=int(LEFT_RIGHT_PX),
        uniquenessRatio=config.uniqueness_ratio,
        mode=cv2.StereoSGBM_MODE_SGBM_3WAY,
    )


def _columns(image: np.ndarray, rows: slice, first: int, last: int) -> np.ndarray:
    """Columns `first` to `last` (exclusive) of `image`'s `rows`, black where outside it."""
    import cv2

    width = image.shape[1]
    crop = image[rows, max(0, first) : min(width, last)]
    return cv2.copyMakeBorder(
        crop, 0, 0, max(0, -first), max(0, last - width), cv2.BORDER_CONSTANT, value=0
    )


def _disparities(matcher, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    fixed = matcher.compute(left, right)  # 1/16 px; negative = no match
    out = fixed.astype(np.float64) / 16.0
    out[fixed < 0] = np.nan
    return out


def pixel_box(bbox: BBox, width: int, height: int) -> tuple[int, int, int, int]:
    """A box's pixels: its rows and columns rounded outwards and clipped to the image."""
    u0, v0 = max(0, math.floor(bbox[0])), max(0, math.floor(bbox[1]))
    u1, v1 = min(width, math.ceil(bbox[2])), min(height, math.ceil(bbox[3]))
    return u0, v0, max(u0, u1), max(v0, v1)


def central_box(bbox: BBox, fraction: float, width: int, height: int) -> tuple[int, int, int, int]:
    """The central `fraction` of a box's pixel rows and columns (at least one of each):
    background and ground show at a box's edges."""
    u0, v0, u1, v1 = pixel_box(bbox, width, height)
    keep_u, keep_v = max(1, round((u1 - u0) * fraction)), max(1, round((v1 - v0) * fraction))
    u0, v0 = u0 + (u1 - u0 - keep_u) // 2, v0 + (v1 - v0 - keep_v) // 2
    return u0, v0, u0 + keep_u, v0 + keep_v


def box_disparities(
    left: np.ndarray, right: np.ndarray, bbox: BBox, config: StereoRangeConfig
) -> np.ndarray:
    """Disparities (px) of the box's pixels (`pixel_box`), NaN where SGBM found none or
    matching back from the right image disagrees by more than a pixel."""
    left, right = _gray(left), _gray(right)
    height, width = left.shape
    u0, v0, u1, v1 = pixel_box(bbox, width, height)
    if u1 <= u0 or v1 <= v0:
        return np.empty((0, 0))
    m, d_max = config.margin, config.max_disparity
    rows = slice(max(0, v0 - m), min(height, v1 + m))
    box_rows = slice(v0 - rows.start, v1 - rows.start)
    matcher = _matcher(config)
    # Left to right: the crop starts `d_max` columns left of the box (SGBM leaves that many
    # columns unmatched); left of the image, both crops are black.
    start = u0 - m - d_max
    forward = _disparities(
        matcher, _columns(left, rows, start, u1 + m), _columns(right, rows, start, u1 + m)
    )[box_rows, u0 - start : u1 - start]
    # Right to left, mirrored so that SGBM can do it: the right image's pixels from d_max left
    # of the box to its end, each searched up to d_max to its right in the left image.
    first, last = u0 - m - d_max, u1 + m + d_max
    mirrored = [_columns(image, rows, first, last)[:, ::-1] for image in (right, left)]
    backward = _disparities(matcher, *mirrored)[:, ::-1][box_rows]
    # Keep a left pixel's disparity d where the right pixel it matches, u - d, matches back
    # to within a pixel of it.
    columns = np.arange(u0, u1)[None, :] - np.nan_to_num(forward, nan=0.0)
    index = np.clip(np.rint(columns).astype(int) - first, 0, backward.shape[1] - 1)
    back = np.take_along_axis(backward, index, axis=1)
    agree = np.isfinite(forward) & (columns >= 0) & (np.abs(back - forward) <= LEFT_RIGHT_PX)
    return np.where(agree, forward, np.nan)


@dataclass(frozen=True)
class BoxDisparity:
    disparity: float  # median over the valid pixels (px)
    spread: float  # their spread: the interquartile range over 1.349, a Gaussian's sigma (px)
    valid: int
    total: int


# A Gaussian's quartiles lie this many sigmas apart.
QUARTILE_RANGE_SIGMAS = 1.349


def robust_disparity(disparities: np.ndarray, config: StereoRangeConfig) -> BoxDisparity | None:
    """The median of valid disparities (at least `min_disparity`), or None when fewer than
    `min_valid_fraction` of the pixels have one."""
    values = disparities[np.isfinite(disparities) & (disparities >= config.min_disparity)]
    if values.size == 0 or values.size < config.min_valid_fraction * disparities.size:
        return None
    low, median, high = np.percentile(values, [25.0, 50.0, 75.0])
    spread = float(high - low) / QUARTILE_RANGE_SIGMAS
    return BoxDisparity(float(median), spread, int(values.size), int(disparities.size))


@dataclass(frozen=True)
class BoxRange:
    """The object in a box, in the left camera's optical frame."""

    point: np.ndarray  # (3,) m
    covariance: np.ndarray  # (3, 3)
    uvd: np.ndarray  # the stereo pixel it came from: box centre, median disparity
    disparity: BoxDisparity

    @property
    def range(self) -> float:
        return float(np.linalg.norm(self.point))


def measure_box(
    left: np.ndarray,
    right: np.ndarray,
    bbox: BBox,
    intrinsics: StereoIntrinsics,
    config: StereoRangeConfig,
) -> BoxRange | None:
    """Stereo range of the object in `bbox` (left image) from its central part, or None where
    that has too few matches, or would lie left of the right image at their disparity."""
    height, width = left.shape[:2]
    central = central_box(bbox, config.central_fraction, width, height)
    found = robust_disparity(box_disparities(left, right, central, config), config)
    if found is None or central[0] < found.disparity:
        return None
    uvd = np.array([(bbox[0] + bbox[2]) / 2.0, (bbox[1] + bbox[3]) / 2.0, found.disparity])
    pixel_covariance = box_pixel_covariance(bbox, config, found.spread)
    point, covariance = stereo_point(uvd, pixel_covariance, intrinsics)
    point, covariance = surface_to_centre(
        point, covariance, config.surface_to_centre, config.surface_to_centre_sigma
    )
    return BoxRange(point, covariance, uvd, found)


def surface_to_centre(
    point: np.ndarray, covariance: np.ndarray, offset: float, sigma: float
) -> tuple[np.ndarray, np.ndarray]:
    """Stereo finds the visible surface; the landmark is the object's centre, `offset` further
    along the ray, known to `sigma` along it."""
    ray = point / np.linalg.norm(point)
    return point + offset * ray, covariance + sigma**2 * np.outer(ray, ray)
