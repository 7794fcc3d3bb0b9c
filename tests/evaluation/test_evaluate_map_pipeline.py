"""`evaluate_map_files`: maps read from files, a JSON-ready result, clean errors."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from semslam.errors import ConfigError, MapError
from semslam.evaluation import transform_map
from semslam.geometry import inverse
from semslam.io import save_map
from semslam.pipeline.evaluate import evaluate_map_files
from semslam.simulation.world import make_world
from semslam.types import SemanticMap


@pytest.fixture(scope="module")
def world_map() -> SemanticMap:
    return make_world("small", 0).to_map()


def test_files_give_a_json_serialisable_dict(tmp_path, world_map):
    slots = list(world_map.slots)
    slots[0] = replace(slots[0], corners=slots[0].corners + 0.1, label=None)
    estimate = replace(world_map, slots=tuple(slots[:-1]), tags=(), markings=())
    save_map(tmp_path / "map.json", estimate)
    save_map(tmp_path / "world.json", world_map)
    result = evaluate_map_files(tmp_path / "map.json", tmp_path / "world.json")
    text = json.dumps(result, allow_nan=False)  # no NaN, no numpy values
    assert json.loads(text) == result
    assert result["map"] == str(tmp_path / "map.json")
    assert result["truth"] == str(tmp_path / "world.json")
    assert result["slots_matched"] == len(world_map.slots) - 1
    assert result["missed_slots"] == 1
    assert result["tags_matched"] == 0 and result["tags_rmse_m"] is None
    assert result["marking_endpoint_median_m"] is None
    assert result["alignment"] is None
    assert result["corner_rmse_m"] == pytest.approx(0.1 * math.sqrt(2) / math.sqrt(len(slots) - 1))


def test_align_flag_reports_the_transform(tmp_path, world_map):
    T = np.array([2.0, 1.0, math.radians(-5.0)])
    save_map(tmp_path / "map.json", transform_map(inverse(T), world_map))
    save_map(tmp_path / "world.json", world_map)
    result = evaluate_map_files(tmp_path / "map.json", tmp_path / "world.json", align=True)
    json.dumps(result, allow_nan=False)
    np.testing.assert_allclose(result["alignment"], [2.0, 1.0, -5.0], atol=1e-9)
    assert result["corner_rmse_m"] < 1e-9


def test_empty_map_file(tmp_path, world_map):
    save_map(tmp_path / "map.json", SemanticMap())
    save_map(tmp_path / "world.json", world_map)
    result = evaluate_map_files(tmp_path / "map.json", tmp_path / "world.json", align=True)
    json.dumps(result, allow_nan=False)
    assert result["slots_matched"] == 0 and result["corner_rmse_m"] is None


def test_missing_or_broken_files_and_bad_radius_are_one_line_errors(tmp_path, world_map):
    save_map(tmp_path / "world.json", world_map)
    with pytest.raises(MapError, match="nope.json") as err:
        evaluate_map_files(tmp_path / "nope.json", tmp_path / "world.json")
    assert "\n" not in str(err.value)
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(MapError, match="bad.json"):
        evaluate_map_files(tmp_path / "world.json", tmp_path / "bad.json")
    with pytest.raises(ConfigError, match="match_radius"):
        evaluate_map_files(tmp_path / "world.json", tmp_path / "world.json", match_radius=-1.0)
