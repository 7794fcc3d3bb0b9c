"""Frames less than a microsecond apart are refused by the readers of frames.csv and of the
observation files, naming the file and line. Before, they were read, and ``semslam localize``
ran to the end of the drive and then stopped on writing its trajectory ("T.tum: pose 1: time
0.000000 s repeats at the file's microseconds"), a message about its own output (found by
semantic fuzzing of the drive folder)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import make_frame

from semslam.errors import FormatError
from semslam.io import FrameIndex, read_frames, read_observations, write_frames, write_observations
from semslam.io.errors import DriveFormatError


def test_frames_csv_refuses_frames_repeating_to_the_microsecond(tmp_path):
    path = tmp_path / "frames.csv"
    path.write_text("t,topview\n0.0,a.png\n0.0000004,b.png\n0.1,c.png\n")
    with pytest.raises(DriveFormatError, match=r"frames\.csv line 3: time 0\.000000 repeats "
                                               r"the previous frame's to the microsecond"):
        read_frames(path)
    index = FrameIndex(t=np.array([0.0, 4e-7, 0.1]), images={"topview": ["a", "b", "c"]})
    with pytest.raises(DriveFormatError, match=r"frame 1: time 0\.000000 repeats"):
        write_frames(tmp_path / "out.csv", index)
    assert not (tmp_path / "out.csv").exists()


def test_observations_refuse_frames_repeating_to_the_microsecond(tmp_path):
    path = tmp_path / "obs.jsonl"
    with pytest.raises(FormatError, match=r"frame 1: time 1\.000000 repeats"):
        write_observations(path, [make_frame(1.0), make_frame(1.0000002)])
    assert not path.exists()
    write_observations(path, [make_frame(1.0), make_frame(1.1)])
    path.write_text(path.read_text().replace('"t":1.1', '"t":1.0000002'))
    with pytest.raises(FormatError, match=r"obs\.jsonl line 2: time 1\.000000 repeats"):
        read_observations(path)


def test_frames_a_microsecond_apart_still_read(tmp_path):
    path = tmp_path / "frames.csv"
    path.write_text("t,topview\n0.0,a.png\n0.000001,b.png\n0.1,c.png\n")
    assert len(read_frames(path)) == 3
