"""Infinity written as a float literal of over 308 digits in a map's free-form metadata is
refused like NaN (found by fuzzing load_map with a read-then-write oracle: it loaded, and
save_map then refused the map it returned)."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import make_map, write_drive

from semslam.errors import MapError
from semslam.io import load_map, save_map
from semslam.io.drive import WORLD_JSON


def test_an_overflowing_literal_in_the_metadata_is_refused(tmp_path: Path) -> None:
    write_drive(tmp_path)
    path = tmp_path / WORLD_JSON
    text = path.read_text()
    assert '"rmse": 0.031' in text
    path.write_text(text.replace('"rmse": 0.031', '"rmse": ' + "1" * 400 + ".0"))
    with pytest.raises(MapError, match="world.json: metadata/statistics/rmse: Infinity is not"):
        load_map(path)


def test_a_map_that_loads_saves(tmp_path: Path) -> None:
    save_map(tmp_path / "m.json", make_map())
    save_map(tmp_path / "again.json", load_map(tmp_path / "m.json"))
