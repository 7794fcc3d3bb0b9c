"""The garage-bev-drive reader: the real recording (when ../shared is there) and broken
copies of its files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from semslam.errors import DriveError, FormatError
from semslam.io.garage_bev import (
    SLOT_LINE_RGB,
    class_mask,
    match_times,
    open_garage_bev,
    read_frame_times,
    read_odometry_poses,
    read_vector_map,
)
from semslam.pipeline.import_bev import (
    derive_odometry,
    move_poses,
    odometry_point,
    to_vehicle,
    track_odometry,
)

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "realdata" / "garage-bev-drive"
if not REAL.is_dir():
    REAL = Path("/work/shared/realdata/garage-bev-drive")
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason="../shared/realdata not present")


# --------------------------------------------------------------------------- real folder


@needs_real
def test_real_recording_frames_and_poses() -> None:
    rec = open_garage_bev(REAL)
    assert len(rec.frame_times) == 9855
    assert len(rec.odometry_t) == 9851
    # the odometry starts 3 frames late: frames 0-2 are dropped, the rest of the masks stay
    assert rec.pose_frame[0] == 3 and (rec.pose_frame >= 0).all()
    assert rec.mask_frames[0] == 3 and len(rec.mask_frames) == 1256 - 3
    assert np.allclose(rec.frame_times[rec.mask_frames], rec.mask_times, atol=1e-3)
    names = [p.name for p in rec.mask_paths]
    assert names == [f"{k:06d}.png" for k in rec.mask_frames]
    # yaw is the heading of the body's forward (+y) axis: the car moves along it
    step = np.diff(rec.odometry_poses[:, :2], axis=0)
    fast = np.hypot(*step.T) > 0.15
    heading = np.arctan2(step[:, 1], step[:, 0])[fast]
    off = np.angle(np.exp(1j * (heading - rec.odometry_poses[:-1, 2][fast])))
    assert abs(math.degrees(np.median(off))) < 5


@needs_real
def test_real_vector_map_lies_along_the_drive() -> None:
    seg = read_vector_map(REAL)
    assert seg.shape == (734, 2, 2)
    lengths = np.hypot(*(seg[:, 1] - seg[:, 0]).T)
    assert 1.0 < np.median(lengths) < 3.0
    rec = open_garage_bev(REAL)
    # columns swapped: map x = Ly (about -330..2), y = Bx (about 10..95), like the poses
    assert seg[..., 0].min() < -300 and seg[..., 1].max() < 100
    mid = seg.mean(axis=1)
    path = rec.odometry_poses[::20, :2]
    near = np.hypot(*(mid[:, None] - path[None]).transpose(2, 0, 1)).min(axis=1)
    assert np.median(near) < 5.0


@needs_real
def test_real_odometry_derivation_reproduces_the_poses() -> None:
    from semslam.motion import integrate_odometry

    rec = open_garage_bev(REAL)
    n = 1500  # the first 2.5 minutes
    t, poses = rec.odometry_t[:n], rec.odometry_poses[:n]
    offset, heading = odometry_point(t, poses)
    assert -1.6 < offset < -1.0 and 1.5 < math.degrees(heading) < 4.0
    moved = move_poses(poses, offset, heading)
    speed, yaw_rate = derive_odometry(t, moved)
    reckoned = integrate_odometry(moved[0], t, speed, yaw_rate)
    assert np.hypot(*(reckoned[:, :2] - moved[:, :2]).T).max() < 1.0
    assert np.abs(np.angle(np.exp(1j * (reckoned[:, 2] - moved[:, 2])))).max() < 1e-6


@needs_real
def test_real_tracked_odometry_follows_the_poses() -> None:
    from semslam.motion import integrate_odometry

    rec = open_garage_bev(REAL)
    t, poses = rec.odometry_t, rec.odometry_poses
    moved = move_poses(poses, *odometry_point(t, poses))
    speed, yaw_rate, yaw = track_odometry(t, moved)
    reckoned = integrate_odometry(moved[0], t, speed, yaw_rate)
    # open loop: 5 m off after 1.3 km; tracked: within centimetres, heading turned < 2 deg
    assert np.hypot(*(reckoned[:, :2] - moved[:, :2]).T).max() < 0.08
    assert np.abs(np.angle(np.exp(1j * (reckoned[:, 2] - yaw)))).max() < 1e-6
    assert np.degrees(np.abs(yaw - moved[:, 2])).max() < 2.0


@needs_real
def test_real_mask_class() -> None:
    import cv2

    image = cv2.imread(str(REAL / "masks" / "000500.png"), cv2.IMREAD_COLOR)
    mask = class_mask(image, SLOT_LINE_RGB)
    assert mask.shape == (1457, 1104) and 1000 < mask.sum() < 200_000


# --------------------------------------------------------------------------- pure parts


def test_derive_odometry_is_exact_on_arcs() -> None:
    from semslam.motion import integrate_odometry

    t = np.arange(50) * 0.1
    speed = np.where(t < 2, 1.5, -0.8)
    rate = np.where(t < 3, 0.3, -0.2)
    poses = integrate_odometry([1.0, 2.0, 0.5], t, speed, rate)
    poses[:, 2] = np.unwrap(poses[:, 2])
    v, w = derive_odometry(t, poses)
    assert np.allclose(v[:-1], speed[:-1]) and np.allclose(w[:-1], rate[:-1])


def test_track_odometry_removes_sideways_slip() -> None:
    from semslam.motion import integrate_odometry

    t = np.arange(600) * 0.1
    speed = 2.0 + 0.5 * np.sin(t / 7)
    rate = 0.2 * np.sin(t / 5)
    course = integrate_odometry([0.0, 0.0, 0.3], t, speed, rate)
    course[:, 2] = np.unwrap(course[:, 2])
    slip = np.radians(0.5) * np.sin(t / 11)  # the headings miss the direction of travel
    poses = course.copy()
    poses[:, 2] -= slip
    v, w = derive_odometry(t, poses)
    open_loop = integrate_odometry(poses[0], t, v, w)
    assert np.hypot(*(open_loop[:, :2] - poses[:, :2]).T).max() > 0.2
    v, w, yaw = track_odometry(t, poses)
    tracked = integrate_odometry(poses[0], t, v, w)
    assert np.hypot(*(tracked[:, :2] - poses[:, :2]).T).max() < 0.03
    assert np.abs(yaw - course[:, 2]).max() < np.radians(0.3)
    assert yaw[0] == poses[0, 2]


def test_vehicle_frame_round_trip() -> None:
    centre = np.array([[3.0, 4.0, 0.7]])
    vehicle = move_poses(centre, -1.3, 0.0)
    cP = np.array([[2.0, -1.0], [0.5, 3.0]])
    vP = to_vehicle(cP, -1.3)
    from semslam.geometry import transform_points

    assert np.allclose(transform_points(vehicle[0], vP), transform_points(centre[0], cP))


def test_mask_points_land_where_they_are_through_the_imported_odometry() -> None:
    """A car whose recorded heading is turned 3 deg against its direction of travel (and
    whose recorded position is the mask centre, 1.3 m ahead of the rear axle) sees floor
    points in masks drawn in its own axes: through the importer's calibration, tracked
    odometry and vehicle frame, every point lands on the floor within 2 cm."""
    from semslam.geometry import inverse, transform_points
    from semslam.motion import integrate_odometry

    t = np.arange(900) * 0.1
    axle = integrate_odometry([0.0, 0.0, 0.3], t, 2.0 + 0.5 * np.sin(t / 7),
                              0.15 * np.sin(t / 5))
    axle[:, 2] = np.unwrap(axle[:, 2])
    centre = move_poses(axle, 1.3, 0.0)  # the mask centre, in the car's axes
    recorded = centre.copy()
    recorded[:, 2] -= math.radians(3.0)  # the recording's heading misses the car's
    offset, heading = odometry_point(t, recorded)
    assert offset == pytest.approx(-1.3, abs=0.02)
    assert math.degrees(heading) == pytest.approx(3.0, abs=0.05)
    vehicle = move_poses(recorded, offset, heading)
    speed, rate, _ = track_odometry(t, vehicle)
    reckoned = integrate_odometry(vehicle[0], t, speed, rate)
    floor = np.array([[5.0, 2.0], [-3.0, 1.5], [2.0, -4.0]])  # points around the car
    worst = 0.0
    for k in range(0, len(t), 60):
        cP = transform_points(inverse(centre[k]), floor)  # what the mask shows
        placed = transform_points(reckoned[k], to_vehicle(cP, offset))
        worst = max(worst, float(np.hypot(*(placed - floor).T).max()))
    assert worst < 0.02


def test_match_times_tolerates_a_millisecond() -> None:
    frames = np.array([0.0, 0.1, 0.2, 0.3])
    assert match_times(np.array([0.1004, 0.25, 0.3]), frames).tolist() == [1, -1, 3]
    with pytest.raises(FormatError, match="no pose time matches"):
        match_times(np.array([5.0]), frames, "odo.txt")


# --------------------------------------------------------------------------- broken files


def _write_recording(root: Path) -> Path:
    (root / "masks").mkdir(parents=True)
    (root / "vector_map").mkdir()
    (root / "color.txt").write_text("".join(f"{100 + 0.1 * k:.6f}\n" for k in range(6)))
    lines = [f"{100 + 0.1 * k:.6f} {0.0} {0.2 * k} 0 0 0 0 1\n" for k in range(1, 6)]
    (root / "TUM_odmetry_interpolation.txt").write_text("".join(lines))
    for k in (0, 2, 4):
        (root / "masks" / f"{k:06d}.png").write_bytes(b"")
    (root / "vector_map" / "point.csv").write_text(
        "PID,B,L,H,Bx,Ly,ReF\n1,0,0,0,10.0,-2.0,0\n2,0,0,0,12.5,-2.0,0\n"
    )
    (root / "vector_map" / "line.csv").write_text("LID,BPID,FPID,BLID,FLID\n1,1,2,0,0\n")
    return root


def test_masks_are_read_in_frame_order_and_a_frame_with_two_masks_is_refused(
    tmp_path: Path,
) -> None:
    root = _write_recording(tmp_path / "r")
    (root / "masks" / "000004.png").rename(root / "masks" / "4.png")  # sorts before 000002
    assert open_garage_bev(root).mask_frames.tolist() == [2, 4]
    (root / "masks" / "0000002.png").write_bytes(b"")
    with pytest.raises(DriveError, match=r"masks/0+2\.png: frame 2 has a second mask, 0+2\.png"):
        open_garage_bev(root)


def test_a_gap_in_the_odometry_file_names_that_file_and_line(tmp_path: Path) -> None:
    """Poses missing for 2 s in the middle of the recording: refused where they are
    missing, not later in the odometry.csv the import would write."""
    path = tmp_path / "odo.txt"
    times = [100 + 0.1 * k for k in range(10)] + [102.0 + 0.1 * k for k in range(10)]
    path.write_text("".join(f"{t:.6f} 0 {0.2 * k} 0 0 0 0 1\n" for k, t in enumerate(times)))
    with pytest.raises(FormatError, match=r"odo.txt line 11: 1.100 s since the sample before"):
        read_odometry_poses(path)


def test_a_folder_with_no_vector_map_is_named(tmp_path: Path) -> None:
    with pytest.raises(DriveError, match=rf"{tmp_path}: no vector map there"):
        read_vector_map(tmp_path)
    with pytest.raises(DriveError, match=r"nowhere: vector map folder not found"):
        read_vector_map(tmp_path / "nowhere")
    with pytest.raises(DriveError, match=r"vector_map/line\.csv: missing"):
        _write_recording(tmp_path / "r")
        (tmp_path / "r" / "vector_map" / "line.csv").unlink()
        read_vector_map(tmp_path / "r")


def test_small_recording(tmp_path: Path) -> None:
    rec = open_garage_bev(_write_recording(tmp_path / "r"))
    assert rec.mask_frames.tolist() == [2, 4]  # frame 0 is before the odometry
    assert rec.mask_pose.tolist() == [1, 3]
    # body y forward along +y: yaw pi/2 in semslam's convention
    assert np.allclose(rec.odometry_poses[:, 2], math.pi / 2)
    seg = read_vector_map(tmp_path / "r")
    assert np.allclose(seg, [[[-2.0, 10.0], [-2.0, 12.5]]])  # x = Ly, y = Bx


@pytest.mark.parametrize(
    ("file", "text", "message"),
    [
        ("color.txt", "100.0\nabc\n", r"color.txt line 2: timestamp"),
        ("color.txt", "100.0\n99.0\n", r"color.txt line 2: timestamp 99.0 does not increase"),
        ("color.txt", "100.0\n\n100.2\n", r"color.txt line 2: empty line"),
        ("TUM_odmetry_interpolation.txt", "100.1 0 0 0 0 0 0\n", r"line 1: expected 8 columns"),
        ("TUM_odmetry_interpolation.txt", "100.1 0 0 0 0 0 0 0\n", r"line 1: quaternion"),
        ("TUM_odmetry_interpolation.txt", "100.1 0 nan 0 0 0 0 1\n", r"line 1: y"),
        ("TUM_odmetry_interpolation.txt", "100.1 0 0 0 0 0 0 1\n100.1 0 0 0 0 0 0 1\n",
         r"line 2: time"),
        ("TUM_odmetry_interpolation.txt", "100.1 0 0 0 0.7071068 0 0 0.7071068\n",
         r"line 1: the body's forward \(y\) axis is vertical"),
        ("TUM_odmetry_interpolation.txt", "500.0 0 0 0 0 0 0 1\n", r"no pose time matches"),
    ],
)
def test_broken_recording_files(tmp_path: Path, file: str, text: str, message: str) -> None:
    root = _write_recording(tmp_path / "r")
    (root / file).write_text(text)
    with pytest.raises(FormatError, match=message) as info:
        open_garage_bev(root)
    assert "\n" not in str(info.value) and file in str(info.value)


@pytest.mark.parametrize(
    ("file", "text", "message"),
    [
        ("point.csv", "PID,B,L,H,Bx\n1,0,0,0,1\n", r"point.csv line 1: header lacks Ly"),
        ("point.csv", "PID,Bx,Ly\n1,1.0,x\n", r"point.csv line 2: Ly"),
        ("point.csv", "PID,Bx,Ly\n1,1.0,2\n1,1.0,2\n", r"point.csv line 3: repeated PID 1"),
        (
            "point.csv",
            "PID,Bx,Ly\n1,-1e300,2\n",
            r"point.csv line 2: Bx -1e\+300 m is out of range",
        ),
        ("point.csv", "PID,Bx,Ly\n1.5,1.0,2\n", r"point.csv line 2: PID is '1.5'"),
        ("point.csv", "PID,Bx,Ly\n1,1.0\n", r"point.csv line 2: expected 3 columns"),
        ("point.csv", "", r"point.csv: empty file"),
        ("line.csv", "LID,BPID,FPID\n1,1,7\n", r"line.csv line 2: FPID 7 is not in"),
        ("line.csv", "LID,BPID,FPID\n", r"line.csv: no data rows"),
        ("line.csv", "LID,BPID,FPID\n1,2,2\n", r"line.csv line 2: zero-length line"),
    ],
)
def test_broken_vector_map(tmp_path: Path, file: str, text: str, message: str) -> None:
    root = _write_recording(tmp_path / "r")
    (root / "vector_map" / file).write_text(text)
    with pytest.raises(FormatError, match=message):
        read_vector_map(root)


def test_missing_parts(tmp_path: Path) -> None:
    with pytest.raises(DriveError, match="folder not found"):
        open_garage_bev(tmp_path / "nothing")
    root = _write_recording(tmp_path / "r")
    (root / "TUM_odmetry_interpolation.txt").unlink()
    with pytest.raises(DriveError, match=r"TUM_odmetry_interpolation.txt: missing"):
        open_garage_bev(root)
    (root / "vector_map" / "line.csv").unlink()
    with pytest.raises(DriveError, match=r"line.csv: missing"):
        read_vector_map(root)
    with pytest.raises(FormatError, match="expected an 8-bit colour image"):
        class_mask(np.zeros((4, 4)), SLOT_LINE_RGB)
    assert read_frame_times(root / "color.txt").shape == (6,)
    with pytest.raises(FormatError, match="color.txt"):
        read_frame_times(root / "nope" / "color.txt")
    with pytest.raises(FormatError):
        read_odometry_poses(root / "missing.txt")


@needs_real
def test_import_writes_a_drive_semslam_reads(tmp_path: Path) -> None:
    from semslam.config import load_config
    from semslam.io import Drive, load_map
    from semslam.pipeline.import_bev import import_garage_bev

    summary = import_garage_bev(REAL, tmp_path / "drive", every=200)
    drive = Drive.open(tmp_path / "drive")
    frames = drive.observations("cached")
    assert len(frames) == summary.frames == 7 and summary.markings > 0
    assert len(drive.odometry()) == 9851 and frames[0].t >= drive.odometry().t[0]
    assert drive.frames().images["mask"][0] == "masks/000003.png"
    assert drive.image_path("mask", 0).is_file()
    assert len(load_map(tmp_path / "drive" / "vector_map.json").markings) == 734
    assert load_config(tmp_path / "drive" / "config.json").mapping.marking_min_support == 3
    with pytest.raises(DriveError, match="holds no drive"):
        (tmp_path / "other").mkdir()
        (tmp_path / "other" / "x").write_text("x")
        import_garage_bev(REAL, tmp_path / "other", every=200)


@needs_real
def test_import_refuses_a_crop_that_blanks_the_whole_mask(tmp_path: Path) -> None:
    from semslam.pipeline.import_bev import import_garage_bev

    with pytest.raises(DriveError, match=r"--crop-rows 100000 blanks all \d+ rows of the mask"):
        import_garage_bev(REAL, tmp_path / "drive", crop_rows=100_000, every=200)
    assert not (tmp_path / "drive").exists()


def test_the_drive_settings_are_valid_config(tmp_path: Path) -> None:
    """config.json of an imported drive (mapping and localization settings) loads."""
    import json

    from semslam.config import load_config
    from semslam.pipeline.import_bev import DRIVE_LOCALIZATION_CONFIG, DRIVE_MAPPING_CONFIG

    path = tmp_path / "config.json"
    path.write_text(json.dumps({"mapping": DRIVE_MAPPING_CONFIG,
                                "localization": DRIVE_LOCALIZATION_CONFIG}))
    cfg = load_config(path)
    assert cfg.localization.speed_sigma == DRIVE_LOCALIZATION_CONFIG["speed_sigma"]
    assert not cfg.localization.estimate_odometry_errors
    assert cfg.mapping.marking_sigma == DRIVE_MAPPING_CONFIG["marking_sigma"]


@needs_real
def test_imported_detections_land_on_the_vector_map_and_the_localizer_follows(
    tmp_path: Path,
) -> None:
    """Every 4th mask of the real drive, imported: placed through the drive's odometry, the
    detected end points lie within 0.18 m (median) of the hand-made vector map's lines (0.22
    m when the masks were turned by the recorded heading's offset); localized against the
    vector map with the drive's own settings, the filter tracks most frames and stays within
    0.5 m of the odometry (17 m with the default settings)."""
    from semslam.config import load_config
    from semslam.evaluation.line_map import point_segment_distances
    from semslam.geometry import transform_points
    from semslam.io import Drive, load_map
    from semslam.localization.localizer import Localizer
    from semslam.motion import integrate_odometry
    from semslam.pipeline.import_bev import import_garage_bev

    import_garage_bev(REAL, tmp_path / "drive", every=4)
    drive = Drive.open(tmp_path / "drive")
    vector_map = load_map(tmp_path / "drive" / "vector_map.json")
    segments = np.array([[*m.a, *m.b] for m in vector_map.markings])
    frames = drive.observations("cached")
    odo = drive.odometry()
    reckoned = integrate_odometry(drive.start_pose, odo.t, odo.speed, odo.yaw_rate)
    at = np.searchsorted(odo.t, [f.t for f in frames], side="right") - 1
    ends = np.concatenate([transform_points(reckoned[k], np.array([m.vA, m.vB]))
                           for f, k in zip(frames, at, strict=True) for m in f.markings])
    assert np.median(point_segment_distances(ends, segments)) < 0.18

    cfg = load_config(tmp_path / "drive" / "config.json").localization
    loc = Localizer(vector_map, cfg, odo.t, odo.speed, odo.yaw_rate, drive.start_pose)
    estimates = [loc.step(f) for f in frames]
    poses = np.array([e.pose for e in estimates])
    assert np.hypot(*(poses[:, :2] - reckoned[at, :2]).T).max() < 0.5
    assert sum(e.status == "tracking" for e in estimates) > 0.6 * len(frames)


@needs_real
def test_a_real_mask_gives_the_same_lines_in_every_run() -> None:
    """The line detector on a real slot-line mask, again and again in one process: the same
    lines to the bit (cv2.magnitude's last bits once changed from call to call)."""
    from semslam.io.garage_bev import METRES_PER_PX, SLOT_LINE_RGB, class_mask, open_garage_bev
    from semslam.io.images import read_image
    from semslam.perception.markings import MarkingDetector

    rec = open_garage_bev(REAL)
    mask = class_mask(read_image(rec.mask_paths[500]), SLOT_LINE_RGB, "mask")
    mask[:300] = False
    mask[-300:] = False
    detector = MarkingDetector()
    runs = [detector.detect_mask_lines(mask.copy(), METRES_PER_PX,
                                       (mask.shape[1] / 2, mask.shape[0] / 2)) for _ in range(6)]
    assert len(runs[0].a) >= 3
    for lines in runs[1:]:
        assert np.array_equal(lines.a, runs[0].a) and np.array_equal(lines.b, runs[0].b)
        assert np.array_equal(lines.confidence, runs[0].confidence)
