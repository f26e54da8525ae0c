"""Procedural grey textures: irregular, corner-rich and never periodic.

Visual odometry needs corners everywhere, and stereo matching must not find the same patch
twice along an epipolar line, so every texture is multi-octave noise plus randomly placed and
sized shapes (no grids, no tiling). Sizes are in metres; an image has `texels_per_metre`
texels a metre, row 0 at the top of the surface as seen from its front.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

Rng = np.random.Generator


def fractal_noise(
    rng: Rng, height: int, width: int, feature_texels: float, octaves: int = 4, gain: float = 0.55
) -> np.ndarray:
    """Smooth noise (float32, about unit standard deviation) with features from
    `feature_texels` down, halving the feature size and scaling by `gain` each octave."""
    total = np.zeros((height, width), dtype=np.float32)
    weight = 0.0
    for octave in range(octaves):
        cell = feature_texels / 2**octave
        amplitude = gain**octave
        if cell < 1.5:
            layer = rng.standard_normal((height, width), dtype=np.float32)
        else:
            grid_h = math.ceil(height / cell) + 2
            grid_w = math.ceil(width / cell) + 2
            grid = rng.standard_normal((grid_h, grid_w), dtype=np.float32)
            big = (math.ceil(grid_w * cell), math.ceil(grid_h * cell))
            layer = cv2.resize(grid, big, interpolation=cv2.INTER_CUBIC)[:height, :width]
        total += amplitude * layer
        weight += amplitude**2
    return total / np.float32(math.sqrt(weight))


class Canvas:
    """A float32 grey image addressed in metres: x to the right, y down from the top edge."""

    def __init__(self, width_m: float, height_m: float, texels_per_metre: float, value: float):
        self.scale = texels_per_metre
        rows = max(2, round(height_m * texels_per_metre))
        cols = max(2, round(width_m * texels_per_metre))
        self.image = np.full((rows, cols), value, dtype=np.float32)
        self.width_m, self.height_m = width_m, height_m

    def _px(self, x: float, y: float) -> tuple[int, int]:
        return round(x * self.scale), round(y * self.scale)

    def rect(self, x0: float, y0: float, x1: float, y1: float, value: float) -> None:
        cv2.rectangle(self.image, self._px(x0, y0), self._px(x1, y1), float(value), -1)

    def frame(self, x0: float, y0: float, x1: float, y1: float, value: float, width_m: float):
        thickness = max(1, round(width_m * self.scale))
        cv2.rectangle(self.image, self._px(x0, y0), self._px(x1, y1), float(value), thickness)

    def circle(self, x: float, y: float, radius: float, value: float, width_m: float = -1.0):
        thickness = -1 if width_m < 0 else max(1, round(width_m * self.scale))
        radius_px = max(1, round(radius * self.scale))
        cv2.circle(self.image, self._px(x, y), radius_px, float(value), thickness)

    def polygon(self, points: np.ndarray, value: float) -> None:
        pixels = np.round(np.asarray(points) * self.scale).astype(np.int32)
        cv2.fillPoly(self.image, [pixels], float(value))

    def polyline(self, points: np.ndarray, value: float, width_m: float) -> None:
        pixels = np.round(np.asarray(points) * self.scale).astype(np.int32)
        thickness = max(1, round(width_m * self.scale))
        cv2.polylines(self.image, [pixels], False, float(value), thickness)

    def add_noise(self, rng: Rng, amplitude: float, feature_m: float, octaves: int = 4) -> None:
        rows, cols = self.image.shape
        feature = max(feature_m * self.scale, 1.0)
        self.image += amplitude * fractal_noise(rng, rows, cols, feature, octaves)

    def add_grain(self, rng: Rng, amplitude: float) -> None:
        self.image += amplitude * rng.standard_normal(self.image.shape, dtype=np.float32)

    def to_uint8(self) -> np.ndarray:
        return np.clip(np.round(self.image), 0, 255).astype(np.uint8)


def _rotated_rectangle(centre, length: float, width: float, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    half = np.array([[-length, -width], [length, -width], [length, width], [-length, width]]) / 2
    return half @ np.array([[c, s], [-s, c]]) + np.asarray(centre)


def _random_shape(canvas: Canvas, rng: Rng, x: float, y: float, size: float, value: float):
    """One of a few shapes at a random orientation: corners of many angles for the trackers."""
    kind = rng.integers(0, 4)
    if kind == 0:
        angle = rng.uniform(0, math.pi)
        canvas.polygon(_rotated_rectangle((x, y), size, size * rng.uniform(0.2, 1.0), angle), value)
    elif kind == 1:
        canvas.circle(x, y, size / 2, value)
    elif kind == 2:
        points = np.array([x, y]) + rng.uniform(-size / 2, size / 2, size=(3, 2))
        canvas.polygon(points, value)
    else:
        steps = np.cumsum(rng.uniform(-size / 2, size / 2, size=(rng.integers(2, 5), 2)), axis=0)
        canvas.polyline(np.array([x, y]) + steps, value, size * rng.uniform(0.04, 0.12))


def asphalt(rng: Rng, width_m: float, height_m: float, texels_per_metre: float) -> np.ndarray:
    """Road surface: mottled grey with grain, repair patches, cracks, pebbles and paint marks."""
    canvas = Canvas(width_m, height_m, texels_per_metre, rng.uniform(95, 115))
    area = width_m * height_m
    for _ in range(rng.poisson(area / 30)):
        centre = rng.uniform((0, 0), (width_m, height_m))
        shape = _rotated_rectangle(
            centre, rng.uniform(0.5, 3.0), rng.uniform(0.4, 2.0), rng.uniform(0, math.pi)
        )
        canvas.polygon(shape, rng.uniform(70, 140))
    canvas.add_noise(rng, 12.0, 0.8, octaves=3)
    canvas.add_noise(rng, 8.0, 0.12, octaves=3)
    for _ in range(rng.poisson(area / 12)):
        start = rng.uniform((0, 0), (width_m, height_m))
        steps = rng.normal(0, 0.25, size=(rng.integers(3, 10), 2))
        canvas.polyline(start + np.cumsum(steps, axis=0), rng.uniform(35, 70), 0.015)
    for _ in range(rng.poisson(area * 3)):
        x, y = rng.uniform((0, 0), (width_m, height_m))
        canvas.circle(x, y, rng.uniform(0.01, 0.035), rng.choice([rng.uniform(40, 70), 165.0]))
    for _ in range(rng.poisson(area / 60)):
        centre = rng.uniform((0, 0), (width_m, height_m))
        shape = _rotated_rectangle(
            centre, rng.uniform(0.5, 3.0), rng.uniform(0.1, 0.3), rng.uniform(0, math.pi)
        )
        canvas.polygon(shape, rng.uniform(190, 225))
    for _ in range(rng.poisson(area / 150)):
        x, y = rng.uniform((0, 0), (width_m, height_m))
        radius = rng.uniform(0.3, 0.4)
        canvas.circle(x, y, radius, rng.uniform(60, 90))
        canvas.circle(x, y, radius, 45.0, width_m=0.05)
    canvas.add_grain(rng, 7.0)
    return canvas.to_uint8()


def _window(canvas: Canvas, rng: Rng, x0: float, top: float, width: float, height: float):
    rows, cols = canvas.image.shape
    row = min(max(round((top + height + 0.2) * canvas.scale), 0), rows - 1)
    wall = float(canvas.image[row, min(max(round(x0 * canvas.scale), 0), cols - 1)])
    frame = rng.uniform(200, 240) if rng.random() < 0.6 else rng.uniform(30, 60)
    canvas.rect(x0, top, x0 + width, top + height, rng.uniform(25, 75))
    if rng.random() < 0.5:
        blind = rng.uniform(0.1, 0.8) * height
        canvas.rect(x0, top, x0 + width, top + blind, rng.uniform(150, 215))
    if rng.random() < 0.6:
        mullion = x0 + width * rng.uniform(0.35, 0.65)
        canvas.rect(mullion - 0.03, top, mullion + 0.03, top + height, frame)
    canvas.frame(x0, top, x0 + width, top + height, frame, 0.06)
    canvas.rect(x0 - 0.08, top + height, x0 + width + 0.08, top + height + 0.08, wall * 0.7)


def facade(rng: Rng, width_m: float, height_m: float, texels_per_metre: float) -> np.ndarray:
    """Building fronts side by side: each its own shade, storey height and irregular windows."""
    canvas = Canvas(width_m, height_m, texels_per_metre, 150.0)
    x = -rng.uniform(0, 6)
    while x < width_m:
        building = rng.uniform(6, 16)
        left, right = max(x, 0.0), min(x + building, width_m)
        canvas.rect(left, 0, right, height_m, rng.uniform(85, 200))
        storey = rng.uniform(2.8, 3.6)
        sill = rng.uniform(0.6, 1.1)
        bottom = height_m
        while bottom - storey > -0.5:
            wx = x + rng.uniform(0.4, 1.6)
            while wx < x + building - 1.2:
                width = rng.uniform(0.7, 1.8)
                height = rng.uniform(1.0, min(1.9, storey - sill - 0.3))
                top = bottom - sill - height
                if bottom == height_m and rng.random() < 0.3:  # a door on the ground floor
                    height = rng.uniform(2.0, 2.4)
                    top = bottom - height
                _window(canvas, rng, wx, top, width, height)
                wx += width + rng.uniform(0.6, 2.4)
            bottom -= storey
        x += building
    for _ in range(rng.poisson(width_m / 3)):  # signs and posters at street level
        cx, cy = rng.uniform(0, width_m), height_m - rng.uniform(0.5, 2.8)
        _random_shape(canvas, rng, cx, cy, rng.uniform(0.2, 0.9), rng.uniform(20, 240))
    for _ in range(rng.poisson(width_m * height_m * 1.5)):  # stains, vents, marks, graffiti
        cx, cy = rng.uniform(0, width_m), rng.uniform(0, height_m)
        shade = float(
            canvas.image[
                min(int(cy * canvas.scale), canvas.image.shape[0] - 1),
                min(int(cx * canvas.scale), canvas.image.shape[1] - 1),
            ]
        )
        size = math.exp(rng.uniform(math.log(0.05), math.log(0.4)))
        _random_shape(canvas, rng, cx, cy, size, shade + rng.choice([-1, 1]) * rng.uniform(25, 60))
    canvas.rect(0, height_m - rng.uniform(0.3, 0.6), width_m, height_m, rng.uniform(60, 100))
    canvas.add_noise(rng, 10.0, 1.5, octaves=3)
    canvas.add_noise(rng, 9.0, 0.2, octaves=4)
    canvas.add_grain(rng, 3.0)
    return canvas.to_uint8()


def clutter(
    rng: Rng,
    width_m: float,
    height_m: float,
    texels_per_metre: float,
    base: float,
    shapes_per_m2: float,
) -> np.ndarray:
    """Indoor surfaces: a mottled base covered with random shapes (posters, marks, stains)."""
    canvas = Canvas(width_m, height_m, texels_per_metre, base)
    canvas.add_noise(rng, 18.0, 1.0, octaves=4)
    for _ in range(rng.poisson(width_m * height_m * shapes_per_m2)):
        x, y = rng.uniform((0, 0), (width_m, height_m))
        # Log-uniform sizes: as many small marks (close range) as large ones (far away).
        size = math.exp(rng.uniform(math.log(0.03), math.log(0.8)))
        _random_shape(canvas, rng, x, y, size, rng.uniform(15, 245))
    canvas.add_noise(rng, 9.0, 0.15, octaves=3)
    canvas.add_grain(rng, 3.0)
    return canvas.to_uint8()


def _paint(rng: Rng, canvas: Canvas, paint: float) -> None:
    canvas.image[:] = paint
    canvas.add_noise(rng, 5.0, 0.4, octaves=3)


def car_textures(
    rng: Rng,
    length: float,
    width: float,
    body_height: float,
    cabin: tuple[float, float, float],
    texels_per_metre: float,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Face images of a car built from two boxes: the body (with wheels and lights) and the
    cabin (windows). `cabin` = (length, width, height). Returns (body faces, cabin faces)."""
    paint = rng.uniform(40, 225)
    tpm = texels_per_metre
    body: dict[str, np.ndarray] = {}
    for side in ("left", "right"):
        c = Canvas(length, body_height, tpm, paint)
        _paint(rng, c, paint)
        h = body_height
        c.rect(0, h - 0.16, length, h, 30.0)  # the shadow under the sills
        crease = h * rng.uniform(0.35, 0.5)
        c.rect(0, crease, length, crease + 0.02, paint * 0.75)
        for door in rng.uniform(0.35, 0.65) * length + np.array([-0.55, 0.5]):
            c.rect(door, 0.05, door + 0.012, h - 0.2, paint * 0.5)
            c.rect(door - 0.25, crease - 0.12, door - 0.1, crease - 0.08, paint * 0.45)
        for axle in (0.18 * length, 0.8 * length):
            c.circle(axle, h - 0.33, 0.33, 22.0)
            c.circle(axle, h - 0.33, 0.19, rng.uniform(110, 170))
            for k in range(5):
                angle = 2 * math.pi * k / 5 + rng.uniform(0, 1)
                tip = (axle + 0.17 * math.cos(angle), h - 0.33 + 0.17 * math.sin(angle))
                c.polyline(np.array([(axle, h - 0.33), tip]), 45.0, 0.03)
            c.circle(axle, h - 0.33, 0.05, 60.0)
        body[side] = c.to_uint8()
    for end in ("front", "back"):
        c = Canvas(width, body_height, tpm, paint)
        _paint(rng, c, paint)
        lamp = 225.0 if end == "front" else 70.0
        for x0 in (0.08, width - 0.38):
            c.rect(x0, 0.08, x0 + 0.3, 0.22, lamp)
            c.frame(x0, 0.08, x0 + 0.3, 0.22, 35.0, 0.02)
        if end == "front":
            c.rect(0.45, 0.12, width - 0.45, 0.3, 28.0)
        c.rect(0.02, body_height - 0.45, width - 0.02, body_height - 0.3, paint * 0.6)
        c.rect(width / 2 - 0.26, body_height - 0.42, width / 2 + 0.26, body_height - 0.31, 225.0)
        for k in range(6):
            x = width / 2 - 0.22 + 0.075 * k
            c.rect(x, body_height - 0.4, x + 0.04, body_height - 0.33, 30.0)
        c.rect(0, body_height - 0.16, width, body_height, 30.0)
        body[end] = c.to_uint8()
    c = Canvas(width, length, tpm, paint)
    _paint(rng, c, paint)
    body["top"] = c.to_uint8()

    cabin_length, cabin_width, cabin_height = cabin
    glass = rng.uniform(25, 60)
    cabin_faces: dict[str, np.ndarray] = {}
    for side in ("left", "right"):
        c = Canvas(cabin_length, cabin_height, tpm, paint)
        _paint(rng, c, paint)
        pillar = rng.uniform(0.4, 0.6) * cabin_length
        c.rect(0.12, 0.08, pillar - 0.05, cabin_height - 0.05, glass)
        c.rect(pillar + 0.05, 0.08, cabin_length - 0.12, cabin_height - 0.05, glass + 10)
        cabin_faces[side] = c.to_uint8()
    for end in ("front", "back"):
        c = Canvas(cabin_width, cabin_height, tpm, paint)
        _paint(rng, c, paint)
        c.rect(0.1, 0.07, cabin_width - 0.1, cabin_height - 0.04, glass)
        c.polygon(
            np.array([[0.3, 0.07], [0.55, 0.07], [0.35, cabin_height - 0.04]]), glass + 40
        )  # a reflection streak
        cabin_faces[end] = c.to_uint8()
    c = Canvas(cabin_width, cabin_length, tpm, paint)
    _paint(rng, c, paint)
    cabin_faces["top"] = c.to_uint8()
    return body, cabin_faces


def crate_textures(
    rng: Rng, size: tuple[float, float, float], texels_per_metre: float
) -> dict[str, np.ndarray]:
    """Faces of a wooden crate: planks of uneven width and a printed label."""
    length, width, height = size
    tone = rng.uniform(110, 190)
    faces: dict[str, np.ndarray] = {}
    for face, (w, h) in {
        "front": (width, height),
        "back": (width, height),
        "left": (length, height),
        "right": (length, height),
        "top": (width, length),
    }.items():
        c = Canvas(w, h, texels_per_metre, tone)
        y = 0.0
        while y < h:
            plank = rng.uniform(0.08, 0.2)
            c.rect(0, y, w, y + plank, tone + rng.uniform(-25, 25))
            c.rect(0, y + plank - 0.008, w, y + plank, tone * 0.45)
            y += plank
        c.add_noise(rng, 8.0, 0.05, octaves=3)
        c.frame(0, 0, w, h, tone * 0.55, 0.05)
        if face != "top" and rng.random() < 0.8:
            x0, y0 = rng.uniform(0.1, 0.4) * w, rng.uniform(0.1, 0.4) * h
            x1, y1 = x0 + 0.4 * w, y0 + 0.35 * h
            c.rect(x0, y0, x1, y1, 230.0)
            for _ in range(6):
                _random_shape(
                    c, rng, rng.uniform(x0, x1), rng.uniform(y0, y1), 0.2 * (y1 - y0), 30.0
                )
        faces[face] = c.to_uint8()
    return faces
