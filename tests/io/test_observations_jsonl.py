import json
from pathlib import Path

import numpy as np
import pytest
from conftest import make_frame
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from semslam.errors import FormatError
from semslam.io import (
    frame_observations_from_dict,
    frame_observations_to_dict,
    read_observations,
    write_observations,
)
from semslam.types import (
    FrameObservations,
    MarkingObservation,
    SlotKind,
    SlotObservation,
    TagFamily,
    TagObservation,
)

real = st.floats(-1e6, 1e6, allow_nan=False)
metres = st.floats(-1e3, 1e3, allow_nan=False)  # an observation's reach (MAX_RANGE)
unit = st.floats(0.0, 1.0)
positive = st.floats(1e-6, 1e3)


def arrays(shape: tuple[int, ...], values=metres) -> st.SearchStrategy[np.ndarray]:
    n = int(np.prod(shape))
    return st.lists(values, min_size=n, max_size=n).map(lambda v: np.array(v).reshape(shape))


covariances = arrays((3, 3), st.floats(-10.0, 10.0)).map(lambda a: a @ a.T)  # PSD


def _has_sides(corners: np.ndarray) -> bool:
    return bool(np.hypot(*(np.roll(corners, -1, axis=0) - corners).T).min() >= 0.05)


slots = st.builds(
    SlotObservation,
    vCorners=arrays((4, 2)).filter(_has_sides),
    kind=st.sampled_from(SlotKind),
    label=st.none() | st.text(max_size=8),
    label_confidence=unit,
    confidence=unit,
    corner_sigma=st.floats(0.0, 10.0),
    corner_sigma_own=st.none() | st.tuples(*[st.floats(0.0, 10.0)] * 4),
    corner_sigma_shared=st.none() | st.tuples(*[st.floats(0.0, 10.0)] * 4),
)
tags = st.builds(
    TagObservation,
    family=st.sampled_from(TagFamily),
    tag_id=st.integers(0, 10**6),
    size=positive,
    vTt=st.tuples(metres, metres, st.floats(-1e3, 1e3)).map(np.array),  # yaw: MAX_YAW
    height=real,
    covariance=covariances,
)
markings = st.builds(
    MarkingObservation,
    vA=arrays((2,)),
    vB=arrays((2,)),
    width=positive,
    confidence=unit,
    sigma=st.none() | positive,
)


@st.composite
def frame_lists(draw: st.DrawFn) -> list[FrameObservations]:
    # frames at least 10 us apart: times repeating to the microsecond are refused
    times = sorted({n / 1e5 for n in draw(st.lists(st.integers(-10**11, 10**11), max_size=6))})
    return [
        FrameObservations(
            t=t,
            slots=tuple(draw(st.lists(slots, max_size=3))),
            tags=tuple(draw(st.lists(tags, max_size=2))),
            markings=tuple(draw(st.lists(markings, max_size=2))),
        )
        for t in times
    ]


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(frame_lists())
def test_round_trip(tmp_path: Path, frames: list[FrameObservations]) -> None:
    path = tmp_path / "obs.jsonl"
    write_observations(path, frames)
    loaded = read_observations(path)
    assert [frame_observations_to_dict(f) for f in loaded] == [
        frame_observations_to_dict(f) for f in frames
    ]
    assert len(path.read_text().splitlines()) == len(frames)


def test_types_after_reading(tmp_path: Path) -> None:
    path = tmp_path / "obs.jsonl"
    write_observations(path, (make_frame(t) for t in (0.0, 0.1)))
    frame = read_observations(path)[1]
    assert frame.t == 0.1
    assert frame.slots[0].vCorners.shape == (4, 2) and frame.slots[0].kind is SlotKind.PARALLEL
    assert frame.tags[0].vTt.shape == (3,) and frame.tags[0].covariance.shape == (3, 3)
    assert frame.tags[0].family is TagFamily.TAG25H9
    assert frame.markings[0].vA.shape == (2,)


def test_missing_lists_mean_nothing_seen() -> None:
    frame = frame_observations_from_dict({"t": 3.0})
    assert frame.slots == () and frame.tags == () and frame.markings == ()


def test_empty_file_is_no_frames(tmp_path: Path) -> None:
    path = tmp_path / "obs.jsonl"
    write_observations(path, [])
    assert read_observations(path) == []


def _lines(n: int = 3) -> list[dict]:
    return [frame_observations_to_dict(make_frame(0.1 * i)) for i in range(n)]


def _write(path: Path, documents: list[dict]) -> None:
    path.write_text("".join(json.dumps(d) + "\n" for d in documents))


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (
            lambda d: d["slots"][0]["corners"].pop(),
            r"obs\.jsonl line 3: slots/0/corners: expected 4 points, got 3",
        ),
        (
            lambda d: d["slots"][0]["corners"].__setitem__(1, d["slots"][0]["corners"][0]),
            r"obs\.jsonl line 3: slots/0/corners: a side of 0 m: corners must be at least 0.05 m",
        ),
        (
            lambda d: d["slots"][0].update(kind="round"),
            r"line 3: slots/0/kind: 'round' is not one of",
        ),
        (
            lambda d: d["slots"][0].update(confidence=2),
            r"line 3: slots/0/confidence: must be <= 1\.0",
        ),
        (lambda d: d["tags"][0].pop("size"), r"line 3: tags/0: missing field 'size'"),
        (lambda d: d["tags"][0].update(id=1.5), r"line 3: tags/0/id: expected an integer"),
        (
            lambda d: d["tags"][0]["covariance"][1].append(0),
            r"line 3: tags/0/covariance/1: expected 3 numbers, got 4",
        ),
        (
            lambda d: d["markings"][0].update(a=[1.0, float("nan")]),
            r"line 3: markings/0/a/1: NaN is not allowed",
        ),
        (  # NaN in a field no reader looks at: found by the scan of the line's text
            lambda d: d["markings"][0].update(note=[float("nan")]),
            r"line 3: markings/0/note/0: NaN is not allowed",
        ),
        (
            lambda d: d["slots"][0]["corners"][2].__setitem__(0, float("-inf")),
            r"line 3: slots/0/corners/2/0: -Infinity is not allowed",
        ),
        (  # true is 1 to numpy, not a number here
            lambda d: d["markings"][0].update(b=[True, 1.0]),
            r"line 3: markings/0/b/0: expected a number, got true/false",
        ),
        (
            lambda d: d["markings"][0].update(b=[10**400, 1.0]),
            r"line 3: markings/0/b/0: number too large",
        ),
        (
            lambda d: d["markings"][0].update(b=[[1.0], 1.0]),
            r"line 3: markings/0/b/0: expected a number, got an array",
        ),
        (
            lambda d: d["markings"][0].update(sigma=-0.1),
            r"line 3: markings/0/sigma: must be > 0",
        ),
        (  # finite but absurd: a broken file, and the filters' squares would overflow
            lambda d: d["slots"][0]["corners"][1].__setitem__(1, -1e300),
            r"line 3: slots/0/corners: -1e\+300 is out of range \(\|value\| <= 1000\)",
        ),
        (
            lambda d: d["markings"][0].update(a=[2.0, 5e3]),
            r"line 3: markings/0/a: 5000 is out of range",
        ),
        (
            lambda d: d["markings"][0].update(width=1e300),
            r"line 3: markings/0/width: must be <= 1000\.0",
        ),
        (
            lambda d: d["slots"][0].update(corner_sigma=1e200),
            r"line 3: slots/0/corner_sigma: must be <= 1000\.0",
        ),
        (
            lambda d: d["slots"][0].update(corner_sigma_own=[0.01, 0.01, 0.02]),
            r"line 3: slots/0/corner_sigma_own: expected 4 numbers, got 3",
        ),
        (
            lambda d: d["slots"][0].update(corner_sigma_shared=[0.01, 0.01, -0.02, 0.02]),
            r"line 3: slots/0/corner_sigma_shared: a sigma below 0",
        ),
        (lambda d: d["tags"][0].update(y=-2e3), r"line 3: tags/0/y: must be >= -1000\.0"),
        (
            lambda d: d["tags"][0].update(covariance=[[1, 0, 0], [0, -1, 0], [0, 0, 1]]),
            r"line 3: tags/0/covariance: not positive semi-definite",
        ),
        (
            lambda d: d["tags"][0].update(covariance=[[1e300, 0, 0], [0, 1, 0], [0, 0, 1]]),
            r"line 3: tags/0/covariance: covariance entry 1e\+300 is out of range",
        ),
        (lambda d: d.update(t=0.05), r"line 3: time goes backwards \(0\.050 after 0\.100\)"),
        (lambda d: d.pop("t"), r"line 3: missing field 't'"),
    ],
)
def test_rejects(tmp_path: Path, mutate, message: str) -> None:
    documents = _lines()
    mutate(documents[2])
    path = tmp_path / "obs.jsonl"
    _write(path, documents)
    with pytest.raises(FormatError, match=message):
        read_observations(path)


def test_overflowing_exponent_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "obs.jsonl"
    _write(path, _lines())
    text = path.read_text().splitlines()
    text[1] = text[1].replace('"t": 0.1', '"t": 1e999', 1)
    path.write_text("\n".join(text) + "\n")
    with pytest.raises(FormatError, match=r"obs\.jsonl line 2: t: Infinity is not allowed"):
        read_observations(path)


def test_truncated_last_line(tmp_path: Path) -> None:
    path = tmp_path / "obs.jsonl"
    write_observations(path, [make_frame(0.1 * i) for i in range(3)])
    text = path.read_text()
    path.write_text(text[:-20])
    with pytest.raises(FormatError, match=r"obs\.jsonl line 3: not valid JSON"):
        read_observations(path)


def test_line_not_an_object(tmp_path: Path) -> None:
    path = tmp_path / "obs.jsonl"
    path.write_text("[1, 2]\n")
    with pytest.raises(FormatError, match=r"obs\.jsonl line 1: expected an object, got an array"):
        read_observations(path)


def test_writer_refuses_unordered_or_broken_frames(tmp_path: Path) -> None:
    path = tmp_path / "obs.jsonl"
    with pytest.raises(FormatError, match=r"obs\.jsonl: frame 1: time goes backwards"):
        write_observations(path, [make_frame(1.0), make_frame(0.5)])
    broken = make_frame(0.0)
    slot = broken.slots[0]
    bad = FrameObservations(
        t=0.0,
        slots=(SlotObservation(slot.vCorners[:3], slot.kind, None, 0.0, 1.0, 0.1),),
    )
    with pytest.raises(
        FormatError, match=r"obs\.jsonl: frame 0: slots/0/corners: expected 4 points"
    ):
        write_observations(path, [bad])
    assert not path.exists()


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ('{"t": 0.1, "a": [1.5e-07, 2E+30]}', False),
        ('{"t": NaN}', True),
        ('{"t": -Infinity}', True),
        ('{"t": 1e999}', True),
        ('{"t": 1E+308}', True),
        ('{"label": "NaN"}', True),  # a false alarm costs only the walk
    ],
)
def test_which_lines_need_the_non_finite_walk(text: str, expected: bool) -> None:
    from semslam.io._json import may_hold_non_finite

    assert may_hold_non_finite(text) is expected


def test_the_shortest_side_counts_the_side_that_closes_the_slot():
    from semslam.io.observations import shortest_side

    assert shortest_side(np.array([[0.0, 0.0], [2.5, 0.0], [2.5, 5.0], [0.0, 5.0]])) == 2.5
    # only the side from the last corner back to the first is short
    assert shortest_side(np.array([[0.0, 0.0], [2.5, 0.0], [2.5, 5.0], [0.0, 0.03]])) \
        == pytest.approx(0.03)
