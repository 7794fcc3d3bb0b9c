"""track CSV: exact round trip, one-line refusals naming file and line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from semslam.errors import FormatError
from semslam.io import TRACK_STATUSES, Track, read_track_csv, write_track_csv

HEADER = "t,x,y,yaw,cov_xx,cov_xy,cov_xyaw,cov_yy,cov_yyaw,cov_yawyaw,status,associated,rejected"
ROW = "0.1,1.0,2.0,0.5,0.04,0.001,0.0001,0.09,-0.0002,0.0025,tracking,3,1"


def make_track(n: int = 6, seed: int = 0) -> Track:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n, 3, 3)) * [0.2, 0.3, 0.05]
    covs = a @ np.swapaxes(a, 1, 2) + np.eye(3) * 1e-6  # symmetric positive definite
    return Track(
        t=np.cumsum(rng.uniform(0.01, 0.2, n)) + 1e9 / 7,  # large times keep every digit
        poses=rng.normal(size=(n, 3)) * [30.0, 20.0, 2.0],
        covariances=covs,
        status=tuple(TRACK_STATUSES[i % len(TRACK_STATUSES)] for i in range(n)),
        associated=rng.integers(0, 20, n),
        rejected=rng.integers(0, 5, n),
    )


def test_round_trip_is_exact(tmp_path: Path) -> None:
    track = make_track()
    path = tmp_path / "run.csv"
    write_track_csv(path, track)
    back = read_track_csv(path)
    assert len(back) == len(track)
    np.testing.assert_array_equal(back.t, track.t)
    np.testing.assert_array_equal(back.poses, track.poses)
    np.testing.assert_array_equal(
        back.covariances[:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]],
        track.covariances[:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]],
    )
    np.testing.assert_array_equal(back.covariances, np.swapaxes(back.covariances, 1, 2))
    np.testing.assert_allclose(back.covariances, track.covariances, rtol=1e-15, atol=0)
    assert back.status == track.status
    np.testing.assert_array_equal(back.associated, track.associated)
    np.testing.assert_array_equal(back.rejected, track.rejected)
    assert back.associated.dtype.kind == "i" and back.rejected.dtype.kind == "i"


def test_file_layout(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    track = Track(
        t=np.array([0.1]),
        poses=np.array([[1.0, 2.0, 0.5]]),
        covariances=np.array([[[0.04, 0.001, 1e-4], [0.001, 0.09, -2e-4], [1e-4, -2e-4, 0.0025]]]),
        status=("tracking",),
        associated=np.array([3]),
        rejected=np.array([1]),
    )
    write_track_csv(path, track)
    assert path.read_text() == f"{HEADER}\n{ROW}\n"


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("", r"run\.csv: empty file"),
        (f"{HEADER}\n", r"run\.csv: no data rows"),
        (f"t,x,y,yaw\n{ROW}\n", r"run\.csv line 1: header is 't,x,y,yaw', expected 't,x,y"),
        (f"{HEADER}\n{ROW}\n1.0,2.0\n", r"run\.csv line 3: expected 13 columns .*got 2"),
        (f"{HEADER}\n{ROW},7\n", r"run\.csv line 2: expected 13 columns .*got 14"),
        (f"{HEADER}\n{ROW.replace('1.0', 'nan', 1)}\n", r"run\.csv line 2: x is NaN"),
        (f"{HEADER}\n{ROW.replace('0.09', 'inf')}\n", r"run\.csv line 2: cov_yy is infinite"),
        (f"{HEADER}\n{ROW.replace('2.0', 'two')}\n", r"run\.csv line 2: y is not a number"),
        (f"{HEADER}\n{ROW.replace('0.04', '-0.04')}\n", r"run\.csv line 2: cov_xx is negative"),
        (
            f"{HEADER}\n{ROW.replace('tracking', 'found')}\n",
            r"run\.csv line 2: status 'found' is not one of tracking, coasting, lost",
        ),
        (f"{HEADER}\n{ROW.replace(',3,', ',3.5,')}\n", r"run\.csv line 2: associated is '3\.5'"),
        (f"{HEADER}\n{ROW[:-2]},-1\n", r"run\.csv line 2: rejected is '-1', expected an integer"),
        (f"{HEADER}\n{ROW[:-2]},{10**20}\n", r"run\.csv line 2: rejected 10{20} is out of range"),
        (
            f"{HEADER}\n{ROW}\n\n{ROW.replace('0.1,', '0.05,', 1)}\n",
            r"run\.csv line 4: time goes backwards \(0\.050 after 0\.100\)",
        ),
        (f"{HEADER}\n{ROW}\n{ROW}\n", r"run\.csv line 3: time repeats \(0\.100\)"),
    ],
)
def test_reader_rejects_with_one_line_naming_file_and_line(
    tmp_path: Path, content: str, message: str
) -> None:
    path = tmp_path / "run.csv"
    path.write_text(content)
    with pytest.raises(FormatError, match=message) as err:
        read_track_csv(path)
    assert "\n" not in str(err.value)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match=r"nope\.csv: file not found"):
        read_track_csv(tmp_path / "nope.csv")


def _with(**changes) -> Track:
    track = make_track(3)
    fields = {k: getattr(track, k) for k in Track.__dataclass_fields__}
    return Track(**(fields | changes))


@pytest.mark.parametrize(
    ("track", "message"),
    [
        (_with(poses=np.zeros((2, 3))), r"expected t \(N,\), poses \(N, 3\)"),
        (_with(status=("tracking",) * 2), r"expected t \(N,\)"),
        (_with(t=np.array([1.0, 3.0, 2.0])), r"frame 2: time goes backwards"),
        (_with(poses=np.array([[0, 0, 0], [0, np.inf, 0], [0, 0, 0]])), r"frame 1: y is inf"),
        (_with(status=("tracking", "lost", "asleep")), r"frame 2: status 'asleep' is not one"),
        (_with(associated=np.array([1, -2, 0])), r"frame 1: associated is -2"),
        (_with(rejected=np.array([0.0, 0.5, 1.0])), r"frame 1: rejected is 0\.5"),
        (_with(covariances=-np.tile(np.eye(3), (3, 1, 1))), r"frame 0: cov_\w+ is negative"),
        (
            Track(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3, 3)), (), np.zeros(0), np.zeros(0)),
            r"no frames to write",
        ),
    ],
)
def test_writer_refuses_and_writes_nothing(tmp_path: Path, track: Track, message: str) -> None:
    path = tmp_path / "run.csv"
    with pytest.raises(FormatError, match=message) as err:
        write_track_csv(path, track)
    assert "\n" not in str(err.value) and "run.csv" in str(err.value)
    assert not path.exists()
