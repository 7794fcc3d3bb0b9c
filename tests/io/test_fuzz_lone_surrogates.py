"""A JSON string holding a lone UTF-16 surrogate is refused when read (found by fuzzing the
readers with a read-then-write oracle): it read as a name or label, and the writer that
took it (save_rig, save_map, write_drive_info) failed with UnicodeEncodeError."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import write_drive

from semslam.errors import FormatError, MapError
from semslam.io import load_map, load_rig, read_drive_info, read_observations
from semslam.io.drive import DRIVE_JSON, RIG_JSON, WORLD_JSON


def _replace_once(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


def test_a_rig_camera_name_with_a_lone_surrogate_is_refused(tmp_path: Path) -> None:
    write_drive(tmp_path)
    _replace_once(tmp_path / RIG_JSON, '"name": "front"', '"name": "\\ud800"')
    with pytest.raises(FormatError, match=r"rig.json: not valid JSON: cameras/0/name: .*surrogate"):
        load_rig(tmp_path / RIG_JSON)


def test_a_map_label_or_metadata_with_a_lone_surrogate_is_refused(tmp_path: Path) -> None:
    write_drive(tmp_path)
    _replace_once(tmp_path / WORLD_JSON, '"B17"', '"B\\udc0017"')
    with pytest.raises(MapError, match=r"slots/0/label: .*lone surrogate"):
        load_map(tmp_path / WORLD_JSON)


def test_a_drive_name_and_an_observation_label_with_a_lone_surrogate_are_refused(
    tmp_path: Path,
) -> None:
    write_drive(tmp_path)
    _replace_once(tmp_path / DRIVE_JSON, '"name": "test"', '"name": "\\ud83d"')
    with pytest.raises(FormatError, match=r"name: .*lone surrogate"):
        read_drive_info(tmp_path / DRIVE_JSON)
    obs = tmp_path / "observations" / "exact.jsonl"
    _replace_once(obs, '"label":"A3"', '"label":"\\udfff"')
    with pytest.raises(FormatError, match=r"exact.jsonl line 1: not valid JSON: slots/0/label"):
        read_observations(obs)


def test_a_key_with_a_lone_surrogate_is_refused(tmp_path: Path) -> None:
    write_drive(tmp_path)
    _replace_once(tmp_path / DRIVE_JSON, '"source": {', '"source": {"\\ud800": 1, ')
    with pytest.raises(FormatError, match=r"source/\?: .*lone surrogate"):
        read_drive_info(tmp_path / DRIVE_JSON)


def test_an_escaped_surrogate_pair_still_reads(tmp_path: Path) -> None:
    write_drive(tmp_path)
    _replace_once(tmp_path / DRIVE_JSON, '"name": "test"', '"name": "car \\ud83d\\ude97"')
    assert read_drive_info(tmp_path / DRIVE_JSON).name == "car \U0001F697"
    assert json.loads('"\\ud83d\\ude97"') == "\U0001F697"
