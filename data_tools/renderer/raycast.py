"""Per-pixel ray casting of a scene of textured rectangles, vectorised in numpy.

For each surface that can be seen (front-facing, in the view frustum) the renderer takes the
pixel rectangle its near-clipped outline covers, intersects every sub-pixel ray there with the
surface's plane, keeps the hits inside the rectangle and nearer than the depth buffer, and
samples the texture at the hit with trilinear mip-mapping (the mip level follows the texel
footprint of the sub-pixel, so far and grazing surfaces are area-filtered rather than
aliased). Sub-pixels are then averaged to pixels: `supersample = 2` puts 2 x 2 rays in a
pixel, which anti-aliases the silhouettes the textures cannot.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from data_tools.renderer.geometry import clip_polygon_near, pixel_ray_coordinates
from data_tools.renderer.scene import Scene, Texture

# A fixed sun, so that faces of different orientation differ in brightness (edges at corners).
LIGHT_DIRECTION = np.array([0.35, 0.55, 0.76]) / np.linalg.norm([0.35, 0.55, 0.76])
AMBIENT = 0.6
DIFFUSE = 0.4
# Hits this far outside a rectangle (in its own [0, 1] coordinates) still count: adjacent
# rectangles then overlap a hair instead of leaving cracks the sky shows through.
EDGE_TOLERANCE = 1e-4
_REMAP_LIMIT = 32767
_REMAP_ROW = 8192


@dataclass(frozen=True)
class PinholeCamera:
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    supersample: int = 2
    near: float = 0.05
    far: float = 1000.0

    @property
    def camera_matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclass(frozen=True, eq=False)
class RenderedView:
    """One rendered camera: `image` (float32 grey, 0..255), `samples_depth` (metres along the
    optical axis at each sub-pixel, inf where only sky shows) and `owner` (the landmark id seen
    at each sub-pixel, -1 for background); sub-pixel arrays are `supersample` times larger."""

    image: np.ndarray
    samples_depth: np.ndarray
    owner: np.ndarray
    supersample: int

    @functools.cached_property
    def depth(self) -> np.ndarray:
        """Depth a pixel: the mean over its sub-pixels (inf where any of them sees sky)."""
        ss = self.supersample
        rows, cols = self.image.shape
        return self.samples_depth.reshape(rows, ss, cols, ss).mean(axis=(1, 3))


class Scratch:
    """Work arrays kept between calls. Allocating big temporaries afresh for every surface
    costs page faults (a third of the run time, measured); views of kept buffers do not."""

    def __init__(self) -> None:
        self._buffers: dict[tuple[str, str], np.ndarray] = {}

    def get(self, name: str, shape: tuple[int, ...], dtype: type = np.float32) -> np.ndarray:
        size = math.prod(shape)
        key = (name, np.dtype(dtype).str)
        buffer = self._buffers.get(key)
        if buffer is None or buffer.size < size:
            buffer = self._buffers[key] = np.empty(size, dtype=dtype)
        return buffer[:size].reshape(shape)


def sample_texture(
    texture: Texture,
    s: np.ndarray,
    t: np.ndarray,
    level: np.ndarray,
    scratch: Scratch | None = None,
) -> np.ndarray:
    """Texture values at coordinates `(s, t)` in [0, 1], trilinear between mip levels.

    `level` is log2 of the texel footprint of each sample at level 0. Arrays of any shape; NaN
    or infinite inputs give some texture value (the caller masks those samples out). The result
    may be a view of `scratch`, valid until its next use.
    """
    scratch = scratch or Scratch()
    shape = np.shape(s)
    top = texture.num_levels - 1
    fraction = scratch.get("fraction", shape)
    np.fmax(level, np.float32(0.0), out=fraction)
    np.fmin(fraction, np.float32(top), out=fraction)
    low_level = scratch.get("low_level", shape, np.int32)
    np.copyto(low_level, fraction, casting="unsafe")
    np.minimum(low_level, max(top - 1, 0), out=low_level)
    fraction -= low_level
    low = _sample_level(texture, s, t, low_level, scratch, "low")
    result = scratch.get("texture", shape)
    if top == 0:
        np.copyto(result, low)
        return result
    low_level += 1
    high = _sample_level(texture, s, t, low_level, scratch, "high")
    np.subtract(high, low, out=result, dtype=np.float32)
    result *= fraction
    result += low
    return result


def _sample_level(
    texture: Texture, s: np.ndarray, t: np.ndarray, level: np.ndarray, scratch: Scratch, tag: str
) -> np.ndarray:
    """Bilinear lookups (the atlas' dtype) in the given mip level (int32) of each sample."""
    shape = np.shape(s)
    width, height = np.int32(texture.width), np.int32(texture.height)
    integer = scratch.get("integer", shape, np.int32)
    # Level k's size and atlas position (see Texture): integer arithmetic, no table lookups.
    # Each axis: m = clamp(coordinate * size - 1/2, 0, size - 1) + offset, where texel centres
    # sit at (i + 1/2) / size and the clamp keeps the bilinear filter inside the level (fmax and
    # fmin also turn NaN into a number).
    maps = []
    for axis, coordinate, full in (("x", s, width), ("y", t, height)):
        size = scratch.get("size", shape)
        np.right_shift(full, level, out=integer)
        np.copyto(size, integer)
        m = scratch.get(f"map_{axis}_{tag}", shape)
        np.multiply(coordinate, size, out=m)
        m -= np.float32(0.5)
        size -= np.float32(1.0)
        np.fmin(m, size, out=m)
        np.fmax(m, np.float32(0.0), out=m)
        if axis == "x":
            np.minimum(level, 1, out=integer)
            integer *= width
        else:
            np.subtract(level, 1, out=integer)
            np.maximum(integer, 0, out=integer)
            np.right_shift(height, integer, out=integer)
            np.subtract(height, integer, out=integer)
        m += integer
        maps.append(m)
    return _remap(
        texture.atlas,
        maps[0],
        maps[1],
        scratch.get(f"remap_{tag}", shape, np.uint8) if texture.atlas.dtype == np.uint8 else None,
    )


def _remap(
    image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, out: np.ndarray | None = None
) -> np.ndarray:
    """Bilinear lookups at pixel coordinates, in the maps' shape and the image's dtype."""
    if map_x.ndim == 2 and max(map_x.shape) < _REMAP_LIMIT:
        return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, dst=out)
    # cv2.remap wants maps under 32767 a side: lay long lists out in rows.
    count = map_x.size
    rows = max(1, math.ceil(count / _REMAP_ROW))
    width = _REMAP_ROW if rows > 1 else count
    padded_x = np.zeros(rows * width, dtype=np.float32)
    padded_y = np.zeros(rows * width, dtype=np.float32)
    padded_x[:count] = map_x.ravel()
    padded_y[:count] = map_y.ravel()
    result = cv2.remap(
        image, padded_x.reshape(rows, width), padded_y.reshape(rows, width), cv2.INTER_LINEAR
    )
    return result.reshape(-1)[:count].reshape(map_x.shape)


class SceneRenderer:
    """Renders grey images of a fixed scene from any camera pose (world-from-camera, 4x4)."""

    def __init__(self, scene: Scene, camera: PinholeCamera):
        self.scene = scene
        self.camera = camera
        surfaces = scene.surfaces
        self._origins = np.array([s.origin for s in surfaces]).reshape(-1, 3)
        self._u = np.array([s.u_edge for s in surfaces]).reshape(-1, 3)
        self._v = np.array([s.v_edge for s in surfaces]).reshape(-1, 3)
        self._corners = np.array([s.corners for s in surfaces]).reshape(-1, 4, 3)
        self._normals = np.array([s.front_normal for s in surfaces]).reshape(-1, 3)
        self._owners = np.array([s.owner for s in surfaces], dtype=np.int32)
        self._textures = [s.texture for s in surfaces]
        self._shade = AMBIENT + DIFFUSE * np.clip(self._normals @ LIGHT_DIRECTION, 0.0, None)
        # Texels a metre along each surface (geometric mean of its two axes): the mip footprint.
        texel_counts = np.array([t.shape for t in self._textures], dtype=np.float64).reshape(-1, 2)
        lengths = np.stack(
            [np.linalg.norm(self._v, axis=1), np.linalg.norm(self._u, axis=1)], axis=1
        )
        self._density = np.sqrt(np.prod(texel_counts / lengths, axis=1))
        ss = camera.supersample
        self._ray_x = pixel_ray_coordinates(camera.width, camera.fx, camera.cx, ss).astype(
            np.float32
        )
        self._ray_y = pixel_ray_coordinates(camera.height, camera.fy, camera.cy, ss).astype(
            np.float32
        )
        self._ray_norm = np.sqrt(
            1.0 + self._ray_x[None, :] ** 2 + self._ray_y[:, None] ** 2, dtype=np.float32
        )
        self._scratch = Scratch()
        # Focal length in sub-pixels, for the texel footprint of one sub-pixel.
        self._focal_ss = math.sqrt(camera.fx * camera.fy) * ss

    def render(self, world_from_camera: np.ndarray) -> RenderedView:
        cam = self.camera
        ss = cam.supersample
        rows, cols = cam.height * ss, cam.width * ss
        depth = np.full((rows, cols), np.inf, dtype=np.float32)
        owner = np.full((rows, cols), -1, dtype=np.int32)
        image = np.zeros((rows, cols), dtype=np.float32)

        rotation, position = world_from_camera[:3, :3], world_from_camera[:3, 3]
        # Row vectors: p_camera = R^T (p_world - t)  ==  (p_world - t) @ R.
        corners = (self._corners - position) @ rotation
        origins = (self._origins - position) @ rotation
        u_axes, v_axes, normals = self._u @ rotation, self._v @ rotation, self._normals @ rotation

        for k in self._visible_order(corners, origins, normals):
            self._draw(
                k, corners[k], origins[k], u_axes[k], v_axes[k], normals[k], depth, owner, image
            )

        sky = np.isinf(depth)
        if sky.any():
            image[sky] = self._sky(rotation, sky)
        if ss > 1:
            image = cv2.resize(image, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
        return RenderedView(image, depth, owner, ss)

    def _visible_order(self, corners, origins, normals) -> np.ndarray:
        """Indices of surfaces that face the camera and touch the frustum, nearest first (so
        that the depth test rejects most hidden pixels before their texture is sampled)."""
        cam = self.camera
        facing = np.einsum("ij,ij->i", normals, origins) < 0
        z = corners[..., 2]
        x, y = corners[..., 0], corners[..., 1]
        x_lo, x_hi = float(self._ray_x[0]), float(self._ray_x[-1])
        y_lo, y_hi = float(self._ray_y[0]), float(self._ray_y[-1])
        outside = (
            np.all(x < x_lo * z, axis=1)
            | np.all(x > x_hi * z, axis=1)
            | np.all(y < y_lo * z, axis=1)
            | np.all(y > y_hi * z, axis=1)
            | np.all(z < cam.near, axis=1)
            | np.all(z > cam.far, axis=1)
        )
        candidates = np.flatnonzero(facing & ~outside)
        nearest = np.maximum(z[candidates].min(axis=1), cam.near)
        return candidates[np.argsort(nearest, kind="stable")]

    def _draw(self, k, corners, origin, u_axis, v_axis, normal, depth, owner, image) -> None:
        cam = self.camera
        ss = cam.supersample
        outline = clip_polygon_near(corners, cam.near)
        if len(outline) < 3:
            return
        # The outline's extent in sub-pixel indices (sub-pixel j has centre (j + 1/2)/ss - 1/2).
        u = (cam.fx * outline[:, 0] / outline[:, 2] + cam.cx + 0.5) * ss - 0.5
        v = (cam.fy * outline[:, 1] / outline[:, 2] + cam.cy + 0.5) * ss - 0.5
        c0, c1 = max(0, math.floor(u.min())), min(depth.shape[1], math.ceil(u.max()) + 1)
        r0, r1 = max(0, math.floor(v.min())), min(depth.shape[0], math.ceil(v.max()) + 1)
        if c0 >= c1 or r0 >= r1:
            return
        xs = self._ray_x[c0:c1]
        ys = self._ray_y[r0:r1, None]
        shape = (r1 - r0, c1 - c0)
        scratch = self._scratch
        n = normal.astype(np.float32)
        # Ray (x, y, 1) meets the plane n.p = n.o at depth Z = n.o / n.(x, y, 1). Every work
        # array is a kept buffer written in place: fewer passes over memory, no page faults.
        facing = np.add(n[1] * ys, n[0] * xs + n[2], out=scratch.get("facing", shape))
        z = scratch.get("z", shape)
        with np.errstate(divide="ignore", invalid="ignore"):
            np.divide(np.float32(normal @ origin), facing, out=z)
        hit = np.greater(z, cam.near, out=scratch.get("hit", shape, np.bool_))
        test = scratch.get("test", shape, np.bool_)
        hit &= np.less(z, depth[r0:r1, c0:c1], out=test)
        # Rectangle coordinates of the hit point Z (x, y, 1): (p - o).axis / |axis|^2, which
        # must lie in [0, 1]: |coordinate - 1/2| <= 1/2.
        coords = []
        inside = scratch.get("inside", shape)
        for name, axis in (("s", u_axis), ("t", v_axis)):
            a = (axis / (axis @ axis)).astype(np.float32)
            coordinate = np.add(a[1] * ys, a[0] * xs + a[2], out=scratch.get(name, shape))
            coordinate *= z
            coordinate -= np.float32(a @ origin)
            np.subtract(coordinate, np.float32(0.5), out=inside)
            np.abs(inside, out=inside)
            hit &= np.less_equal(inside, np.float32(0.5 + EDGE_TOLERANCE), out=test)
            coords.append(coordinate)
        if not hit.any():
            return
        # Texel footprint of a sub-pixel: depth / focal metres, stretched by 1/sqrt(cos) as a
        # compromise between the two axes of the footprint ellipse on a slanted surface. All
        # of the rectangle's box is computed and the hits copied: cheaper than gathering.
        level = inside  # reused
        np.divide(facing, self._ray_norm[r0:r1, c0:c1], out=level)
        np.negative(level, out=level)
        np.fmax(level, np.float32(1e-4), out=level)
        np.sqrt(level, out=level)
        np.divide(z, level, out=level)
        level *= np.float32(self._density[k] / self._focal_ss)
        with np.errstate(divide="ignore", invalid="ignore"):
            np.log2(level, out=level)
        texture = sample_texture(self._textures[k], coords[0], coords[1], level, scratch)
        texture *= np.float32(self._shade[k])
        np.copyto(depth[r0:r1, c0:c1], z, where=hit)
        np.copyto(owner[r0:r1, c0:c1], self._owners[k], where=hit)
        np.copyto(image[r0:r1, c0:c1], texture, where=hit)

    def _sky(self, rotation: np.ndarray, sky: np.ndarray) -> np.ndarray:
        """A smooth gradient, brighter at the horizon: featureless, as a clear sky is."""
        horizon, zenith = self.scene.sky
        rows, cols = np.nonzero(sky)
        x, y = self._ray_x[cols], self._ray_y[rows]
        up = (rotation[2, 0] * x + rotation[2, 1] * y + rotation[2, 2]) / self._ray_norm[rows, cols]
        elevation = np.clip(up, 0.0, 1.0)
        return (horizon + (zenith - horizon) * np.sqrt(elevation)).astype(np.float32)
