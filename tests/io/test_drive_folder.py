import json
from pathlib import Path

import numpy as np
import pytest
from conftest import make_map, write_drive
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from semslam.errors import DriveError, FormatError, MapError
from semslam.io import (
    Drive,
    DriveFormatError,
    DriveInfo,
    FrameIndex,
    Odometry,
    map_to_dict,
    read_drive_info,
    read_frames,
    read_odometry,
    write_drive_info,
    write_frames,
    write_odometry,
)
from semslam.io.drive import is_drive_file

# --------------------------------------------------------------------------- odometry.csv


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    st.floats(-1e6, 1e6),
    st.lists(st.floats(0.01, 0.05), min_size=0, max_size=29),
    st.data(),
)
def test_odometry_round_trip_is_exact(
    tmp_path: Path, start: float, steps: list[float], data: st.DataObject
) -> None:
    t = start + np.concatenate([[0.0], np.cumsum(steps)])
    assume(np.all(np.diff(t) > 0))
    n = len(t)
    speed = np.array(data.draw(st.lists(st.floats(-50, 50), min_size=n, max_size=n)))
    yaw_rate = np.array(data.draw(st.lists(st.floats(-3, 3), min_size=n, max_size=n)))
    path = tmp_path / "odometry.csv"
    write_odometry(path, Odometry(t, speed, yaw_rate))
    loaded = read_odometry(path)
    np.testing.assert_array_equal(loaded.t, t)
    np.testing.assert_array_equal(loaded.speed, speed)
    np.testing.assert_array_equal(loaded.yaw_rate, yaw_rate)


def _odometry_file(tmp_path: Path, body: str, header: str = "t,speed,yaw_rate") -> Path:
    path = tmp_path / "odometry.csv"
    path.write_text(f"{header}\n{body}")
    return path


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("0.0,1,0\n0.1,nan,0\n", r"odometry\.csv line 3: speed is NaN"),
        ("0.0,1,0\n0.1,1,-inf\n", r"odometry\.csv line 3: yaw_rate is infinite"),
        ("0.0,1,0\n0.1,fast,0\n", r"odometry\.csv line 3: speed is not a number \('fast'\)"),
        (
            "0.0,1,0\n0.1,1\n",
            r"odometry\.csv line 3: expected 3 columns \(t,speed,yaw_rate\), got 2",
        ),
        ("0.0,1,0\n0.1,1,0,7\n", r"odometry\.csv line 3: expected 3 columns .*got 4"),
        (
            "12.4,1,0\n\n12.3,1,0\n",
            r"odometry\.csv line 4: time goes backwards \(12\.300 after 12\.400\)",
        ),
        ("0.5,1,0\n0.5,1,0\n", r"odometry\.csv line 3: time repeats \(0\.500\)"),
        ("", r"odometry\.csv: no data rows after the header"),
        (
            "0.0,1,0\n0.02,1,0\n0.04,1,0\n40.04,1,0\n40.06,1,0\n",
            r"odometry\.csv line 5: 40\.000 s since the sample before \(the median interval "
            r"is 0\.020 s\): odometry is missing there",
        ),
    ],
)
def test_odometry_rejects(tmp_path: Path, body: str, message: str) -> None:
    path = _odometry_file(tmp_path, body)
    with pytest.raises(DriveFormatError, match=message) as err:
        read_odometry(path)
    assert isinstance(err.value, FormatError) and isinstance(err.value, DriveError)


def test_odometry_wrong_header_and_empty_file(tmp_path: Path) -> None:
    path = _odometry_file(tmp_path, "0,1,0\n", header="t,v,w")
    with pytest.raises(
        DriveFormatError,
        match=r"odometry\.csv line 1: header is 't,v,w', expected 't,speed,yaw_rate'",
    ):
        read_odometry(path)
    path.write_text("")
    with pytest.raises(DriveFormatError, match=r"odometry\.csv: empty file"):
        read_odometry(path)


def test_odometry_writer_refuses_a_gap(tmp_path: Path) -> None:
    t = np.array([0.0, 0.02, 0.04, 40.04, 40.06])
    with pytest.raises(DriveFormatError, match=r"sample 3: 40\.000 s since the sample before"):
        write_odometry(tmp_path / "odometry.csv", Odometry(t, np.ones(5), np.zeros(5)))
    assert not (tmp_path / "odometry.csv").exists()


def test_odometry_writer_refuses(tmp_path: Path) -> None:
    path = tmp_path / "odometry.csv"
    with pytest.raises(DriveFormatError, match=r"sample 1: speed is nan"):
        write_odometry(path, Odometry(np.array([0.0, 1.0]), np.array([1.0, np.nan]), np.zeros(2)))
    with pytest.raises(DriveFormatError, match=r"sample 1: time goes backwards"):
        write_odometry(path, Odometry(np.array([1.0, 0.0]), np.zeros(2), np.zeros(2)))
    with pytest.raises(DriveFormatError, match=r"one length"):
        write_odometry(path, Odometry(np.array([0.0, 1.0]), np.zeros(3), np.zeros(2)))
    assert not path.exists()


# --------------------------------------------------------------------------- frames.csv


def test_frames_round_trip(tmp_path: Path) -> None:
    frames = FrameIndex(
        np.array([0.0, 0.1, 0.2]),
        {"topview": ["images/a.png", "images/b.png", ""], "front": ["", "f/1.jpg", "f/2.jpg"]},
    )
    write_frames(tmp_path / "frames.csv", frames)
    loaded = read_frames(tmp_path / "frames.csv")
    np.testing.assert_array_equal(loaded.t, frames.t)
    assert loaded.images == frames.images
    assert (tmp_path / "frames.csv").read_text().splitlines()[0] == "t,topview,front"


def test_frames_without_image_columns(tmp_path: Path) -> None:
    write_frames(tmp_path / "frames.csv", FrameIndex(np.array([0.0, 1.0])))
    loaded = read_frames(tmp_path / "frames.csv")
    assert len(loaded) == 2 and loaded.images == {}


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("time,topview\n0,a.png\n", r"frames\.csv line 1: first column is 'time', expected 't'"),
        ("t,topview,topview\n0,a,b\n", r"frames\.csv line 1: repeated column name"),
        ("t,top view\n0,a\n", r"frames\.csv line 1: bad column name 'top view'"),
        ("t,topview\n0,a.png\n1\n", r"frames\.csv line 3: expected 2 columns \(t,topview\), got 1"),
        ("t,topview\n0,a.png\n-1,b.png\n", r"frames\.csv line 3: time goes backwards"),
        ("t,topview\nNaN,a.png\n", r"frames\.csv line 2: t is NaN"),
        (
            "t,topview\n0,/etc/passwd\n",
            r"frames\.csv line 2: topview: path '/etc/passwd' is absolute",
        ),
        (
            "t,topview\n0,../x.png\n",
            r"frames\.csv line 2: topview: path '\.\./x\.png' leaves the drive folder",
        ),
    ],
)
def test_frames_rejects(tmp_path: Path, content: str, message: str) -> None:
    path = tmp_path / "frames.csv"
    path.write_text(content)
    with pytest.raises(DriveFormatError, match=message):
        read_frames(path)


def test_frames_writer_refuses(tmp_path: Path) -> None:
    path = tmp_path / "frames.csv"
    with pytest.raises(DriveFormatError, match=r"column front has 1 paths for 2 frames"):
        write_frames(path, FrameIndex(np.array([0.0, 1.0]), {"front": ["a.png"]}))
    with pytest.raises(DriveFormatError, match=r"frame 0: front: path 'a,b.png' contains ','"):
        write_frames(path, FrameIndex(np.array([0.0]), {"front": ["a,b.png"]}))
    with pytest.raises(DriveFormatError, match=r"frame 0: front: path ' a.png' starts or ends"):
        write_frames(path, FrameIndex(np.array([0.0]), {"front": [" a.png"]}))
    assert not path.exists()


def test_a_form_feed_in_an_image_path_reads_back(tmp_path: Path) -> None:
    path = tmp_path / "frames.csv"
    write_frames(path, FrameIndex(np.array([0.0]), {"front": ["img/a\x0cb.png"]}))
    assert read_frames(path).images["front"] == ["img/a\x0cb.png"]


# --------------------------------------------------------------------------- drive.json


def test_drive_info_round_trip(tmp_path: Path) -> None:
    info = DriveInfo("run-1", np.array([1.0, -2.0, 0.3]), 12.5, {"seed": 4}, ("exact", "noisy"))
    write_drive_info(tmp_path / "drive.json", info)
    loaded = read_drive_info(tmp_path / "drive.json")
    assert (loaded.name, loaded.frame_rate, loaded.source, loaded.observations) == (
        "run-1",
        12.5,
        {"seed": 4},
        ("exact", "noisy"),
    )
    np.testing.assert_array_equal(loaded.start_pose, info.start_pose)
    write_drive_info(tmp_path / "drive.json", DriveInfo("run-2"))
    assert read_drive_info(tmp_path / "drive.json").start_pose is None


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (
            lambda d: d.update(format="semslam-map"),
            r"drive\.json: format is 'semslam-map', expected 'semslam-drive'",
        ),
        (
            lambda d: d.update(version=2),
            r"drive\.json: version 2 is newer than this semslam reads \(1\)",
        ),
        (
            lambda d: d.update(start_pose=[1, 2]),
            r"drive\.json: start_pose: expected 3 numbers, got 2",
        ),
        (
            lambda d: d.update(start_pose=[1e300, 0, 0]),  # the filter would overflow
            r"drive\.json: start_pose: 1e\+300 is out of range \(\|value\| <= 100000\)",
        ),
        (lambda d: d.update(frame_rate=0), r"drive\.json: frame_rate: must be > 0"),
        (
            lambda d: d.update(frame_rate=1e308),
            r"drive\.json: frame_rate: must be <= 2000\.0, got 1e\+308",
        ),
        (
            lambda d: d.update(observations=["a/b"]),
            r"drive\.json: observations/0: 'a/b' is not a usable file name",
        ),
        (lambda d: d.update(frame_rat=1), r"drive\.json: unknown field 'frame_rat'"),
        (lambda d: d.pop("name"), r"drive\.json: missing field 'name'"),
    ],
)
def test_drive_info_rejects(tmp_path: Path, mutate, message: str) -> None:
    write_drive_info(tmp_path / "drive.json", DriveInfo("x", None, 10.0))
    document = json.loads((tmp_path / "drive.json").read_text())
    mutate(document)
    (tmp_path / "drive.json").write_text(json.dumps(document))
    with pytest.raises(DriveFormatError, match=message):
        read_drive_info(tmp_path / "drive.json")


# --------------------------------------------------------------------------- Drive


def test_drive_reads_everything(drive_folder: Path) -> None:
    drive = Drive.open(drive_folder)
    assert drive.info.name == "test"
    np.testing.assert_array_equal(drive.start_pose, [1.0, 2.0, 0.5])
    assert list(drive.rig.cameras) == ["front", "fisheye_rear"]
    assert len(drive.odometry()) == 5
    assert drive.odometry() is drive.odometry()  # parsed once
    assert len(drive.frames()) == 3
    t, poses = drive.groundtruth()
    assert poses.shape == (3, 3)
    assert map_to_dict(drive.world()) == map_to_dict(make_map())
    assert drive.observation_names() == ["exact"]
    assert len(drive.observations("exact")) == 3
    assert drive.image_path("topview", 1) == drive_folder / "images/000001_topview.png"


def test_drive_without_optional_files(tmp_path: Path) -> None:
    write_drive(tmp_path, with_optional=False)
    drive = Drive.open(tmp_path)
    assert drive.groundtruth() is None and drive.world() is None
    assert drive.observation_names() == []
    with pytest.raises(
        DriveError, match=r"no observation set 'exact' \(drive\.json lists it\); available: none"
    ):
        drive.observations("exact")


def test_drive_start_pose_defaults_to_origin(drive_folder: Path) -> None:
    write_drive_info(drive_folder / "drive.json", DriveInfo("x", None, 10.0))
    np.testing.assert_array_equal(Drive.open(drive_folder).start_pose, np.zeros(3))


@pytest.mark.parametrize("missing", ["drive.json", "rig.json", "odometry.csv", "frames.csv"])
def test_drive_missing_required_file(drive_folder: Path, missing: str) -> None:
    (drive_folder / missing).unlink()
    with pytest.raises(DriveError, match=rf"drive: not a drive folder, missing {missing}$"):
        Drive.open(drive_folder)


def test_drive_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(DriveError, match=r"nowhere: drive folder not found"):
        Drive.open(tmp_path / "nowhere")
    (tmp_path / "map.json").write_text("{}")
    with pytest.raises(DriveError, match=r"map\.json: a file, not a drive folder$"):
        Drive.open(tmp_path / "map.json")


def test_drive_unknown_observations_lists_available(drive_folder: Path) -> None:
    with pytest.raises(
        DriveError, match=r"observations/noisy\.jsonl: no observation set 'noisy'; available: exact"
    ):
        Drive.open(drive_folder).observations("noisy")


def test_drive_image_path_errors(drive_folder: Path) -> None:
    drive = Drive.open(drive_folder)
    with pytest.raises(
        DriveError, match=r"frames\.csv: no column 'rear' \(image columns: topview, front\)"
    ):
        drive.image_path("rear", 0)
    with pytest.raises(
        DriveError, match=r"frames\.csv: frame 3 out of range \(the drive has 3 frames\)"
    ):
        drive.image_path("topview", 3)
    with pytest.raises(DriveError, match=r"frames\.csv: frame 0 has no front image"):
        drive.image_path("front", 0)
    (drive_folder / "images/000002_topview.png").unlink()
    with pytest.raises(DriveError, match=r"000002_topview\.png: image file missing"):
        drive.image_path("topview", 2)


def test_drive_broken_parts_raise_their_errors(drive_folder: Path) -> None:
    (drive_folder / "world.json").write_text("{")
    (drive_folder / "groundtruth.tum").write_text("0 1 2\n")
    (drive_folder / "odometry.csv").write_text("t,speed,yaw_rate\n1,2,3\n0,2,3\n")
    drive = Drive.open(drive_folder)  # lazy: opening does not parse
    with pytest.raises(MapError, match=r"world\.json: not valid JSON"):
        drive.world()
    with pytest.raises(FormatError, match=r"groundtruth\.tum line 1: expected 8 columns"):
        drive.groundtruth()
    with pytest.raises(DriveError, match=r"odometry\.csv line 3: time goes backwards"):
        drive.odometry()


def test_a_drive_s_own_files_are_known_and_new_files_are_not(tmp_path: Path) -> None:
    (tmp_path / "observations").mkdir()
    for name in ("odometry.csv", "observations/noisy.jsonl", "map.json"):
        (tmp_path / name).write_text("x")
    assert is_drive_file(tmp_path, tmp_path / "odometry.csv")
    assert is_drive_file(tmp_path, tmp_path / "observations" / "noisy.jsonl")
    assert not is_drive_file(tmp_path, tmp_path / "map.json")  # a map written there before
    assert not is_drive_file(tmp_path, tmp_path / "world.json")  # not there
    assert not is_drive_file(tmp_path / "observations", tmp_path / "odometry.csv")
