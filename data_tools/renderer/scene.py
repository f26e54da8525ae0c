"""The scene: textured planar rectangles, plus the ground truth of the tags and boxes they form.

All geometry is in the world frame (z up, metres). A `Surface` is a rectangle with a texture;
its front is the side from which the texture reads normally (columns left to right along
`u_edge`, rows top to bottom along `v_edge`), so its front normal is `v_edge x u_edge`. Only the
front is drawn.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

# tag36h11 has 587 codes; its tags are 8 cells wide inside a white quiet zone of one cell.
TAG36H11_COUNT = 587
TAG_CELLS = 8
TAG_MARGIN_CELLS = 1


@dataclass(frozen=True, eq=False)
class Texture:
    """A grey texture and its mip pyramid, packed into one atlas image.

    Level k (k >= 1) is level k - 1 area-averaged by 2, so it has `width >> k` x `height >> k`
    texels. Level 0 sits at the atlas' left; level k >= 1 to its right, at x = `width` and
    y = `height - (height >> (k - 1))`. Positions that follow from the level number let a
    renderer sample any mix of levels with integer arithmetic and one lookup.
    """

    atlas: np.ndarray
    width: int
    height: int
    num_levels: int

    @classmethod
    def from_image(cls, image: np.ndarray) -> Texture:
        height, width = image.shape[:2]
        levels = [np.ascontiguousarray(image)]
        while min(levels[-1].shape[:2]) > 1:
            k = len(levels)
            levels.append(
                cv2.resize(levels[-1], (width >> k, height >> k), interpolation=cv2.INTER_AREA)
            )
        extra = levels[1].shape[1] if len(levels) > 1 else 0
        atlas = np.zeros((height, width + extra), dtype=image.dtype)
        texture = cls(atlas, width, height, len(levels))
        for k, level in enumerate(levels):
            x, y = texture.level_offset(k)
            atlas[y : y + level.shape[0], x : x + level.shape[1]] = level
        return texture

    def level_offset(self, k: int) -> tuple[int, int]:
        """(x, y) of level k's top-left texel in the atlas."""
        if k == 0:
            return 0, 0
        return self.width, self.height - (self.height >> (k - 1))

    def level(self, k: int) -> np.ndarray:
        x, y = self.level_offset(k)
        return self.atlas[y : y + (self.height >> k), x : x + (self.width >> k)]

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns) of level 0."""
        return self.height, self.width


@dataclass(frozen=True, eq=False)
class Surface:
    """A textured rectangle `origin + a u_edge + b v_edge`, a and b in [0, 1]."""

    origin: np.ndarray
    u_edge: np.ndarray
    v_edge: np.ndarray
    texture: Texture
    # The landmark this surface belongs to (tag or box id), -1 for the background.
    owner: int = -1

    @property
    def front_normal(self) -> np.ndarray:
        normal = np.cross(self.v_edge, self.u_edge)
        return normal / np.linalg.norm(normal)

    @property
    def corners(self) -> np.ndarray:
        o, u, v = self.origin, self.u_edge, self.v_edge
        return np.array([o, o + u, o + u + v, o + v])


@dataclass(frozen=True, eq=False)
class Tag:
    """An AprilTag (tag36h11) on a surface.

    `size` is the edge of the black square (what detectors call the tag size); the white quiet
    zone around it adds one cell a side. `rotation` is world-from-tag in the AprilTag convention:
    x to the right and y down the printed tag as seen from its front, z into the tag.
    """

    tag_id: int
    size: float
    centre: np.ndarray
    rotation: np.ndarray

    def corners(self) -> np.ndarray:
        """World corners of the black square in the order AprilTag detectors report them.

        Tag-frame `(-s/2, s/2)`, `(s/2, s/2)`, `(s/2, -s/2)`, `(-s/2, -s/2)`: bottom-left,
        bottom-right, top-right, top-left of the upright tag.
        """
        half = self.size / 2
        local = np.array([[-half, half, 0], [half, half, 0], [half, -half, 0], [-half, -half, 0]])
        return local @ self.rotation.T + self.centre


@dataclass(frozen=True, eq=False)
class BoxObject:
    """A box-shaped object: `centre` of its bounding box, `rotation` world-from-object (x along
    the length, y along the width, z up), `size` = (length, width, height)."""

    landmark_id: int
    class_name: str
    centre: np.ndarray
    rotation: np.ndarray
    size: np.ndarray
    style: str


@dataclass(frozen=True, eq=False)
class Scene:
    surfaces: tuple[Surface, ...]
    tags: tuple[Tag, ...] = ()
    objects: tuple[BoxObject, ...] = ()
    # Grey levels of the sky at the horizon and overhead (seen where no surface is hit).
    sky: tuple[float, float] = (200.0, 150.0)


def facing_surface(
    centre: np.ndarray,
    normal: np.ndarray,
    up: np.ndarray,
    width: float,
    height: float,
    texture: Texture,
    owner: int = -1,
) -> Surface:
    """A rectangle centred at `centre` whose front faces `normal`, texture top towards `up`."""
    normal = np.asarray(normal, dtype=np.float64)
    up = np.asarray(up, dtype=np.float64)
    right = np.cross(up, normal)
    u_edge = right / np.linalg.norm(right) * width
    v_edge = -up / np.linalg.norm(up) * height
    origin = np.asarray(centre, dtype=np.float64) - (u_edge + v_edge) / 2
    return Surface(origin, u_edge, v_edge, texture, owner)


def tag_bitmap(tag_id: int, texels_per_cell: int = 24, black: int = 22, white: int = 238):
    """The tag36h11 image of `tag_id` with its one-cell white quiet zone, as uint8.

    OpenCV's `DICT_APRILTAG_36h11` holds each code rotated by 180 degrees relative to the
    AprilTag library's own images (checked bit by bit against apriltag's tag36h11.c), so the
    bitmap is turned back: what is drawn is the official tag, upright.
    """
    if not 0 <= tag_id < TAG36H11_COUNT:
        raise ValueError(f"tag36h11 has ids 0..{TAG36H11_COUNT - 1}, not {tag_id}")
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    cells = cv2.aruco.generateImageMarker(dictionary, tag_id, TAG_CELLS)
    cells = np.rot90(cells, 2)
    cells = np.pad(cells, TAG_MARGIN_CELLS, constant_values=255)
    image = np.where(cells > 127, white, black).astype(np.uint8)
    return np.kron(image, np.ones((texels_per_cell, texels_per_cell), dtype=np.uint8))


def tag_surface(tag: Tag, texels_per_cell: int = 24) -> Surface:
    """The tag and its quiet zone as one surface, its front facing out of the tag (-z)."""
    total = tag.size * (TAG_CELLS + 2 * TAG_MARGIN_CELLS) / TAG_CELLS
    x_axis, y_axis = tag.rotation[:, 0], tag.rotation[:, 1]
    u_edge, v_edge = x_axis * total, y_axis * total
    origin = tag.centre - (u_edge + v_edge) / 2
    texture = Texture.from_image(tag_bitmap(tag.tag_id, texels_per_cell))
    return Surface(origin, u_edge, v_edge, texture, tag.tag_id)


# Outward normal and texture "up" of each face of a box, in the object frame.
BOX_FACES: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "front": ((1, 0, 0), (0, 0, 1)),
    "back": ((-1, 0, 0), (0, 0, 1)),
    "left": ((0, 1, 0), (0, 0, 1)),
    "right": ((0, -1, 0), (0, 0, 1)),
    "top": ((0, 0, 1), (1, 0, 0)),
    "bottom": ((0, 0, -1), (1, 0, 0)),
}


def box_face_size(face: str, size: np.ndarray) -> tuple[float, float]:
    """(width, height) of a face's texture rectangle for a box of (length, width, height)."""
    length, width, height = size
    if face in ("front", "back"):
        return width, height
    if face in ("left", "right"):
        return length, height
    return width, length


def cuboid_surfaces(
    centre: np.ndarray,
    rotation: np.ndarray,
    size: np.ndarray,
    textures: dict[str, Texture],
    owner: int,
) -> list[Surface]:
    """The faces of a box that have a texture in `textures` (leave out "bottom" on the floor)."""
    surfaces = []
    half = np.asarray(size) / 2
    for face, texture in textures.items():
        normal_local, up_local = (np.array(v, dtype=np.float64) for v in BOX_FACES[face])
        face_centre = centre + rotation @ (normal_local * half)
        width, height = box_face_size(face, size)
        surfaces.append(
            facing_surface(
                face_centre,
                rotation @ normal_local,
                rotation @ up_local,
                width,
                height,
                texture,
                owner,
            )
        )
    return surfaces
