import json
from pathlib import Path

import numpy as np
import pytest
from conftest import make_rig

from semslam.errors import FormatError
from semslam.io import load_rig, rig_from_dict, rig_to_dict, save_rig
from semslam.rig import CameraModel, default_rig


def test_round_trip(tmp_path: Path) -> None:
    rig = make_rig()
    save_rig(tmp_path / "rig.json", rig)
    loaded = load_rig(tmp_path / "rig.json")
    assert rig_to_dict(loaded) == rig_to_dict(rig)
    assert list(loaded.cameras) == ["front", "fisheye_rear"]
    cam = loaded.cameras["fisheye_rear"]
    assert cam.model is CameraModel.FISHEYE and cam.size == (1280, 960)
    np.testing.assert_array_equal(cam.D, [0.1, -0.02, 0.003, -0.0004])
    assert loaded.topview == rig.topview and loaded.vehicle == rig.vehicle


def test_default_rig_round_trips() -> None:
    document = json.loads(json.dumps(rig_to_dict(default_rig())))
    assert rig_to_dict(rig_from_dict(document)) == document


def _document() -> dict:
    return json.loads(json.dumps(rig_to_dict(make_rig())))


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (
            lambda d: d.update(format="semslam-map"),
            r"rig\.json: format is 'semslam-map', expected 'semslam-rig'",
        ),
        (
            lambda d: d.update(version=3),
            r"rig\.json: version 3 is newer than this semslam reads \(1\)",
        ),
        (lambda d: d["cameras"][1]["K"].pop(), r"rig\.json: cameras/1/K: expected 3 rows, got 2"),
        (
            lambda d: d["cameras"][1]["K"][2].__setitem__(2, 0.0),
            r"rig\.json: cameras/1/K: expected \[\[fx",
        ),
        (
            lambda d: d["cameras"][1]["D"].pop(),
            r"rig\.json: cameras/1/D: fisheye model takes 4 coefficients, got 3",
        ),
        (
            lambda d: d["cameras"][0].update(D=[0.0] * 3),
            r"rig\.json: cameras/0/D: pinhole model takes",
        ),
        (
            lambda d: d["cameras"][0].update(model="orthographic"),
            r"cameras/0/model: 'orthographic' is not one of",
        ),
        (
            lambda d: d["cameras"][0].update(size=[1280]),
            r"rig\.json: cameras/0/size: expected 2 numbers, got 1",
        ),
        (
            lambda d: d["cameras"][0].update(size=[1280, 0]),
            r"rig\.json: cameras/0/size/1: must be >= 1",
        ),
        (
            lambda d: [row.__setitem__(0, -row[0])
                       for row in d["cameras"][0]["T_vehicle_camera"][:3]],
            r"cameras/0/T_vehicle_camera: rotation part is a reflection",
        ),
        (
            lambda d: d["cameras"][0]["T_vehicle_camera"][3].__setitem__(0, 1.0),
            r"cameras/0/T_vehicle_camera: last row",
        ),
        (
            lambda d: d["cameras"][0]["T_vehicle_camera"][0].__setitem__(0, 2.0),
            r"cameras/0/T_vehicle_camera: rotation",
        ),
        (
            lambda d: d["cameras"][1].update(name="front"),
            r"cameras/1/name: duplicate camera name 'front'",
        ),
        (
            lambda d: d["cameras"][1].update(T_vehicle_cam=[]),
            r"cameras/1: unknown field 'T_vehicle_cam'",
        ),
        (
            lambda d: d["topview"].update(metres_per_px=0),
            r"rig\.json: topview/metres_per_px: must be >= 0\.001",
        ),
        (  # the detectors would ask for a view of terabytes
            lambda d: d["topview"].update(metres_per_px=1e-9),
            r"rig\.json: topview/metres_per_px: must be >= 0\.001, got 1e-09",
        ),
        (
            lambda d: d["topview"].update(size_px=10**30),
            r"rig\.json: topview/size_px: must be <= 4096, got 1e\+30$",
        ),
        (lambda d: d["vehicle"].pop("wheelbase"), r"rig\.json: vehicle: missing field 'wheelbase'"),
        (
            lambda d: d["vehicle"].update(width=float("inf")),
            r"rig\.json: vehicle/width: Infinity is not allowed",
        ),
    ],
)
def test_rejects(tmp_path: Path, mutate, message: str) -> None:
    document = _document()
    mutate(document)
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(document))
    with pytest.raises(FormatError, match=message):
        load_rig(path)


def test_truncated(tmp_path: Path) -> None:
    path = tmp_path / "rig.json"
    save_rig(path, make_rig())
    path.write_text(path.read_text()[:100])
    with pytest.raises(
        FormatError,
        match=r"rig\.json: not valid JSON at line \d+ column \d+: .* \(the file looks truncated\)$",
    ):
        load_rig(path)
