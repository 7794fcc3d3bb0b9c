"""A map slot whose orientation variance is huge (its ``heading_variance`` 1e12 rad^2, or
corner covariances of 1e12 m^2 on a slot a few centimetres wide) says only that its heading
is unknown: the localizer takes it as that, where its heading floor made the next frame's
innovation covariance singular (numpy's LinAlgError, a traceback; found by semantic fuzzing
of ``semslam localize``)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from semslam.cli import app
from semslam.types import Slot

runner = CliRunner()
RECTANGLE = np.array([[0.0, 0.0], [2.5, 0.0], [2.5, 5.0], [0.0, 5.0]])


def _run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def small_drive(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "drive"
    result = _run("simulate", out, "--preset", "small", "--seed", "2", "--no-images",
                  "--no-progress")
    assert result.exit_code == 0, result.output
    return out


@pytest.mark.parametrize("variance", [1e12, 1e300])
def test_a_huge_heading_variance_is_a_heading_not_known(variance):
    from semslam.types import MAX_ORIENTATION_VARIANCE

    cov = np.tile(np.eye(2) * 1e-4, (4, 1, 1))
    slot = Slot(0, None, 0.0, RECTANGLE, cov, "perpendicular", 3, heading_variance=variance)
    assert slot.orientation_variance == MAX_ORIENTATION_VARIANCE
    tiny = Slot(0, None, 0.0, RECTANGLE * 0.025, np.tile(np.eye(2) * 1e12, (4, 1, 1)),
                "perpendicular", 3)
    assert tiny.orientation_variance == MAX_ORIENTATION_VARIANCE
    assert math.isclose(Slot(0, None, 0.0, RECTANGLE, cov, "perpendicular", 3,
                             heading_variance=1e-6).orientation_variance, 1e-6)


def test_localize_against_a_map_of_huge_heading_variances(small_drive, tmp_path):
    document = json.loads((small_drive / "world.json").read_text())
    for slot in document["slots"]:
        slot["heading_variance"] = 1e12  # within the map's MAX_VARIANCE: the reader takes it
    path = tmp_path / "map.json"
    path.write_text(json.dumps(document))
    result = _run("localize", small_drive, "--map", path, "-o", tmp_path / "t.tum",
                  "--no-progress")
    assert result.exit_code == 0, (result.output, result.exception)
    assert "Traceback" not in result.output
    track = (tmp_path / "t.csv").read_text()
    assert "nan" not in track and "inf" not in track
