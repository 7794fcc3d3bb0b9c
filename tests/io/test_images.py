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


def test_a_png_reads_as_bgr_or_grey(tmp_path: Path) -> None:
    path = _png(tmp_path)
    assert read_image(path).shape == (6, 4, 3)
    assert read_image(path, grey=True).shape == (6, 4)


def _png(folder: Path) -> Path:
    path = folder / "a.png"
    cv2.imwrite(str(path), np.full((6, 4), 200, np.uint8))
    return path
