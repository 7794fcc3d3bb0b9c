"""Bad input found by the audit, refused by the library with one line naming what and where."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import make_map

import semslam.io.g2o as g2o_module
from semslam.analysis.accuracy import MapGeometry, predicted_on_grid
from semslam.config import LocalizationConfig, MappingConfig, load_config, with_overrides
from semslam.errors import ConfigError, DriveError, FormatError, MapError, MappingError
from semslam.io import Drive, map_from_dict, map_to_dict
from semslam.io.errors import DriveFormatError
from semslam.io.g2o import parse_g2o, read_g2o
from semslam.io.odometry import Odometry, read_odometry, write_odometry
from semslam.localization.localizer import Localizer
from semslam.mapping.mapper import Mapper
from semslam.mapping.pose_graph import optimize_pose_graph
from semslam.types import FrameObservations


def _one_line(exc: pytest.ExceptionInfo, *words: str) -> None:
    message = str(exc.value)
    assert "\n" not in message, message
    for word in words:
        assert word in message, (word, message)


# --------------------------------------------------------------------------- 1: no observations


def test_an_empty_observation_set_is_refused(drive_folder: Path) -> None:
    path = drive_folder / "observations" / "exact.jsonl"
    path.write_text("")
    with pytest.raises(DriveError) as exc:
        Drive.open(drive_folder).observations("exact")
    _one_line(exc, "exact.jsonl", "no observations")


def test_the_mapper_refuses_to_finish_without_frames() -> None:
    mapper = Mapper(MappingConfig(), np.zeros(3), np.array([0.0, 0.1]), np.ones(2), np.zeros(2))
    with pytest.raises(MappingError) as exc:
        mapper.finish()
    _one_line(exc, "no observation frames")


# --------------------------------------------------------------------------- 2: odometry values


@pytest.mark.parametrize(
    ("row", "column"), [("0.2,1e308,0.0", "speed"), ("0.2,1.0,-25", "yaw_rate")]
)
def test_impossible_odometry_is_refused_with_its_line(
    tmp_path: Path, row: str, column: str
) -> None:
    path = tmp_path / "odometry.csv"
    path.write_text(f"t,speed,yaw_rate\n0.0,1.0,0.0\n0.1,1.0,0.0\n{row}\n")
    with pytest.raises(DriveFormatError) as exc:
        read_odometry(path)
    _one_line(exc, "odometry.csv line 4", column, "impossible")


def test_plausible_odometry_still_reads_and_impossible_is_not_written(tmp_path: Path) -> None:
    path = tmp_path / "odometry.csv"
    plausible = Odometry(np.array([0.0, 0.1]), np.array([99.0, -3.0]), np.array([-19.0, 1.0]))
    write_odometry(path, plausible)
    assert read_odometry(path).speed[0] == 99.0
    with pytest.raises(DriveFormatError) as exc:
        write_odometry(path, Odometry(np.array([0.0]), np.array([101.0]), np.array([0.0])))
    _one_line(exc, "sample 0", "speed")


# --------------------------------------------------------------------------- 3: map values


def _map_document() -> dict:
    return json.loads(json.dumps(map_to_dict(make_map())))


@pytest.mark.parametrize(
    ("mutate", "words"),
    [
        (
            lambda d: d["slots"][0].__setitem__("corner_covariances", [[[-1, 0], [0, -1]]] * 4),
            ("slots/0/corner_covariances/0", "not positive semi-definite"),
        ),
        (
            lambda d: d["slots"][1].__setitem__("corner_covariances", [[[1, 5], [0, 1]]] * 4),
            ("slots/1/corner_covariances/0", "not symmetric"),
        ),
        (
            lambda d: d["tags"][0].__setitem__("covariance", (-np.eye(3)).tolist()),
            ("tags/0/covariance", "not positive semi-definite"),
        ),
        (
            lambda d: d["slots"][0]["corner_covariances"][1][0].__setitem__(0, 1e308),
            ("slots/0/corner_covariances/1", "out of range"),
        ),
        (
            lambda d: d["tags"][0].__setitem__("covariance", (1e13 * np.eye(3)).tolist()),
            ("tags/0/covariance", "out of range"),
        ),
        (
            lambda d: d["slots"][0].__setitem__("heading_variance", 1e300),
            ("slots/0/heading_variance", "must be <="),
        ),
        (
            lambda d: d["slots"][0]["corners"][2].__setitem__(0, 1e300),
            ("slots/0/corners", "out of range"),
        ),
        (lambda d: d["tags"][0].__setitem__("y", -2e6), ("tags/0", "out of range")),
        (lambda d: d["markings"][0].__setitem__("b", [1e7, 0.0]), ("markings/0/b", "out of range")),
        (
            lambda d: d["markings"][0].__setitem__("b", d["markings"][0]["a"]),
            ("markings/0", "zero-length"),
        ),
        (
            lambda d: d["tags"].append(dict(d["tags"][0], x=9.0)),
            ("tags/1", "duplicate tag", "id 5", "also tags/0"),
        ),
    ],
)
def test_map_values_are_checked(mutate, words) -> None:
    document = _map_document()
    mutate(document)
    with pytest.raises(MapError) as exc:
        map_from_dict(document, "m.json")
    _one_line(exc, "m.json: ", *words)


def test_a_valid_map_with_zero_covariances_still_loads() -> None:
    document = _map_document()
    document["slots"][0]["corner_covariances"] = [[[0, 0], [0, 0]]] * 4
    assert len(map_from_dict(document, "m.json").slots) == 2


# --------------------------------------------------------------------------- 4: g2o


@pytest.mark.parametrize("text", ["", "# only a comment\n\n", "VERTEX_XY 1 0 0\n"])
def test_a_g2o_file_without_poses_is_refused(tmp_path: Path, text: str) -> None:
    path = tmp_path / "g.g2o"
    path.write_text(text)
    with pytest.raises(FormatError) as exc:
        read_g2o(path)
    _one_line(exc, "g.g2o", "no VERTEX_SE2 lines")


_CHAIN = (
    "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\n"
    "EDGE_SE2 0 1 1 0 0 {v} 0 0 {v} 0 {v}\nEDGE_SE2 1 2 1 0 0 100 0 0 100 0 1000\n"
)


@pytest.mark.parametrize(
    ("value", "words"),
    [("1e-300", ("eigenvalue", "1e-300")), ("1e300", ("entry", "1e+300"))],
)
def test_ill_conditioned_information_is_refused_with_its_line(
    tmp_path: Path, value: str, words: tuple[str, ...]
) -> None:
    path = tmp_path / "g.g2o"
    path.write_text(_CHAIN.format(v=value))
    with pytest.raises(FormatError) as exc:
        read_g2o(path)
    _one_line(exc, "g.g2o line 4", "information matrix", *words)


def test_a_poorly_conditioned_information_matrix_is_refused() -> None:
    text = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1e13 0 0 1e13 0 0.1\n"
    with pytest.raises(FormatError) as exc:
        parse_g2o(text, "g.g2o")
    _one_line(exc, "g.g2o line 3", "ill-conditioned")


def test_an_indeterminate_system_is_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(g2o_module, "MIN_INFORMATION", 0.0)  # let the reader through
    graph = parse_g2o(_CHAIN.format(v="1e-15"), "g.g2o")
    with pytest.raises(MappingError) as exc:  # iSAM2 (auto would fall back to batch LM)
        optimize_pose_graph(graph, "maxmix", schedule="incremental")
    _one_line(exc, "indeterminate", "variable 1")


# --------------------------------------------------------------------------- 5: accuracy grid


def test_a_huge_accuracy_grid_is_refused_before_allocating() -> None:
    geometry = MapGeometry(make_map())
    with pytest.raises(ConfigError) as exc:
        predicted_on_grid(geometry, step=2e-3)
    _one_line(exc, "accuracy: a grid of", "cells", "--grid-step")
    with pytest.raises(ConfigError) as exc:  # the cell count overflowed a float here
        predicted_on_grid(geometry, step=1e-300)
    _one_line(exc, "accuracy: the grid step must be a number of metres >= 0.001, got 1e-300")
    with pytest.raises(ConfigError) as exc:
        predicted_on_grid(geometry, step=1.0, bounds=(0.0, 0.0, 1e6, 20.0))
    _one_line(exc, "1000001 x 21")
    with pytest.raises(ConfigError) as exc:  # one cell: matplotlib warned, the plot was empty
        predicted_on_grid(geometry, step=1e9)
    _one_line(exc, "leaves a grid of 1 x 1 cells", "lower --grid-step")


# --------------------------------------------------------------------------- 6, 7: config


def test_min_speed_above_max_speed_names_both(tmp_path: Path) -> None:
    path = tmp_path / "c.json"
    path.write_text('{"simulation": {"drive": {"min_speed": 5, "max_speed": 1}}}')
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    _one_line(exc, "c.json", "simulation.drive", "min_speed (5)", "max_speed (1)")


def test_false_for_a_switch_is_taken(tmp_path: Path) -> None:
    """(true for a number is refused: the table of refused files below)"""
    path = tmp_path / "c.json"
    path.write_text('{"mapping": {"use_markings": false}}')
    assert load_config(path).mapping.use_markings is False


def test_a_huge_integer_setting_is_refused_before_gtsam_overflows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "c.json"
    path.write_text('{"mapping": {"relinearize_skip": 99999999999999999999}}')
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    _one_line(exc, "c.json", "mapping.relinearize_skip", "out of range", "1,000,000")
    monkeypatch.setenv("SEMSLAM_MAPPING__RELINEARIZE_SKIP", "2147483648")  # crashed iSAM2
    with pytest.raises(ConfigError) as exc:
        load_config()
    _one_line(exc, "SEMSLAM_MAPPING__RELINEARIZE_SKIP", "out of range")


def test_a_semslam_variable_overrides_the_config_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "c.json"
    path.write_text('{"mapping": {"keyframe_distance": 2, "keyframe_angle_deg": 4}}')
    monkeypatch.setenv("SEMSLAM_MAPPING__KEYFRAME_DISTANCE", "3")
    config = load_config(path)
    assert (config.mapping.keyframe_distance, config.mapping.keyframe_angle_deg) == (3.0, 4.0)


def test_a_value_is_blamed_on_a_variable_only_if_the_variable_holds_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from semslam.config import with_overrides

    monkeypatch.setenv("SEMSLAM_MAPPING__OPTIMIZER", "none")
    with pytest.raises(ConfigError) as exc:
        with_overrides(load_config(), mapping={"optimizer": "bogus"})
    _one_line(exc, "configuration: mapping.optimizer")
    monkeypatch.setenv("SEMSLAM_MAPPING__OPTIMIZER", "bogus")
    with pytest.raises(ConfigError) as exc:
        load_config()
    _one_line(exc, "SEMSLAM_MAPPING__OPTIMIZER: mapping.optimizer")
    monkeypatch.delenv("SEMSLAM_MAPPING__OPTIMIZER")
    monkeypatch.setenv("SEMSLAM_MAPPING", '{"optimizer": "bogus"}')  # a section as JSON
    with pytest.raises(ConfigError) as exc:
        load_config()
    _one_line(exc, "SEMSLAM_MAPPING: mapping.optimizer")
    monkeypatch.setenv("SEMSLAM_MAPPING", '{"optimizer": "none"}')
    with pytest.raises(ConfigError) as exc:
        with_overrides(load_config(), mapping={"optimizer": "bogus"})
    _one_line(exc, "configuration: mapping.optimizer")


def test_a_config_that_never_ends_is_refused_without_filling_the_memory(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """`--config /dev/zero` read until the kernel killed it (23 GB); every text reader now
    stops after MAX_TEXT_BYTES (1 GiB; 4 KiB here)."""
    import semslam.io._text as text_module

    monkeypatch.setattr(text_module, "MAX_TEXT_BYTES", 4096)
    with pytest.raises(ConfigError) as exc:
        load_config(Path("/dev/zero"))
    _one_line(exc, "/dev/zero: larger than", "not a text file semslam reads")


def test_the_size_cap_reserves_no_memory_up_front(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``f.read(cap)`` reserved the whole cap (1 GiB) for every file read; with a cap of a
    terabyte a small file must still read."""
    import semslam.io._text as text_module

    monkeypatch.setattr(text_module, "MAX_TEXT_BYTES", 1 << 40)
    path = tmp_path / "c.json"
    path.write_text('{"mapping": {}}')
    assert load_config(path).mapping == MappingConfig()


def test_a_misspelt_section_in_a_semslam_variable_is_refused(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("SEMSLAM_MAPING__KEYFRAME_DISTANCE", "2")
    with pytest.raises(ConfigError) as exc:
        load_config()
    _one_line(exc, "SEMSLAM_MAPING__KEYFRAME_DISTANCE: no section 'maping'")


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (b"\xff\xfe{}", ["c.json line 1: not UTF-8 text"]),
        (b'{"mapping": {"calibration_walk": [-0.002, 2e-5]}}', ["calibration_walk", "sigmas >= 0"]),
        (b'{"mapping": {"calibration_walk": [NaN, 1]}}', ["calibration_walk", "not a finite"]),
        (b'{"mapping": {"reorder_growth": 0.5}}', ["reorder_growth", "0 (never) or a growth"]),
        (b'{"mapping": {"rebuild_share": 1.5}}',
         ["mapping.rebuild_share", "less than or equal to 1"]),
        (b'{"simulation": {"observation_noise": {"detection_confidence_range": [0.9, 0.1]}}}',
         ["detection_confidence_range", "0 <= low <= high <= 1"]),
        (b'{"simulation": {"observation_noise": {"label_confidence_range": [-3, 5]}}}',
         ["label_confidence_range", "0 <= low <= high <= 1"]),
        (b'{"simulation": {"drive": {"max_speed": true}}}',
         ["simulation.drive.max_speed", "expected a number, got true"]),
        # a switch where a word is meant: pydantic's own message, not "a number"
        (b'{"localization": {"update": true}}', ["localization.update", "valid string"]),
    ],
)
def test_config_files_that_would_break_a_run_later_are_refused(
    tmp_path: Path, content: bytes, words: list[str]
) -> None:
    path = tmp_path / "c.json"
    path.write_bytes(content)
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    _one_line(exc, "c.json", *words)


def test_a_frame_rate_that_does_not_divide_the_odometry_rate_is_refused(tmp_path: Path) -> None:
    """Frames fall on odometry samples: at 50 Hz odometry, 20 Hz frames would come at 25 Hz."""
    path = tmp_path / "c.json"
    path.write_text('{"simulation": {"drive": {"frame_rate": 20}}}')
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    _one_line(exc, "c.json", "simulation.drive", "frame_rate (20 Hz) must divide odometry_rate")


@pytest.mark.parametrize(
    ("field", "value"), [("odometry_rate", 1e9), ("frame_rate", 1000.0), ("odometry_rate", 0)]
)
def test_rates_are_bounded(tmp_path: Path, field: str, value: float) -> None:
    path = tmp_path / "c.json"
    path.write_text(json.dumps({"simulation": {"drive": {field: value}}}))
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    _one_line(exc, "c.json", f"simulation.drive.{field}")


@pytest.mark.parametrize(
    ("section", "field", "value"),
    [
        ("mapping", "pool_radius", 1e300),
        ("mapping", "speed_scale_sigma", 1e300),  # overflowed in the odometry factor
        ("localization", "yaw_acceleration_sigma", 1e300),  # the filter overflowed
        ("localization", "init_position_sigma", 1e12),
    ],
)
def test_absurd_real_settings_are_refused(
    tmp_path: Path, section: str, field: str, value: float
) -> None:
    path = tmp_path / "c.json"
    path.write_text(json.dumps({section: {field: value}}))
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    _one_line(exc, "c.json", f"{section}.{field}", f"{value:g} is out of range (|value| <= 1000)")


@pytest.mark.parametrize(
    ("section", "field", "value", "words"),
    [  # each hung for more than a minute on `small` (found by fuzzing)
        ("mapping", "marking_distance_gate", 1000.0, "less than or equal to 10"),
        ("mapping", "label_vote_gate", 1000.0, "less than or equal to 10"),
        ("mapping", "association_gate", 1000.0, "less than or equal to 10"),
        ("mapping", "id_gate", 1e300, "less than or equal to 10"),  # > 240 s on `garage`
        ("mapping", "marking_gap", 1000.0, "less than or equal to 20"),
        ("simulation.observation_noise", "slot_false_rate", 0.999999, "less than or equal to 0.9"),
        ("simulation.observation_noise", "marking_false_rate", 0.95, "less than or equal to 0.9"),
    ],
)
def test_gates_and_false_rates_are_bounded(
    tmp_path: Path, section: str, field: str, value: float, words: str
) -> None:
    settings: dict = {field: value}
    for name in reversed(section.split(".")):
        settings = {name: settings}
    path = tmp_path / "c.json"
    path.write_text(json.dumps(settings))
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    _one_line(exc, "c.json", f"{section}.{field}", words)


def test_the_defaults_and_large_counts_are_within_range() -> None:
    from pydantic import BaseModel

    from semslam.config import MAX_SETTING

    def reals(section):
        for name in type(section).model_fields:
            value = getattr(section, name)
            if isinstance(value, BaseModel):
                yield from reals(value)
            elif isinstance(value, float):
                yield value

    assert max(abs(v) for v in reals(load_config(None))) <= MAX_SETTING
    counts = with_overrides(load_config(None), mapping={"new_landmark_observations": 10**6})
    assert counts.mapping.new_landmark_observations == 10**6


def test_default_rates_are_valid() -> None:
    drive = load_config(None).simulation.drive
    assert drive.min_speed <= drive.max_speed and drive.odometry_rate <= 1000


def test_an_environment_variable_that_is_not_json_is_named(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("SEMSLAM_MAPPING", "{")
    with pytest.raises(ConfigError) as exc:
        load_config(None)
    _one_line(exc, "SEMSLAM_MAPPING: not valid JSON")


def test_an_invalid_environment_value_is_named_not_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "c.json"
    path.write_text("{}")
    monkeypatch.setenv("SEMSLAM_MAPPING__ROBUST", "sometimes")
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    _one_line(exc, "SEMSLAM_MAPPING__ROBUST: mapping.robust")
    assert "c.json" not in str(exc.value)
    monkeypatch.delenv("SEMSLAM_MAPPING__ROBUST")
    with pytest.raises(ConfigError) as exc:
        with_overrides(load_config(path), mapping={"robust": "sometimes"})
    _one_line(exc, "mapping.robust")


# --------------------------------------------------------------------------- 8: odometry too short


def _short_odometry() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.arange(0.0, 1.0, 0.1)  # ends at 0.9 s, period 0.1 s
    return t, np.ones_like(t), np.zeros_like(t)


def test_the_mapper_refuses_frames_after_the_odometry() -> None:
    mapper = Mapper(MappingConfig(), np.zeros(3), *_short_odometry())
    mapper.add_frame(FrameObservations(t=0.0))
    mapper.add_frame(FrameObservations(t=1.0))  # within one period: fine
    with pytest.raises(DriveError) as exc:
        mapper.add_frame(FrameObservations(t=5.0))
    _one_line(exc, "observations reach 5.000 s", "after the odometry", "0.900 s")


def test_the_mapper_refuses_frames_before_the_odometry() -> None:
    t, v, w = _short_odometry()
    mapper = Mapper(MappingConfig(), np.zeros(3), t + 2.0, v, w)
    with pytest.raises(DriveError) as exc:
        mapper.add_frame(FrameObservations(t=0.0))
    _one_line(exc, "observations start at 0.000 s", "before the odometry (2.000 s)")


def test_the_localizer_refuses_frames_after_the_odometry() -> None:
    localizer = Localizer(make_map(), LocalizationConfig(), *_short_odometry(), np.zeros(3))
    localizer.step(FrameObservations(t=0.5))
    with pytest.raises(DriveError) as exc:
        localizer.step(FrameObservations(t=3.0))
    _one_line(exc, "observations reach 3.000 s", "after the odometry")


# --------------------------------------------------------------------------- a key twice


def test_a_key_twice_in_one_object_is_refused(tmp_path: Path) -> None:
    """Python's json keeps the last of two equal keys silently; every reader refuses it."""
    from semslam.io import load_map, read_observations

    path = tmp_path / "map.json"
    path.write_text('{"version": 1, "version": 1, "slots": [], "tags": [], "markings": []}')
    with pytest.raises(MapError) as exc:
        load_map(path)
    _one_line(exc, str(path), "duplicate key 'version'")
    path = tmp_path / "obs.jsonl"
    path.write_text('{"t": 0.0}\n{"t": 1.0, "t": 0.5}\n')
    with pytest.raises(FormatError) as exc:
        read_observations(path)
    _one_line(exc, f"{path} line 2", "duplicate key 't'")
    path = tmp_path / "config.json"
    path.write_text('{"mapping": {"keyframe_distance": 1.0, "keyframe_distance": 2.0}}')
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    _one_line(exc, str(path), "duplicate key 'keyframe_distance'")


@pytest.mark.parametrize("text, words", [
    ("[" * 100_000, "nested too deeply"),
    ('{"a": ' + "9" * 5000 + "}", "an integer of more than"),
])
def test_json_python_cannot_parse_is_named_in_plain_words(
    tmp_path: Path, text: str, words: str
) -> None:
    """Nesting past Python's recursion limit and integers past its digit limit: the message
    says what the file holds, not which Python setting would take it."""
    path = tmp_path / "m.json"
    path.write_text(text)
    with pytest.raises(MapError) as exc:
        from semslam.io import load_map

        load_map(path)
    _one_line(exc, "m.json", "not valid JSON", words)
    assert "sys." not in str(exc.value) and "recursion" not in str(exc.value)
