"""Image reading: a one-line error naming the file, and nothing from OpenCV on stderr."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.errors import FormatError
from semslam.io.images import read_image


def test_an_image_opencv_cannot_decode_is_one_error_and_no_opencv_warning(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "float.tif"  # OpenCV writes 32-bit float TIFFs it then cannot read
    assert cv2.imwrite(str(path), np.random.default_rng(0).random((8, 8, 3), np.float32))
    capfd.readouterr()
    with pytest.raises(FormatError, match="float.tif: not an image OpenCV can read"):
        read_image(path)
    assert capfd.readouterr().err == ""  # OpenCV's "[ WARN:0 ... TIFF ..." line is kept quiet
    level = cv2.utils.logging.getLogLevel()
    read_image(_png(tmp_path))
    assert cv2.utils.logging.getLogLevel() == level  # restored


def test_a_png_whose_header_claims_too_many_pixels_is_one_error(tmp_path: Path) -> None:
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    path = tmp_path / "bomb.png"  # 60000 x 60000 grey, four rows: cv2.error escaped
    ihdr = struct.pack(">IIBBBBB", 60000, 60000, 8, 0, 0, 0, 0)
    idat = zlib.compress(b"\0" * 60001 * 4)  # four rows of zeros
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat)
                     + chunk(b"IEND", b""))
    with pytest.raises(FormatError, match="bomb.png: its header claims more pixels"):
        read_image(path)


def test_a_png_reads_as_bgr_or_grey(tmp_path: Path) -> None:
    path = _png(tmp_path)
    assert read_image(path).shape == (6, 4, 3)
    assert read_image(path, grey=True).shape == (6, 4)


def _png(folder: Path) -> Path:
    path = folder / "a.png"
    cv2.imwrite(str(path), np.full((6, 4), 200, np.uint8))
    return path


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda b: b[: len(b) // 2], "cut short"),
        (lambda b: b[:8], "cut short at byte 8"),
        (lambda b: b[:20] + bytes([b[20] ^ 0xFF]) + b[21:], "chunk 'IHDR' at byte 8 fails its CRC"),
        (lambda b: b[:8] + b[33:], "its first chunk is 'IDAT', not IHDR"),
    ],
)
def test_a_broken_png_is_one_error_and_nothing_from_libpng(
    tmp_path: Path, capfd: pytest.CaptureFixture[str], damage, message: str
) -> None:
    """A PNG cut short, with a flipped byte or without its header chunk: one line naming
    the file and the fault, and libpng's own "libpng error: ..." line never printed."""
    path = tmp_path / "b.png"
    cv2.imwrite(str(path), np.random.default_rng(1).integers(0, 255, (40, 30, 3), np.uint8))
    path.write_bytes(damage(path.read_bytes()))
    capfd.readouterr()
    with pytest.raises(FormatError, match=f"b.png: broken PNG: {message}"):
        read_image(path)
    assert capfd.readouterr().err == ""
