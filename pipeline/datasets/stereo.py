"""What every sequence reader shares: left and right image files paired by name, read as they
are stored (grey or colour), each frame checked against the sequence's image size."""

from __future__ import annotations

import logging
import os
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pipeline.errors import InputError

if TYPE_CHECKING:
    from pipeline.datasets.camera import StereoIntrinsics

log = logging.getLogger(__name__)

STDERR_FD = 2
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".pgm", ".ppm", ".tif", ".tiff")


def image_files(folder: Path) -> list[Path]:
    """The images of a folder, in name order."""
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def pair_files(left: Path, right: Path, where: Path) -> tuple[list[Path], list[Path]]:
    """The images of two folders paired by name (the part before the suffix), in name order.
    An image without its partner is an error that names it: pairing by position would put
    frames of different times together after one lost file."""
    by_stem = []
    for folder in (left, right):
        stems: dict[str, Path] = {}
        for path in image_files(folder):
            if path.stem in stems:
                raise InputError(
                    f"sequence {where}: {folder.name}/ holds both {stems[path.stem].name} and "
                    f"{path.name}"
                )
            stems[path.stem] = path
        by_stem.append(stems)
    lefts, rights = by_stem
    for stems, other, folder, other_folder in (
        (lefts, rights, left, right),
        (rights, lefts, right, left),
    ):
        missing = sorted(set(stems) - set(other))
        if missing:
            raise InputError(
                f"sequence {where}: {folder.name}/{stems[missing[0]].name} has no image of the "
                f"same name in {other_folder.name}/"
                + (f" ({len(missing)} such images)" if len(missing) > 1 else "")
            )
    if not lefts:
        raise InputError(f"sequence {where}: no images in {left.name}/")
    names = sorted(lefts)
    return [lefts[n] for n in names], [rights[n] for n in names]


@contextmanager
def _decoder_messages() -> Iterator[None]:
    """Send what image decoders print to stderr (libpng's "iCCP: known incorrect sRGB profile"
    and the like) to the debug log: a run's stderr is one line on failure, nothing else. The
    decoders write to C's stderr, file descriptor 2, whatever `sys.stderr` is: that is what is
    redirected."""
    sys.stderr.flush()
    saved = os.dup(STDERR_FD)
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), STDERR_FD)
        try:
            yield
        finally:
            os.dup2(saved, STDERR_FD)
            os.close(saved)
            sink.seek(0)
            text = sink.read().decode(errors="replace").strip()
            if text:
                log.debug("image decoder: %s", " / ".join(text.splitlines()))


def read_image(path: Path) -> np.ndarray:
    """An 8-bit image as stored: grey (H, W) or colour (H, W, 3, BGR); orientation tags are
    ignored (stereo calibration is of the pixels as they are)."""
    import cv2

    with _decoder_messages():
        image = cv2.imread(str(path), cv2.IMREAD_ANYCOLOR | cv2.IMREAD_IGNORE_ORIENTATION)
    if image is None:
        raise InputError(f"image {path}: cannot be read")
    return image


def to_grey(image: np.ndarray) -> np.ndarray:
    """A grey image of a grey or BGR one."""
    import cv2

    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image


def read_grey(path: Path) -> np.ndarray:
    return to_grey(read_image(path))


class StereoSequence:
    """The small face of a sequence: `len`, `[index]` -> (left, right) grey images, `images(index)`
    -> the same frame as stored (colour when the sequence is colour), and the `times`,
    `intrinsics`, `gt_poses` and `colour` its reader sets."""

    root: Path
    left_files: list[Path]
    right_files: list[Path]
    intrinsics: StereoIntrinsics
    times: np.ndarray
    gt_poses: np.ndarray | None
    colour: bool  # the images are stored in colour
    # The frames' stamps (ns) as the layout gives them, where it gives integers (EuRoC, ROS
    # bags): seconds in a float lose nanoseconds past about 100 days since the epoch.
    exact_stamps_ns: list[int] | None = None
    # Frames left out for want of a partner of the other camera (layouts paired by stamps).
    unmatched_left: int = 0
    unmatched_right: int = 0

    def __len__(self) -> int:
        return len(self.left_files)

    def stamps_ns(self) -> list[int]:
        """Each frame's stamp (ns): the exact ones, else `times` rounded to nanoseconds."""
        if self.exact_stamps_ns is not None:
            return list(self.exact_stamps_ns)
        return [round(float(t) * 1e9) for t in self.times]

    def __getitem__(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """The rectified (left, right) grey images of a frame."""
        left, right = self.images(index)
        return to_grey(left), to_grey(right)

    def images(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """The rectified (left, right) images of a frame as stored, checked against the
        sequence's size (that of its calibration and first frame)."""
        pair = read_image(self.left_files[index]), read_image(self.right_files[index])
        expected = (self.intrinsics.width, self.intrinsics.height)
        for path, image in zip(
            (self.left_files[index], self.right_files[index]), pair, strict=True
        ):
            size = (image.shape[1], image.shape[0])
            if size != expected:
                raise InputError(
                    f"sequence {self.root}: frame {index} ({path.parent.name}/{path.name}) is "
                    f"{size[0]}x{size[1]}, the sequence's images are {expected[0]}x{expected[1]}"
                )
        return pair
