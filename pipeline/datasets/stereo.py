"""What every sequence reader shares: a list of left and right image files, read as grey."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.errors import InputError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".pgm")


def image_files(folder: Path) -> list[Path]:
    """The images of a folder, in name order."""
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def read_grey(path: Path) -> np.ndarray:
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise InputError(f"image {path}: cannot be read")
    return image


class StereoSequence:
    """The small face of a sequence: `len`, `[index]` -> (left, right) grey images, and the
    `times`, `intrinsics` and `gt_poses` its reader sets."""

    root: Path
    left_files: list[Path]
    right_files: list[Path]

    def __len__(self) -> int:
        return len(self.left_files)

    def __getitem__(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """The rectified (left, right) grey images of a frame."""
        left, right = read_grey(self.left_files[index]), read_grey(self.right_files[index])
        if left.shape != right.shape:
            raise InputError(
                f"sequence {self.root}: frame {index} has left {left.shape[::-1]} and right "
                f"{right.shape[::-1]} images"
            )
        return left, right
