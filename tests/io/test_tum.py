import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from semslam.errors import FormatError
from semslam.geometry import wrap_angle
from semslam.io import read_tum, write_tum

coordinate = st.floats(-1e4, 1e4, allow_nan=False)
angle = st.floats(-10.0, 10.0, allow_nan=False)


@st.composite
def trajectories(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    n = draw(st.integers(1, 20))
    start = draw(st.floats(0.0, 1e6, allow_nan=False))
    steps = draw(st.lists(st.integers(1, 10**6), min_size=n, max_size=n))
    t = start + np.cumsum(steps) * 1e-5  # at least 10 us apart
    poses = [[draw(coordinate), draw(coordinate), draw(angle)] for _ in range(n)]
    return np.round(t, 6), np.array(poses)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(trajectories())
def test_round_trip(tmp_path: Path, trajectory: tuple[np.ndarray, np.ndarray]) -> None:
    t, poses = trajectory
    path = tmp_path / "traj.tum"
    write_tum(path, t, poses)
    t2, poses2 = read_tum(path)
    np.testing.assert_allclose(t2, t, rtol=0, atol=1e-6)
    np.testing.assert_allclose(poses2[:, :2], poses[:, :2], rtol=0, atol=1e-6)
    yaw_error = wrap_angle(poses2[:, 2] - poses[:, 2])
    assert np.all(np.abs(yaw_error) < 1e-8)
    assert np.all(poses2[:, 2] <= math.pi) and np.all(poses2[:, 2] > -math.pi)


def test_file_looks_like_tum(tmp_path: Path) -> None:
    path = tmp_path / "traj.tum"
    write_tum(path, [1.0, 2.0], [[1.0, 2.0, math.pi / 2], [3.0, 4.0, 0.0]])
    lines = path.read_text().splitlines()
    assert lines[0].startswith("#")
    assert (
        lines[1]
        == "1.000000 1.000000 2.000000 0.000000 0.000000000 0.000000000 0.707106781 0.707106781"
    )


def test_a_quaternion_of_any_length_gives_its_yaw(tmp_path: Path) -> None:
    path = tmp_path / "q.tum"
    path.write_text("0 0 0 0 0 0 1 1\n0.1 0 0 0 0 0 0.5 0.5\n0.2 0 0 0 0 0 0.7071 0.7071\n")
    _, poses = read_tum(path)
    np.testing.assert_allclose(poses[:, 2], np.pi / 2, atol=1e-4)


def test_a_tilt_up_to_45_degrees_keeps_its_yaw(tmp_path: Path) -> None:
    """A car on a ramp: pitch 20 deg and roll 40 deg after a yaw of 1 rad."""
    path = tmp_path / "ramp.tum"
    lines = []
    for i, (pitch, roll) in enumerate([(20.0, 0.0), (0.0, 40.0)]):
        yaw, p, r = 1.0, math.radians(pitch), math.radians(roll)
        cy, sy, cp, sp, cr, sr = (f(a / 2) for a in (yaw, p, r) for f in (math.cos, math.sin))
        q = (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
             cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)  # ZYX Euler
        lines.append(f"{i} 0 0 0 " + " ".join(f"{v:.9f}" for v in q))
    path.write_text("\n".join(lines) + "\n")
    _, poses = read_tum(path)
    np.testing.assert_allclose(poses[:, 2], 1.0, atol=1e-6)


def test_comments_and_blank_lines_are_skipped(tmp_path: Path) -> None:
    path = tmp_path / "traj.tum"
    path.write_text("# header\n\n0 1 2 0 0 0 0 1\n  # late comment\n1 2 3 0 0 0 1 0\n\n")
    t, poses = read_tum(path)
    np.testing.assert_array_equal(t, [0.0, 1.0])
    np.testing.assert_allclose(poses, [[1, 2, 0], [2, 3, math.pi]])


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("0 1 2 0 0 0 0 1\n1 2 3 0 0 0 1\n", r"traj\.tum line 2: expected 8 columns .*got 7"),
        ('{"format": "semslam-map"}\n', r"traj\.tum line 1: .*got 2 \(a JSON file\? a TUM"),
        ("0 1 2 0 0 0 0 1\n1 2 y 0 0 0 0 1\n", r"traj\.tum line 2: y is not a number \('y'\)"),
        ("0 1 2 0 0 0 0 1\n1 nan 3 0 0 0 0 1\n", r"traj\.tum line 2: x is NaN"),
        ("# c\n0 1 2 0 0 0 0 1\n1 1 3 0 0 0 0 inf\n", r"traj\.tum line 3: qw is infinite"),
        (
            "5 1 2 0 0 0 0 1\n4 1 2 0 0 0 0 1\n",
            r"traj\.tum line 2: time goes backwards \(4\.000 after 5\.000\)",
        ),
        ("5 1 2 0 0 0 0 1\n5 1 2 0 0 0 0 1\n", r"traj\.tum line 2: time repeats \(5\.000\)"),
        ("0 1 2 0 0 0 0 0\n", r"traj\.tum line 1: quaternion has zero length"),
        (  # finite but absurd: the errors' squares would overflow in the evaluation
            "0 1 2 0 0 0 0 1\n1 1 -3e300 0 0 0 0 1\n",
            r"traj\.tum line 2: y -3e\+300 m is out of range \(\|y\| <= 1e\+06 m\)",
        ),
        (  # nanosecond stamps
            "1700000000000000000 1 2 0 0 0 0 1\n",
            r"line 1: t 1\.7e\+18 s is out of range \(\|t\| <= 1e\+11 s; TUM times are seconds\)",
        ),
        ("# only a comment\n", r"traj\.tum: no poses"),
        (  # a camera-frame trajectory (z forward): rotated 90 deg about x
            "0 1 2 0 0 0 0 1\n1 1 2 0 -0.7071068 0 0 0.7071068\n",
            r"traj\.tum line 2: the pose is tilted 90 deg from level \(more than 45\)",
        ),
    ],
)
def test_rejects(tmp_path: Path, content: str, message: str) -> None:
    path = tmp_path / "traj.tum"
    path.write_text(content)
    with pytest.raises(FormatError, match=message):
        read_tum(path)


def test_huge_times_are_printed_short() -> None:
    from semslam.io._rows import check_time_order

    with pytest.raises(FormatError, match=r"^f: time goes backwards \(2 after 1e\+300\)$"):
        check_time_order(1e300, 2.0, "f", FormatError)
    with pytest.raises(FormatError, match=r"^f: time repeats \(1e\+300\)$"):
        check_time_order(1e300, 1e300, "f", FormatError)


def test_close_times_are_told_apart(tmp_path: Path) -> None:
    path = tmp_path / "traj.tum"
    path.write_text("1.00002 1 2 0 0 0 0 1\n1.00001 1 2 0 0 0 0 1\n")
    with pytest.raises(FormatError, match=r"\(1\.00001 after 1\.00002\)"):
        read_tum(path)


@pytest.mark.parametrize(
    ("t", "poses", "message"),
    [
        ([0.0, 1.0], [[0, 0, 0]], r"expected t \(N,\) and poses \(N, 3\)"),
        ([0.0, 1.0], [[0, 0, 0], [0, np.nan, 0]], r"pose 1: y is nan"),
        ([1.0, 1.0], [[0, 0, 0], [0, 0, 0]], r"pose 1: time repeats"),
        ([], np.zeros((0, 3)), r"no poses"),
        ([0.0, 1e-7], [[0, 0, 0], [0, 0, 0]], r"pose 1: time 0\.000000 s repeats at the file"),
        ([0.0, 1.0], [[0, 0, 0], [2e6, 0, 0]], r"pose 1: x 2e\+06 is out of range"),
        ([0.0, 2e11], [[0, 0, 0], [0, 0, 0]], r"pose 1: t 2e\+11 is out of range"),
    ],
)
def test_writer_refuses(tmp_path: Path, t, poses, message: str) -> None:
    with pytest.raises(FormatError, match=message):
        write_tum(tmp_path / "traj.tum", t, poses)
    assert not (tmp_path / "traj.tum").exists()
