"""A small image file declaring a huge image is refused before decoding (found by fuzzing)."""

from __future__ import annotations

import struct
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.errors import FormatError
from semslam.io.images import read_image


def _jpeg(width: int, height: int) -> bytes:
    """A valid 8 x 8 JPEG whose frame header claims ``width`` x ``height`` (it keeps its
    end-of-image marker: libjpeg fills the missing scan with grey)."""
    data = bytearray(cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))[1].tobytes())
    sof = data.find(b"\xff\xc0")
    struct.pack_into(">HH", data, sof + 5, height, width)
    return bytes(data)


def _rle_bmp(width: int, height: int) -> bytes:
    """An 8-bit RLE BMP of ``width`` x ``height`` whose data is only the end-of-bitmap code."""
    palette, rle = b"\0\0\0\0" * 256, b"\x00\x01"
    offset = 14 + 40 + len(palette)
    return (b"BM" + struct.pack("<IHHI", offset + len(rle), 0, 0, offset)
            + struct.pack("<IiiHHIIiiII", 40, width, height, 1, 8, 1, len(rle), 2835, 2835,
                          256, 0)
            + palette + rle)


@pytest.mark.parametrize("make, suffix", [(_jpeg, ".jpg"), (_rle_bmp, ".bmp")])
def test_a_small_file_declaring_a_huge_image_is_refused(make, suffix, tmp_path: Path) -> None:
    path = tmp_path / f"bomb{suffix}"
    path.write_bytes(make(9000, 9000))  # 81 M pixels in about a kilobyte
    assert path.stat().st_size < 2000
    start = time.perf_counter()
    claims = r"bomb\.(jpg|bmp): its header claims more pixels than semslam decodes \(9000 x 9000"
    with pytest.raises(FormatError, match=claims):
        read_image(path)
    assert time.perf_counter() - start < 1.0


def test_the_largest_top_view_still_reads(tmp_path: Path) -> None:
    path = tmp_path / "topview.png"
    path.write_bytes(cv2.imencode(".png", np.zeros((4096, 4096, 3), np.uint8))[1].tobytes())
    assert read_image(path).shape == (4096, 4096, 3)
