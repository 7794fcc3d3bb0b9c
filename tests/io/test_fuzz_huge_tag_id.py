"""A tag ID beyond any AprilTag family (2^62, 10^30) is refused by the readers, naming the file,
line and field: the mapper keys a tag's graph variable by its ID, and gtsam's symbols hold only
IDs below 2^56 (``semslam map`` ended in a ValueError or TypeError traceback; found by
semantic fuzzing of the pipelines)."""

from __future__ import annotations

import json

import pytest
from conftest import make_frame, make_map
from typer.testing import CliRunner

from semslam.cli import app
from semslam.errors import FormatError, MapError
from semslam.io import map_to_dict
from semslam.io.map_json import map_from_dict
from semslam.io.observations import frame_observations_from_dict, frame_observations_to_dict

runner = CliRunner()


def _run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.mark.parametrize("tag_id", [2**56, 2**62, 2**63, 10**30])
def test_readers_refuse_a_tag_id_beyond_any_family(tag_id):
    frame = frame_observations_to_dict(make_frame(1.0))
    frame["tags"][0]["id"] = tag_id
    with pytest.raises(FormatError, match=r"obs line 3: tags/0/id: must be <= 1000000"):
        frame_observations_from_dict(frame, "obs line 3")
    document = map_to_dict(make_map())
    document["tags"][0]["id"] = tag_id
    with pytest.raises(MapError, match=r"m\.json: tags/0/id: must be <= 1000000"):
        map_from_dict(document, "m.json")


def test_ids_of_the_families_still_read():
    frame = frame_observations_to_dict(make_frame(1.0))
    for tag_id in (0, 586, 2114, 10**6):
        frame["tags"][0]["id"] = tag_id
        assert frame_observations_from_dict(frame, "obs").tags[0].tag_id == tag_id


def test_map_refuses_a_huge_tag_id_in_one_line(tmp_path):
    drive = tmp_path / "drive"
    result = _run("simulate", drive, "--preset", "small", "--seed", "2", "--no-images",
                  "--no-progress")
    assert result.exit_code == 0, result.output
    path = drive / "observations" / "noisy.jsonl"
    frames = [json.loads(line) for line in path.read_text().splitlines()]
    assert any(f.get("tags") for f in frames)
    for frame in frames:
        for tag in frame.get("tags") or []:
            tag["id"] = 2**62
    path.write_text("".join(json.dumps(f) + "\n" for f in frames))
    result = _run("map", drive, "-o", tmp_path / "m.json", "--no-progress")
    assert result.exit_code == 2, (result.output, result.exception)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "noisy.jsonl line" in lines[0] and "tags/0/id: must be <= 1000000" in lines[0]
