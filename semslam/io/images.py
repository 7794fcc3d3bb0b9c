"""Image files: read as 8-bit BGR or grey, or a one-line error naming the file; the image
files of a folder."""

from __future__ import annotations

import io
import os
import struct
import warnings
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np

from semslam.errors import FormatError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")
"""The file name endings taken for images in a folder (any case)."""

_JPEG_START = b"\xff\xd8"
_JPEG_END = b"\xff\xd9"
_JPEG_TAIL = 1024
"""Bytes at a JPEG file's end searched for its end-of-image marker (writers may pad after it)."""

_PNG_START = b"\x89PNG\r\n\x1a\n"

MAX_IMAGE_PIXELS = 1 << 26
"""Most pixels (width x height) an image file may declare: 8192 x 8192, four times semslam's
largest top view. A JPEG or RLE BMP of a few hundred bytes can declare 30000 x 30000, which
OpenCV decodes (filling what the file lacks) into 2.7 GB in seconds."""


def declared_pixel_problem(data: bytes) -> str | None:
    """Why the size an image file's header declares is more than :data:`MAX_IMAGE_PIXELS`
    (one phrase), or None. Pillow reads the header only; a format it does not know, or a
    header it cannot read, is left to OpenCV."""
    from PIL import Image

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data)) as im:
                width, height = im.size
    except Image.DecompressionBombError:  # Pillow's own limit, beyond ours
        return f"its header claims more pixels than semslam decodes ({MAX_IMAGE_PIXELS:,})"
    except Exception:  # noqa: BLE001 - not an image Pillow reads: OpenCV decides
        return None
    if width * height > MAX_IMAGE_PIXELS:
        return (f"its header claims more pixels than semslam decodes ({width} x {height} > "
                f"{MAX_IMAGE_PIXELS:,})")
    return None


def png_problem(data: bytes) -> str | None:
    """What is wrong with the chunks of a PNG file's bytes (one phrase), or None.

    Walks the chunks (length, type, data, CRC-32 over type and data) from the signature:
    the first must be IHDR, each CRC must match, and the file must reach IEND. libpng
    would find the same faults, but prints them to stderr itself before OpenCV returns."""
    at = len(_PNG_START)
    first = True
    while True:
        if at + 8 > len(data):
            return f"cut short at byte {len(data)} (no IEND chunk)"
        length, kind = struct.unpack(">I4s", data[at : at + 8])
        name = kind.decode("latin-1")
        if first and kind != b"IHDR":
            return f"its first chunk is {name!r}, not IHDR"
        first = False
        end = at + 8 + length + 4
        if end > len(data):
            return f"cut short in chunk {name!r} at byte {len(data)} (no IEND chunk)"
        (crc,) = struct.unpack(">I", data[end - 4 : end])
        if zlib.crc32(memoryview(data)[at + 4 : end - 4]) != crc:  # no copy of the chunk
            return f"chunk {name!r} at byte {at} fails its CRC check"
        if kind == b"IEND":
            return None
        at = end


def read_image(path: str | os.PathLike[str], grey: bool = False) -> np.ndarray:
    """An image file (any format OpenCV reads) as uint8 BGR (H, W, 3), grey images
    expanded, or as grey (H, W) with ``grey``.

    Raises:
        FormatError: the file is missing, not an image OpenCV can read (or larger than it
            decodes), its header declares more than :data:`MAX_IMAGE_PIXELS`, or a JPEG cut
            short (OpenCV would decode what is there and fill the rest with grey).
    """
    p = Path(path)
    if not p.is_file():
        raise FormatError(f"{p}: no such image file")
    data = p.read_bytes()
    if data.startswith(_JPEG_START) and _JPEG_END not in data[-_JPEG_TAIL:]:
        raise FormatError(f"{p}: JPEG cut short (no end-of-image marker), {len(data)} bytes")
    if data.startswith(_PNG_START) and (problem := png_problem(data)) is not None:
        raise FormatError(f"{p}: broken PNG: {problem}")
    if (problem := declared_pixel_problem(data)) is not None:
        raise FormatError(f"{p}: {problem}")
    image = None
    if data:  # imdecode asserts on an empty buffer
        with _opencv_quiet():  # its own warnings ("can not handle 32-bit samples") before ours
            try:
                image = cv2.imdecode(
                    np.frombuffer(data, np.uint8),
                    cv2.IMREAD_GRAYSCALE if grey else cv2.IMREAD_COLOR,
                )
            except cv2.error as exc:  # e.g. a header claiming more pixels than OpenCV takes
                if "CV_IO_MAX_IMAGE_PIXELS" in str(exc):
                    raise FormatError(
                        f"{p}: its header claims more pixels than OpenCV decodes (2^30)"
                    ) from None
                raise FormatError(f"{p}: OpenCV cannot decode it") from None
    if image is None:
        raise FormatError(f"{p}: not an image OpenCV can read")
    return image


@contextmanager
def _opencv_quiet() -> Iterator[None]:
    """OpenCV's log silent for the duration (it prints its own warnings and errors, such as
    "can not handle 32-bit samples", to stderr before ours)."""
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(level)


def image_files(path: str | os.PathLike[str]) -> list[str | os.PathLike[str]]:
    """``path`` itself, or for a folder its image files (:data:`IMAGE_SUFFIXES`) by name.

    Raises:
        FormatError: a folder with no image file.
    """
    folder = Path(path)
    if not folder.is_dir():
        return [path]
    files: list[str | os.PathLike[str]] = sorted(
        p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES
    )
    if not files:
        raise FormatError(f"{folder}: a folder with no image file ({', '.join(IMAGE_SUFFIXES)})")
    return files


__all__ = ["IMAGE_SUFFIXES", "MAX_IMAGE_PIXELS", "declared_pixel_problem", "image_files",
           "png_problem", "read_image"]
