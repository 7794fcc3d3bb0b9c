"""rig.json's camera intrinsics are bounded as ``semslam tags --intrinsics`` bounds them: focal
lengths under ``rig_json.MIN_FOCAL_PX`` (1 px) and entries of ``K`` or ``D`` beyond
``rig_json.MAX_PIXELS`` (1e6) are refused, naming the file and field. Before, ``fx = fy = 1e-300``
(or a denormal) passed the reader's ``> 0`` and ``semslam map --observations images`` ended in a
ZeroDivisionError traceback in the tag covariance (``fx * fy`` underflowed to 0), and D = 1e200
stopped it with "tag corners must be finite", naming no file. A front-camera tag error is now
named by its image, as a top view's already was (found by semantic fuzzing of the drive folder
through the CLI)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from semslam.config import SemslamConfig
from semslam.errors import FormatError, PerceptionError
from semslam.io import Drive, FrameIndex, rig_to_dict, write_frames
from semslam.io.rig_json import rig_from_dict
from semslam.pipeline.perceive import perceive_drive


def _rig_doc(**changes):
    from conftest import make_rig

    document = rig_to_dict(make_rig())
    for key, value in changes.items():
        document["cameras"][0][key] = value
    return document


def _K(fx, fy=None, cx=639.5, s=0.0):
    return [[fx, s, cx], [0.0, fx if fy is None else fy, 399.5], [0.0, 0.0, 1.0]]


@pytest.mark.parametrize("f", [1e-300, 5e-324, 1e-160, 0.5])
def test_a_focal_length_under_a_pixel_is_refused(f):
    with pytest.raises(FormatError, match=r"rig\.json: cameras/0/K: focal lengths must be at "
                                          r"least 1 px, got "):
        rig_from_dict(_rig_doc(K=_K(f)), "rig.json")
    with pytest.raises(FormatError, match=r"focal lengths must be at least 1 px"):
        rig_from_dict(_rig_doc(K=_K(640.0, f)), "rig.json")


@pytest.mark.parametrize("K", [_K(1e300), _K(640.0, cx=1e300), _K(640.0, s=-1e7)])
def test_intrinsics_beyond_a_million_pixels_are_refused(K):
    with pytest.raises(FormatError, match=r"rig\.json: cameras/0/K: -?1e\+\d+ is out of range "
                                          r"\(\|value\| <= 1e\+06\)"):
        rig_from_dict(_rig_doc(K=K), "rig.json")


@pytest.mark.parametrize("D", [[1e200] * 14, [1e300, 0, 0, 0, 0], [0.0, -1e7, 0.0, 0.0]])
def test_distortion_beyond_a_million_is_refused(D):
    with pytest.raises(FormatError, match=r"rig\.json: cameras/0/D: -?1e\+\d+ is out of range"):
        rig_from_dict(_rig_doc(D=D), "rig.json")


def test_plausible_intrinsics_still_read():
    rig = rig_from_dict(_rig_doc(K=_K(1.0), D=[1e6, -1e6, 0.0, 0.0, 0.5]), "rig.json")
    assert rig.cameras["front"].K[0, 0] == 1.0
    assert rig_from_dict(_rig_doc(K=_K(1e6, cx=-1e6)), "rig.json").cameras["front"].K[0, 0] == 1e6


def test_a_front_camera_tag_error_names_the_image(drive_folder, monkeypatch):
    image = drive_folder / "images" / "front0.png"
    cv2.imwrite(str(image), np.zeros((800, 1280), np.uint8))
    write_frames(drive_folder / "frames.csv",
                 FrameIndex(np.array([0.0, 0.1, 0.2]), {"front": ["images/front0.png", "", ""]}))

    def broken(*args, **kwargs):
        raise PerceptionError("tag corners must be finite")

    monkeypatch.setattr("semslam.perception.tags.observe_tags", broken)
    with pytest.raises(PerceptionError) as e:
        perceive_drive(Drive.open(drive_folder), SemslamConfig(), show_progress=False, workers=1)
    assert str(e.value) == f"{image}: tag corners must be finite (camera 'front' of rig.json)"
