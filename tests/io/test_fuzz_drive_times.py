"""Times in odometry.csv and frames.csv beyond ``tum.MAX_TIME`` (1e11 s) are refused by their
readers, naming the file and line. Before, any finite time was read: with every time of a drive
shifted by 1e12 s, ``semslam map`` and ``localize`` ran to the end and then the TUM writer
refused their own output (``M.trajectory.tum: pose 0: t 1e+12 is out of range``), and a time of
1e300 s was printed with 300 digits in the gap and coverage messages (found by semantic fuzzing
of the drive folder through the CLI)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from semslam.cli import app
from semslam.io import (
    FrameIndex,
    Odometry,
    read_frames,
    read_odometry,
    write_frames,
    write_odometry,
)
from semslam.io.errors import DriveFormatError
from semslam.io.odometry import check_covered

runner = CliRunner()


def _odometry_csv(path, times):
    path.write_text("t,speed,yaw_rate\n" + "".join(f"{float(t)!r},1.0,0.0\n" for t in times))
    return path


@pytest.mark.parametrize("t0", [1e12, -1e12, 1e300])
def test_odometry_times_beyond_max_time_are_refused(tmp_path, t0):
    path = _odometry_csv(tmp_path / "odometry.csv", t0 + np.arange(5) * 0.02)
    with pytest.raises(DriveFormatError, match=r"odometry\.csv line 2: t -?1e\+(12|300) s is "
                                               r"out of range \(\|t\| <= 1e\+11 s\)"):
        read_odometry(path)


def test_a_late_last_odometry_time_is_named_by_its_line(tmp_path):
    path = _odometry_csv(tmp_path / "odometry.csv", [0.0, 0.02, 0.04, 1e300])
    with pytest.raises(DriveFormatError, match=r"line 5: t 1e\+300 s is out of range") as e:
        read_odometry(path)
    assert len(str(e.value)) < 200


@pytest.mark.parametrize("t0", [1e12, -1e300])
def test_frame_times_beyond_max_time_are_refused(tmp_path, t0):
    path = tmp_path / "frames.csv"
    path.write_text(f"t\n0.0\n{t0!r}\n" if t0 > 0 else f"t\n{t0!r}\n0.0\n")
    line = 3 if t0 > 0 else 2
    with pytest.raises(DriveFormatError, match=rf"frames\.csv line {line}: t -?1e\+\d+ s is out"):
        read_frames(path)


def test_times_up_to_max_time_still_read(tmp_path):
    times = 1e11 - 1.0 + np.arange(5) * 0.02
    assert read_odometry(_odometry_csv(tmp_path / "odometry.csv", times)).t[0] == times[0]
    (tmp_path / "frames.csv").write_text("t\n" + "".join(f"{float(t)!r}\n" for t in times))
    assert read_frames(tmp_path / "frames.csv").t[-1] == times[-1]


def test_writers_refuse_what_the_readers_refuse(tmp_path):
    t = 1e12 + np.arange(3) * 0.02
    with pytest.raises(DriveFormatError, match=r"sample 0: t 1e\+12 s is out of range"):
        write_odometry(tmp_path / "odometry.csv", Odometry(t, np.ones(3), np.zeros(3)))
    with pytest.raises(DriveFormatError, match=r"frame 0: t 1e\+12 s is out of range"):
        write_frames(tmp_path / "frames.csv", FrameIndex(t, {}))
    assert not list(tmp_path.iterdir())


def test_coverage_message_stays_short():
    with pytest.raises(Exception, match=r"observations reach 1e\+300 s, after the odometry") as e:
        check_covered(1e300, (0.0, 10.0, 0.02))
    assert len(str(e.value)) < 200


def test_map_refuses_a_drive_shifted_by_1e12_before_any_work(tmp_path):
    drive = tmp_path / "drive"
    result = runner.invoke(app, ["simulate", str(drive), "--preset", "small", "--seed", "2",
                                 "--no-images", "--no-progress"])
    assert result.exit_code == 0, result.output
    odometry = (drive / "odometry.csv").read_text().splitlines()
    rows = [line.split(",", 1) for line in odometry[1:]]
    (drive / "odometry.csv").write_text(
        "\n".join([odometry[0], *(f"{float(t) + 1e12!r},{rest}" for t, rest in rows)]) + "\n")
    (drive / "frames.csv").write_text("t\n" + "".join(
        f"{float(t) + 1e12!r}\n" for t in (drive / "frames.csv").read_text().split()[1:]))
    path = drive / "observations" / "noisy.jsonl"
    frames = [json.loads(line) for line in path.read_text().splitlines()]
    path.write_text("".join(json.dumps({**f, "t": f["t"] + 1e12}) + "\n" for f in frames))
    result = runner.invoke(app, ["map", str(drive), "-o", str(tmp_path / "m.json"),
                                 "--no-progress"])
    assert result.exit_code == 2, (result.output, result.exception)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "odometry.csv line 2: t 1e+12 s is out of range (|t| <= 1e+11 s)" in lines[0]
    assert not list(tmp_path.glob("m.*"))
