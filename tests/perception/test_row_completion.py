"""The next junction of a row of T junctions, on hand-drawn top views."""

import math

import numpy as np
import pytest

from semslam.perception.marking_points import MarkingPoint
from semslam.perception.row_completion import ROW_SHARE_RIGHT, row_completions
from semslam.perception.slots import SlotDetector
from semslam.types import JunctionShape

UP = -math.pi / 2  # separators run up from the entrance line (v down)
T, L = JunctionShape.T, JunctionShape.L


def _view(black_box=None) -> np.ndarray:
    img = np.full((600, 600, 3), 90, np.uint8)
    if black_box is not None:
        (u0, v0), (u1, v1) = black_box
        img[v0:v1, u0:u1] = 0
    return img


def _points(*spec) -> list[MarkingPoint]:
    return [MarkingPoint(np.array(uv, float), UP, shape, c) for uv, shape, c in spec]


def test_the_next_junction_of_a_row_is_added_on_both_sides():
    pts = _points(((250.0, 400.0), T, 0.9), ((400.0, 400.0), T, 0.8))
    added = row_completions(_view(), pts, [(0, 1)])
    assert sorted(p.uv[0] for p in added) == pytest.approx([100.0, 550.0])
    for p in added:
        assert p.uv[1] == pytest.approx(400.0)
        assert p.shape is T
        assert p.direction == pytest.approx(UP)
        assert p.confidence == pytest.approx(ROW_SHARE_RIGHT * 0.8)  # the lower of the pair's
        assert p.from_row


def test_an_l_junction_ends_its_row():
    pts = _points(((250.0, 400.0), T, 0.9), ((400.0, 400.0), L, 0.9))
    assert row_completions(_view(), pts, [(0, 1)]) == []


def test_no_point_where_the_view_is_black_or_at_its_border():
    # beyond 320 lies the ego box; beyond 170 the place is 20 px from the border
    pts = _points(((170.0, 400.0), T, 0.9), ((320.0, 400.0), T, 0.9))
    assert row_completions(_view(((460, 300), (490, 500))), pts, [(0, 1)]) == []
    assert len(row_completions(_view(), pts, [(0, 1)])) == 1


def test_no_point_where_one_is_detected_already():
    pts = _points(((250.0, 400.0), T, 0.9), ((400.0, 400.0), T, 0.9), ((540.0, 410.0), T, 0.9))
    added = row_completions(_view(), pts, [(0, 1)])
    assert [p.uv[0] for p in added] == pytest.approx([100.0])


def test_the_added_point_makes_its_slot(monkeypatch):
    # the detector's points replaced by two T junctions 2.5 m apart (150 px)
    detector = SlotDetector(verify=False, check_entrance=False)
    pts = _points(((250.0, 400.0), T, 0.9), ((400.0, 400.0), T, 0.9))
    monkeypatch.setattr(detector.points, "detect", lambda img: list(pts))
    points, slots = detector.detect(_view())
    assert len(points) == 4 and len(slots) == 3
    detector.complete_rows = False
    points, slots = detector.detect(_view())
    assert len(points) == 2 and len(slots) == 1
