"""Greedy tag placement on a straight route that leaves its only landmarks behind."""

import math

import numpy as np

from semslam.analysis.accuracy import GRADES, MapGeometry, route_information
from semslam.analysis.tag_placement import (
    candidate_tags,
    even_placement,
    greedy_placement,
    resample_route,
)
from semslam.types import SemanticMap, Slot, SlotKind


def _route():
    t = np.arange(0.0, 40.0, 0.1)
    poses = np.column_stack([2.0 * t, np.zeros_like(t), np.zeros_like(t)])
    return resample_route(poses, t, 1.0)


def _map():
    c = np.array([[1.0, 1.5], [3.5, 1.5], [3.5, 4.0], [1.0, 4.0]])
    return SemanticMap(slots=(Slot(1, None, 0.0, c, np.zeros((4, 2, 2)), SlotKind.PERPENDICULAR),))


def test_candidates_stand_beside_the_route_facing_the_oncoming_car():
    poses, _ = _route()
    cands = candidate_tags(poses, spacing=10.0, offset=3.0)
    assert len(cands) == 2 * 7  # 10, 20, ..., 70 m on both sides of a 79 m route
    np.testing.assert_allclose(np.abs(cands[:, 1]), 3.0)
    np.testing.assert_allclose(np.abs(cands[:, 2]), math.pi)


def test_greedy_tags_lower_the_worst_sigma_and_beat_even_spread():
    poses, t = _route()
    infos, _ = route_information(MapGeometry(_map()), poses)
    cands = candidate_tags(poses, spacing=5.0, offset=3.0)
    steps = greedy_placement(infos, poses, t, cands, 3, GRADES["automotive"])
    worst = [s.worst_m for s in steps]
    assert len(steps) == 4 and steps[0].tag is None
    assert all(b < a for a, b in zip(worst, worst[1:], strict=False))
    assert worst[-1] < 0.6 * worst[0]
    assert even_placement(infos, poses, t, cands, 3, GRADES["automotive"]).worst_m >= worst[-1]
