import json
import re
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from conftest import make_map

from semslam.errors import FormatError, MapError
from semslam.io import load_map, map_from_dict, map_to_dict, save_map
from semslam.io._schema import load_schema
from semslam.types import SemanticMap, SlotKind, TagFamily


def _saved(tmp_path: Path) -> tuple[Path, dict]:
    path = tmp_path / "map.json"
    save_map(path, make_map())
    return path, json.loads(path.read_text())


def _write(path: Path, document: dict) -> None:
    path.write_text(json.dumps(document))


def test_round_trip(tmp_path: Path) -> None:
    original = make_map()
    path = tmp_path / "out" / "map.json"
    save_map(path, original)
    loaded = load_map(path)
    assert map_to_dict(loaded) == map_to_dict(original)
    assert loaded.slots[0].corners.shape == (4, 2)
    assert loaded.slots[0].corner_covariances.shape == (4, 2, 2)
    assert loaded.slots[1].label is None
    assert loaded.tags[0].family is TagFamily.TAG36H11
    assert loaded.slots[0].kind is SlotKind.PERPENDICULAR
    np.testing.assert_array_equal(loaded.tags[0].mTt, original.tags[0].mTt)
    assert loaded.metadata["statistics"]["rmse"] == 0.031


def test_empty_map_round_trip(tmp_path: Path) -> None:
    save_map(tmp_path / "map.json", SemanticMap())
    loaded = load_map(tmp_path / "map.json")
    assert loaded.slots == () and loaded.tags == () and loaded.markings == ()


def test_file_is_pretty_and_has_header(tmp_path: Path) -> None:
    path, document = _saved(tmp_path)
    assert document["format"] == "semslam-map" and document["version"] == 1
    assert path.read_text().count("\n") > 20


def test_schema_is_valid_and_matches_enums() -> None:
    schema = load_schema("map")
    jsonschema.Draft202012Validator.check_schema(schema)
    defs = schema["$defs"]
    assert set(defs["tag"]["properties"]["family"]["enum"]) == {f.value for f in TagFamily}
    assert set(defs["slot"]["properties"]["kind"]["enum"]) == {k.value for k in SlotKind}


def test_saved_file_validates_against_schema(tmp_path: Path) -> None:
    _, document = _saved(tmp_path)
    jsonschema.validate(document, load_schema("map"))


def test_truncated_json(tmp_path: Path) -> None:
    path, _ = _saved(tmp_path)
    text = path.read_text()
    path.write_text(text[: len(text) // 2])
    with pytest.raises(MapError) as err:
        load_map(path)
    msg = str(err.value)
    assert str(path) in msg and "line" in msg and "truncated" in msg and "\n" not in msg


def test_not_json(tmp_path: Path) -> None:
    path = tmp_path / "map.json"
    path.write_text('{"format": "semslam-map",\n  oops}')
    with pytest.raises(MapError, match=r"map\.json: not valid JSON at line 2 column 3"):
        load_map(path)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(MapError, match=r"nothere\.json: file not found"):
        load_map(tmp_path / "nothere.json")


def test_wrong_format(tmp_path: Path) -> None:
    path, document = _saved(tmp_path)
    document["format"] = "semslam-rig"
    _write(path, document)
    with pytest.raises(
        MapError, match=r"map\.json: format is 'semslam-rig', expected 'semslam-map'"
    ):
        load_map(path)


def test_newer_version(tmp_path: Path) -> None:
    path, document = _saved(tmp_path)
    document["version"] = 2
    _write(path, document)
    with pytest.raises(MapError) as err:
        load_map(path)
    assert str(err.value) == f"{path}: version 2 is newer than this semslam reads (1)"


def test_schema_violation_names_field(tmp_path: Path) -> None:
    path, document = _saved(tmp_path)
    document["slots"][1]["corners"] = document["slots"][1]["corners"][:3]
    _write(path, document)
    with pytest.raises(MapError) as err:
        load_map(path)
    assert str(err.value) == f"{path}: slots/1/corners: expected 4 items, got 3"


@pytest.mark.parametrize(
    ("mutate", "pointer"),
    [
        (lambda d: d["slots"][0].update(kind="diagonal"), "slots/0/kind"),
        (lambda d: d["slots"][0].update(label_confidence=1.5), "slots/0/label_confidence"),
        (lambda d: d["slots"][0].pop("id"), "slots/0"),
        (lambda d: d["tags"][0].update(size=0), "tags/0/size"),
        (lambda d: d["tags"][0].update(family="qr"), "tags/0/family"),
        (lambda d: d["tags"][0]["covariance"].pop(), "tags/0/covariance"),
        (lambda d: d["markings"][0].update(width=-1), "markings/0/width"),
        (lambda d: d["markings"][0].update(a=[1, "x"]), "markings/0/a/1"),
        (lambda d: d["metadata"].update(created=5), "metadata/created"),
        (lambda d: d.update(extra=1), "(top level)"),
    ],
)
def test_schema_violations(tmp_path: Path, mutate, pointer: str) -> None:
    path, document = _saved(tmp_path)
    mutate(document)
    _write(path, document)
    with pytest.raises(MapError, match="^" + re.escape(f"{path}: {pointer}: ")) as err:
        load_map(path)
    assert "\n" not in str(err.value) and len(str(err.value)) < len(str(path)) + 150


def test_nan_is_refused_with_field(tmp_path: Path) -> None:
    path, _ = _saved(tmp_path)
    path.write_text(path.read_text().replace('"height": 1.1', '"height": NaN'))
    with pytest.raises(MapError, match=r"map\.json: tags/0/height: NaN is not allowed"):
        load_map(path)


def test_duplicate_slot_ids(tmp_path: Path) -> None:
    path, document = _saved(tmp_path)
    document["slots"][1]["id"] = document["slots"][0]["id"]
    _write(path, document)
    with pytest.raises(MapError, match=r"slots/1/id: duplicate id 3"):
        load_map(path)


def test_a_slot_whose_corners_coincide_is_refused(tmp_path: Path) -> None:
    """As a sighting's: four corners at one point are no slot (sides under 5 cm)."""
    path, document = _saved(tmp_path)
    document["slots"][1]["corners"] = [[2.0, 3.0]] * 4
    _write(path, document)
    with pytest.raises(MapError, match=r"slots/1/corners: a side of 0 m: corners must be at "
                                       r"least 0.05 m apart"):
        load_map(path)


def test_an_absurd_tag_yaw_is_refused(tmp_path: Path) -> None:
    path, document = _saved(tmp_path)
    document["tags"][0]["yaw"] = 1e300
    _write(path, document)
    with pytest.raises(MapError, match=r"tags/0/yaw: must be <= 1000"):
        load_map(path)


def test_save_refuses_bad_map_and_keeps_old_file(tmp_path: Path) -> None:
    path, _ = _saved(tmp_path)
    before = path.read_text()
    good = make_map()
    bad_slot = good.slots[0]
    broken = SemanticMap(
        slots=(
            type(bad_slot)(
                1,
                None,
                0.0,
                np.full((4, 2), np.nan),
                bad_slot.corner_covariances,
                SlotKind.PARALLEL,
            ),
        ),
    )
    with pytest.raises(MapError, match=r"slots/0/corners/0/0: NaN"):
        save_map(path, broken)
    assert path.read_text() == before


def test_map_from_dict_uses_source_name() -> None:
    with pytest.raises(MapError, match=r"^<dict>: expected a JSON object"):
        map_from_dict([1, 2])
    assert issubclass(MapError, FormatError)


def test_a_slot_heading_variance_round_trips_and_may_be_absent(tmp_path: Path) -> None:
    import dataclasses

    from semslam.geometry import rotation_variance

    original = make_map()
    with_heading = dataclasses.replace(
        original, slots=(dataclasses.replace(original.slots[0], heading_variance=3e-6),
                         *original.slots[1:]))
    save_map(tmp_path / "map.json", with_heading)
    loaded = load_map(tmp_path / "map.json")
    assert loaded.slots[0].heading_variance == 3e-6
    assert loaded.slots[0].orientation_variance == 3e-6
    # an older map without it: the corners' rotation variance, taken as independent
    other = loaded.slots[1]
    assert other.heading_variance is None
    assert other.orientation_variance == pytest.approx(
        rotation_variance(other.corners, other.corner_covariances))
    degenerate = dataclasses.replace(other, corners=np.zeros((4, 2)))
    assert degenerate.orientation_variance == 0.0  # no orientation, no heading floor
    document = json.loads((tmp_path / "map.json").read_text())
    document["slots"][0]["heading_variance"] = -1.0
    _write(tmp_path / "bad.json", document)
    with pytest.raises(MapError, match="heading_variance"):
        load_map(tmp_path / "bad.json")


def test_a_marking_sigma_round_trips_and_may_be_absent(tmp_path: Path) -> None:
    import dataclasses

    original = make_map()
    plain = original.markings[0]
    assert plain.sigma is None
    known = dataclasses.replace(plain, sigma=0.031)
    save_map(tmp_path / "map.json", dataclasses.replace(original, markings=(known, plain)))
    document = json.loads((tmp_path / "map.json").read_text())
    assert document["markings"][0]["sigma"] == 0.031
    assert "sigma" not in document["markings"][1]
    jsonschema.validate(document, load_schema("map"))
    loaded = load_map(tmp_path / "map.json")
    assert loaded.markings[0].sigma == 0.031 and loaded.markings[1].sigma is None
    for bad in (-0.1, 1e300):
        document["markings"][0]["sigma"] = bad
        _write(tmp_path / "bad.json", document)
        with pytest.raises(MapError, match="markings/0/sigma") as err:
            load_map(tmp_path / "bad.json")
        assert "\n" not in str(err.value)


def test_a_marking_across_covariance_round_trips_and_a_broken_one_is_refused(
    tmp_path: Path,
) -> None:
    import dataclasses

    original = make_map()
    plain = original.markings[0]
    assert plain.across_covariance is None
    ends = np.array([[0.01, 0.004], [0.004, 0.25]])
    known = dataclasses.replace(plain, sigma=0.3, across_covariance=ends)
    save_map(tmp_path / "map.json", dataclasses.replace(original, markings=(known, plain)))
    document = json.loads((tmp_path / "map.json").read_text())
    assert "across_covariance" not in document["markings"][1]
    jsonschema.validate(document, load_schema("map"))
    loaded = load_map(tmp_path / "map.json")
    np.testing.assert_array_equal(loaded.markings[0].across_covariance, ends)
    assert loaded.markings[1].across_covariance is None
    for bad in ([[0.01, 0.2], [0.2, 0.25]], [[0.01, 0.0], [0.001, 0.25]], [[0.01], [0.2]]):
        document["markings"][0]["across_covariance"] = bad
        _write(tmp_path / "bad.json", document)
        with pytest.raises(MapError, match="markings/0/across_covariance") as err:
            load_map(tmp_path / "bad.json")
        assert "\n" not in str(err.value)


def _paths(node, prefix=()):
    """Every (path, value) in a JSON document, containers included."""
    yield prefix, node
    if isinstance(node, dict):
        for key, value in node.items():
            yield from _paths(value, (*prefix, key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            yield from _paths(value, (*prefix, i))


def _replaced(document, path, value):
    copy = json.loads(json.dumps(document))
    if not path:
        return value
    node = copy
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return copy


def _removed(document, path):
    copy = json.loads(json.dumps(document))
    node = copy
    for key in path[:-1]:
        node = node[key]
    del node[path[-1]]
    return copy


def test_the_compiled_validator_agrees_with_jsonschema(tmp_path: Path) -> None:
    """The fast path of validation (fastjsonschema) accepts exactly what jsonschema accepts:
    a value at each place of a saved map replaced by each of a set of wrong or edge values,
    its key or array item removed, its array made one longer."""
    from semslam.io._schema import _validator, is_valid

    _, document = _saved(tmp_path)
    reference = _validator("map")
    swaps = [None, True, "x", -1, 0, 1.0, 0.5, 1.5, 1e20, [], [1.0], {"a": 1}]
    checked = refused = 0
    seen = set()
    for path, value in list(_paths(document)):
        place = tuple("*" if isinstance(key, int) else key for key in path)
        if place in seen:  # one of each place in the schema: slots/*/corners/*/*, ...
            continue
        seen.add(place)
        variants = [_replaced(document, path, swap) for swap in swaps if swap != value
                    or type(swap) is not type(value)]
        if path:
            variants.append(_removed(document, path))
        if isinstance(value, list):
            variants.append(_replaced(document, path, [*value, value[-1] if value else 0.0]))
        for variant in variants:
            expected = reference.is_valid(variant)
            assert is_valid(variant, "map") == expected, (path, variant if not path else None)
            checked += 1
            refused += not expected
    assert checked > 400 and refused > checked // 2


def test_another_kind_of_file_is_named_as_such_not_as_truncated(tmp_path: Path) -> None:
    path = tmp_path / "trajectory.tum"
    path.write_text("0.0 1 2 0 0 0 0 1\n0.1 1 2 0 0 0 0 1\n")
    with pytest.raises(MapError) as err:
        load_map(path)
    message = str(err.value)
    assert "it starts with '0': not a JSON document" in message and "truncated" not in message


def test_a_folder_given_as_the_map_is_named_as_one(tmp_path: Path) -> None:
    folder = tmp_path / "maps"
    folder.mkdir()
    with pytest.raises(MapError, match=r"maps: a folder, not a file$"):
        load_map(folder)


def test_covariances_checked_together_decide_as_one_by_one() -> None:
    """A slot's four corner covariances are checked in one batch (the map loads faster); the
    batch refuses exactly what the single check refuses, naming the first bad one."""
    from semslam.io._fields import Field, check_covariance, check_covariances

    rng = np.random.default_rng(3)
    bad_seen = 0
    for trial in range(300):
        a = rng.normal(size=(4, 2, 2))
        stack = a @ np.swapaxes(a, 1, 2)  # positive semi-definite
        k = int(rng.integers(4))
        kind = trial % 5
        if kind == 1:
            stack[k, 0, 1] += 1e-3  # not symmetric
        elif kind == 2:
            stack[k] = np.diag([1.0, -1e-3])  # indefinite
        elif kind == 3:
            stack[k, 0, 0] = 1e300  # huge
        elif kind == 4:
            stack[k] = np.outer([1.0, 2.0], [1.0, 2.0])  # singular, still fine
        doc = {"c": stack.tolist()}
        one_by_one = None
        for j in range(4):
            try:
                check_covariance(Field(doc, "m.json", MapError)["c"].items()[j], stack[j], 1e12)
            except MapError as exc:
                one_by_one = str(exc)
                break
        try:
            check_covariances(Field(doc, "m.json", MapError)["c"], stack, 1e12)
            together = None
        except MapError as exc:
            together = str(exc)
        assert together == one_by_one
        bad_seen += together is not None
        if kind in (1, 2, 3):
            assert together is not None and f"c/{k}" in together
    assert bad_seen == 180
