"""Odometry sampled faster than ``odometry.MAX_RATE`` (2 kHz, by the median interval) is refused
by the reader. Before, a 94 s drive's odometry.csv resampled to 50 kHz (4.7 million rows) was
read, and ``semslam localize`` ran for over 2 minutes (the localizer predicts and updates its
filter at every sample; found by semantic fuzzing of the drive folder through the CLI, with a
120 s limit)."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.io import Odometry, read_odometry, write_odometry
from semslam.io.errors import DriveFormatError


def _odometry_csv(path, rate_hz, seconds=1.0):
    t = np.arange(int(seconds * rate_hz) + 1) / rate_hz
    path.write_text("t,speed,yaw_rate\n" + "".join(f"{float(x)!r},1.0,0.0\n" for x in t))
    return path


@pytest.mark.parametrize("rate", [5000.0, 50_000.0])
def test_odometry_faster_than_max_rate_is_refused(tmp_path, rate):
    path = _odometry_csv(tmp_path / "odometry.csv", rate)
    with pytest.raises(DriveFormatError, match=r"odometry\.csv: samples 0\.\d+ ms apart \(the "
                                               r"median interval\), over 2000 Hz"):
        read_odometry(path)


@pytest.mark.parametrize("rate", [10.0, 50.0, 1000.0, 2000.0])
def test_odometry_up_to_max_rate_still_reads(tmp_path, rate):
    assert len(read_odometry(_odometry_csv(tmp_path / "odometry.csv", rate))) > 10


def test_a_few_close_samples_are_no_rate(tmp_path):
    t = np.r_[0.0, 1e-9, 2e-9, np.arange(1, 50) * 0.02]
    path = tmp_path / "odometry.csv"
    path.write_text("t,speed,yaw_rate\n" + "".join(f"{float(x)!r},1.0,0.0\n" for x in t))
    assert len(read_odometry(path)) == len(t)


def test_writer_refuses_it_too(tmp_path):
    t = np.arange(100) / 10_000.0
    with pytest.raises(DriveFormatError, match=r"over 2000 Hz"):
        write_odometry(tmp_path / "odometry.csv", Odometry(t, np.ones(100), np.zeros(100)))
    assert not (tmp_path / "odometry.csv").exists()
