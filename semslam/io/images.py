"""Image files: read as 8-bit BGR or grey, or a one-line error naming the file."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from semslam.errors import FormatError


def read_image(path: str | os.PathLike[str], grey: bool = False) -> np.ndarray:
    """An image file (any format OpenCV reads) as uint8 BGR (H, W, 3), grey images
    expanded, or as grey (H, W) with ``grey``.

    Raises:
        FormatError: the file is missing or not an image OpenCV can read.
    """
    p = Path(path)
    if not p.is_file():
        raise FormatError(f"{p}: no such image file")
    image = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE if grey else cv2.IMREAD_COLOR)
    if image is None:
        raise FormatError(f"{p}: not an image OpenCV can read")
    return image


__all__ = ["read_image"]
