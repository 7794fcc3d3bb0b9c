"""`semslam evaluate markings`: a map's painted lines against a vector map, from files."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from semslam.cli import app
from semslam.errors import ConfigError
from semslam.io import save_map, write_tum
from semslam.pipeline.evaluate import evaluate_markings_files
from semslam.types import Marking, SemanticMap


def _files(tmp_path: Path) -> tuple[Path, Path]:
    """A map with a line 0.1 m off a vector-map line and 1 m longer, and a drive along it."""
    save_map(
        tmp_path / "map.json",
        SemanticMap(markings=(Marking(np.array([0.0, 0.1]), np.array([5.0, 0.1]), 0.12),)),
    )
    write_tum(tmp_path / "map.trajectory.tum", [0.0, 1.0], [[0.0, 2.0, 0.0], [5.0, 2.0, 0.0]])
    folder = tmp_path / "vector_map"
    folder.mkdir()
    # point.csv columns are swapped against the map frame: x = Ly, y = Bx
    (folder / "point.csv").write_text("PID,Bx,Ly\n1,0.0,0.0\n2,0.0,4.0\n")
    (folder / "line.csv").write_text("LID,BPID,FPID\n1,1,2\n")
    return tmp_path / "map.json", folder


def test_both_ways_from_files(tmp_path: Path) -> None:
    map_path, folder = _files(tmp_path)
    result = evaluate_markings_files(map_path, folder)
    assert json.loads(json.dumps(result, allow_nan=False)) == result
    assert result["trajectory"] == str(tmp_path / "map.trajectory.tum")
    # vector map -> map: both end points 0.1 m from the mapped line
    assert result["vector_points"] == 2 and result["matched"] == 2
    assert result["median_m"] == pytest.approx(0.1)
    # map -> vector map: 0.1 m, and the overhanging end sqrt(1 + 0.01) m
    assert result["mapped_points"] == 2 and result["precision_matched"] == 1
    assert result["precision_median_m"] == pytest.approx(0.5 * (0.1 + math.sqrt(1.01)))
    assert result["precision_max_m"] == pytest.approx(math.sqrt(1.01))
    # a far area leaves nothing to compare
    write_tum(tmp_path / "far.tum", [0.0, 1.0], [[100.0, 0.0, 0.0], [101.0, 0.0, 0.0]])
    empty = evaluate_markings_files(map_path, folder, tmp_path / "far.tum")
    assert empty["vector_points"] == 0 and empty["median_m"] is None


def test_the_reference_can_be_a_map_file(tmp_path: Path) -> None:
    map_path, _ = _files(tmp_path)
    save_map(
        tmp_path / "reference.json",
        SemanticMap(markings=(Marking(np.array([0.0, 0.0]), np.array([4.0, 0.0]), 0.1),)),
    )
    result = evaluate_markings_files(map_path, tmp_path / "reference.json")
    assert result["median_m"] == pytest.approx(0.1) and result["precision_matched"] == 1


def test_bad_arguments_are_one_line_errors(tmp_path: Path) -> None:
    map_path, folder = _files(tmp_path)
    with pytest.raises(ConfigError, match="radius"):
        evaluate_markings_files(map_path, folder, radius=float("nan"))
    (tmp_path / "map.trajectory.tum").unlink()
    runner = CliRunner()
    res = runner.invoke(app, ["evaluate", "markings", str(map_path), "--vector-map", str(folder)])
    assert res.exit_code == 2
    assert "map.trajectory.tum: missing" in res.output and "Traceback" not in res.output
    write_tum(tmp_path / "drive.tum", [0.0, 1.0], [[0.0, 2.0, 0.0], [5.0, 2.0, 0.0]])
    res = runner.invoke(
        app,
        ["evaluate", "markings", str(map_path), "--vector-map", str(tmp_path / "nowhere"),
         "--trajectory", str(tmp_path / "drive.tum")],
    )
    assert res.exit_code == 2 and "nowhere: vector map folder not found" in res.output
