"""A track CSV whose variances are positive but denormal (1e-315) is refused, naming the file,
line and column: its NEES overflowed to infinity and NaN, and ``semslam evaluate trajectory
--json`` ended in a traceback (json.dumps refusing NaN), the table printing ``nan`` (found by
semantic fuzzing of the evaluation)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from semslam.cli import app
from semslam.errors import FormatError
from semslam.io import read_track_csv, write_tum

HEADER = "t,x,y,yaw,cov_xx,cov_xy,cov_xyaw,cov_yy,cov_yyaw,cov_yawyaw,status,associated,rejected"


def _write_run(folder: Path, variance: str) -> tuple[Path, Path]:
    t = np.arange(30) * 0.1
    truth = np.column_stack([t * 2.0, np.zeros(30), np.zeros(30)])
    est = truth + [0.0, 0.1, 0.0]
    write_tum(folder / "gt.tum", t, truth)
    write_tum(folder / "run.tum", t, est)
    v = variance
    rows = [f"{float(ti)!r},{float(x)!r},{float(y)!r},0.0,{v},0.0,0.0,{v},0.0,{v},tracking,4,0"
            for ti, (x, y, _) in zip(t, est, strict=True)]
    (folder / "run.csv").write_text("\n".join([HEADER, *rows]) + "\n")
    return folder / "run.tum", folder / "gt.tum"


@pytest.mark.parametrize("variance", ["1e-315", "5e-324", "1e-31"])
def test_evaluate_refuses_a_denormal_variance_in_one_line(tmp_path, variance):
    traj, gt = _write_run(tmp_path, variance)
    for extra in (["--json"], []):
        result = CliRunner().invoke(app, ["evaluate", "trajectory", str(traj), "--truth", str(gt),
                                          *extra])
        assert result.exit_code == 2, (result.output, result.exception)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1, result.stderr
        assert "run.csv line 2: cov_" in lines[0] and "is below 1e-30" in lines[0]
        assert "nan" not in result.stdout


def test_zero_and_small_variances_still_read(tmp_path):
    for variance in ("0.0", "1e-30", "1e-12"):
        _write_run(tmp_path, variance)
        track = read_track_csv(tmp_path / "run.csv")
        assert track.covariances[0, 0, 0] == float(variance)
    _write_run(tmp_path, "1e-315")
    with pytest.raises(FormatError, match=r"run\.csv line 2: cov_\w+ 1e-315 is below 1e-30"):
        read_track_csv(tmp_path / "run.csv")


def test_a_variance_near_the_largest_float_gives_a_finite_nees_without_warnings(tmp_path):
    """At the other end, variances of 1.7e308 overflowed in the covariance's symmetrisation
    (``cov + cov.T``: a RuntimeWarning printed above the JSON); the pose is simply unknown."""
    traj, gt = _write_run(tmp_path, "1.7e308")
    with np.errstate(all="raise"):
        result = CliRunner().invoke(app, ["evaluate", "trajectory", str(traj), "--truth",
                                          str(gt), "--json"])
    assert result.exit_code == 0, (result.output, result.exception)
    assert "Warning" not in result.stderr
    report = json.loads(result.stdout)
    assert report["nees_frames"] == 30 and 0.0 <= report["nees_mean"] < 1e-100
