"""A JSON string holding a lone UTF-16 surrogate is refused when read (found by fuzzing the
readers with a read-then-write oracle): it read as a name or label, and the writer that
took it (save_rig, save_map, write_drive_info) failed with UnicodeEncodeError."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import write_drive

from semslam.errors import FormatError
from semslam.io import load_map, load_rig, read_drive_info, read_observations
from semslam.io.drive import DRIVE_JSON, RIG_JSON, WORLD_JSON


def _replace_once(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


@pytest.mark.parametrize(
    ("name", "old", "new", "read", "error"),
    [
        (RIG_JSON, '"name": "front"', '"name": "\\ud800"', load_rig,
         r"rig.json: not valid JSON: cameras/0/name: .*surrogate"),
        (WORLD_JSON, '"B17"', '"B\\udc0017"', load_map, r"slots/0/label: .*lone surrogate"),
        (DRIVE_JSON, '"name": "test"', '"name": "\\ud83d"', read_drive_info,
         r"name: .*lone surrogate"),
        ("observations/exact.jsonl", '"label":"A3"', '"label":"\\udfff"', read_observations,
         r"exact.jsonl line 1: not valid JSON: slots/0/label"),
        (DRIVE_JSON, '"source": {', '"source": {"\\ud800": 1, ', read_drive_info,
         r"source/\?: .*lone surrogate"),  # a key
    ],
)
def test_a_string_or_key_with_a_lone_surrogate_is_refused(
    tmp_path: Path, name: str, old: str, new: str, read, error: str
) -> None:
    write_drive(tmp_path)
    _replace_once(tmp_path / name, old, new)
    with pytest.raises(FormatError, match=error):
        read(tmp_path / name)


def test_an_escaped_surrogate_pair_still_reads(tmp_path: Path) -> None:
    write_drive(tmp_path)
    _replace_once(tmp_path / DRIVE_JSON, '"name": "test"', '"name": "car \\ud83d\\ude97"')
    assert read_drive_info(tmp_path / DRIVE_JSON).name == "car \U0001F697"
    assert json.loads('"\\ud83d\\ude97"') == "\U0001F697"
