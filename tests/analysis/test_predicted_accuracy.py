"""Hofmann's predicted accuracy: information of one frame, filtering along a route."""

import math

import numpy as np
import pytest

from semslam.analysis.accuracy import (
    GRADES,
    MapGeometry,
    SensorModel,
    _yaw_row,
    frame_information,
    position_sigma,
    predicted_along_route,
    single_frame_covariance,
    worst_stretches,
)
from semslam.localization.measurements import PointMeasurement
from semslam.types import Marking, SemanticMap, Slot, SlotKind, Tag, TagFamily


def _slot(x: float, y: float, sid: int = 1) -> Slot:
    corners = np.array([[x, y], [x + 2.5, y], [x + 2.5, y + 3.0], [x, y + 3.0]])
    return Slot(sid, None, 0.0, corners, np.zeros((4, 2, 2)), SlotKind.PERPENDICULAR)


def test_corner_information_is_the_point_jacobians_weighted():
    m = SemanticMap(slots=(_slot(1.0, 1.5),))
    pose = np.array([0.0, 0.0, 0.3])
    info, counts = frame_information(MapGeometry(m), pose, SensorModel(corner_sigma=0.1))
    seen = m.slots[0].corners  # all inside the top view, none in the ego box
    # numerical Jacobian of the vehicle-frame prediction of the corners seen
    meas = PointMeasurement(np.zeros(2 * len(seen)), np.eye(2), np.array(seen))
    H = np.zeros((2 * len(seen), 3))
    for k in range(3):
        d = np.zeros(3)
        d[k] = 1e-6
        H[:, k] = (meas.predict(pose + d) - meas.predict(pose - d)).ravel() / 2e-6
    assert counts["corners"] == len(seen) == 4
    np.testing.assert_allclose(info, H.T @ H / 0.01, rtol=1e-5, atol=1e-6)


def test_line_yaw_row_matches_a_numerical_derivative():
    n, vE = np.array([0.6, 0.8]), np.array([2.0, -1.0])

    def f(yaw):
        c, s = math.cos(yaw), math.sin(yaw)
        return float(n @ (np.array([[c, -s], [s, c]]) @ vE))

    yaw = 0.7
    c, s = math.cos(yaw), math.sin(yaw)
    numeric = (f(yaw + 1e-6) - f(yaw - 1e-6)) / 2e-6
    assert abs(_yaw_row(n, np.array([[c, -s], [s, c]]), vE) - numeric) < 1e-8


def test_one_line_cannot_fix_a_pose_but_slots_and_a_tag_can():
    line = SemanticMap(markings=(Marking(np.array([-4.0, 2.0]), np.array([4.0, 2.0]), 0.12),))
    info, counts = frame_information(MapGeometry(line), np.zeros(3))
    assert counts["lines"] == 1
    assert position_sigma(single_frame_covariance(info)) == math.inf
    tag = Tag(TagFamily.TAG36H11, 1, 0.3, np.array([8.0, 0.0, math.pi]), 1.0, np.zeros((3, 3)))
    both = SemanticMap(slots=(_slot(1.0, 1.5),), tags=(tag,))
    info, counts = frame_information(MapGeometry(both), np.zeros(3))
    assert counts == {"corners": 4, "slots": 1, "tags": 1, "lines": 0}
    sigma = position_sigma(single_frame_covariance(info))
    slot_only, _ = frame_information(MapGeometry(SemanticMap(slots=both.slots)), np.zeros(3))
    assert 0 < sigma < position_sigma(single_frame_covariance(slot_only)) < 0.1
    # a tag facing away is not seen
    away = Tag(TagFamily.TAG36H11, 1, 0.3, np.array([8.0, 0.0, 0.0]), 1.0, np.zeros((3, 3)))
    _, counts = frame_information(MapGeometry(SemanticMap(tags=(away,))), np.zeros(3))
    assert counts["tags"] == 0


def test_filtered_error_grows_without_landmarks_faster_for_worse_odometry():
    m = SemanticMap(slots=(_slot(1.0, 1.5),))
    t = np.arange(0.0, 30.0, 0.5)
    poses = np.column_stack([t * 2.0, np.zeros_like(t), np.zeros_like(t)])  # 2 m/s along x
    g = MapGeometry(m)
    auto = predicted_along_route(g, poses, t, GRADES["automotive"])
    precise = predicted_along_route(g, poses, t, GRADES["precise"])
    assert auto["corners"][0] == 4 and auto["corners"][-1] == 0
    assert auto["filtered_sigma"][0] < 0.1
    assert np.all(np.diff(auto["filtered_sigma"][10:]) > 0)  # dead reckoning only

    def growth(r):
        return r["filtered_sigma"][-1] ** 2 - r["filtered_sigma"][10] ** 2

    assert growth(auto) > 2 * growth(precise) > 0
    assert np.isinf(auto["single_sigma"][-1])


def test_worst_stretches_are_the_longest_runs_above_the_threshold():
    d = np.arange(10.0)
    sigma = np.array([0.1, 0.3, 0.4, 0.1, 0.5, 0.1, 0.3, 0.3, 0.3, 0.1])
    runs = worst_stretches(d, sigma, 0.2)
    assert [(r["start_m"], r["end_m"]) for r in runs] == [(6, 8), (1, 2), (4, 4)]
    assert runs[1]["worst_sigma_m"] == 0.4


def test_tag_information_uses_the_tag_measurements_jacobian():
    from semslam.analysis.accuracy import tag_information
    from semslam.localization.measurements import TagMeasurement

    pose = np.array([1.0, -2.0, 0.4])
    mTt = np.array([9.0, 2.0, 0.4 + math.pi - 0.2])
    info, seen = tag_information(pose[None], mTt[None])
    assert seen.tolist() == [1]
    meas = TagMeasurement(np.zeros(3), np.eye(3), mTt)
    H = np.zeros((3, 3))
    for k in range(3):
        d = np.zeros(3)
        d[k] = 1e-6
        H[:, k] = (meas.predict(pose + d) - meas.predict(pose - d)).ravel() / 2e-6
    # info = H^T C^-1 H with the numerical H: recover C, the measurement covariance
    C = np.linalg.inv(np.linalg.inv(H).T @ info[0] @ np.linalg.inv(H))
    np.testing.assert_allclose(C, C.T, atol=1e-9)
    assert np.all(np.linalg.eigvalsh(C) > 0)
    r = math.hypot(
        *(
            np.array([[math.cos(0.4), math.sin(0.4)], [-math.sin(0.4), math.cos(0.4)]])
            @ (mTt[:2] - pose[:2])
            - [1.2, 0.0]
        )
    )
    sr = 0.02 + 0.01 * r
    # range variance along the view ray, bearing variance across it, tag yaw noise
    assert abs(C[:2, :2].trace() - sr**2 - (math.radians(0.3) * r) ** 2) < 1e-6
    assert abs(C[2, 2] - math.radians(3.0) ** 2) < 1e-6


def test_the_vectorised_line_clip_and_reach_agree_with_the_scalar_clip():
    """Painted lines are clipped to the view all at once (a Python loop over thousands of
    lines took minutes per grid); the same ends and the same lines as clip_segment."""
    from semslam.analysis.accuracy import _lines_within
    from semslam.geometry import clip_segment, clip_segments

    rng = np.random.default_rng(4)
    a, b = rng.uniform(-12, 12, (500, 2)), rng.uniform(-12, 12, (500, 2))
    b[:50, 0] = a[:50, 0]  # vertical ones
    b[50:60] = a[50:60]  # points
    ends, keep = clip_segments(a, b, -5.0, 5.0)
    for k in range(len(a)):
        want = clip_segment(a[k], b[k], -5.0, 5.0)
        assert keep[k] == (want is not None), k
        if want is not None:
            np.testing.assert_allclose(ends[k], np.array(want), atol=1e-12)
    near = np.stack([a, b], axis=1)[_lines_within(np.stack([a, b], axis=1), np.zeros(2),
                                                  5.0 * np.sqrt(2.0))]
    assert len(near) < len(a)  # some are left out before clipping ...
    visible = {tuple(np.round(np.concatenate([a[k], b[k]]), 9)) for k in np.flatnonzero(keep)}
    assert visible <= {tuple(np.round(s.ravel(), 9)) for s in near}  # ... none in view


def test_the_landmarks_around_a_place_give_every_frame_there_what_the_whole_map_gives():
    """A grid cell or route pose looks only at the landmarks near it (KD-trees), so a big
    garage costs no more per pose than a small one; every heading, every rule, to the bit."""
    from dataclasses import replace

    from semslam.analysis.accuracy import IDEAL, LocalizerModel, _frame

    rng = np.random.default_rng(7)
    slots = tuple(_slot(x, y, k) for k, (x, y) in enumerate(rng.uniform(-60, 60, (300, 2))))
    tags = tuple(
        Tag(TagFamily.TAG36H11, k, 0.3, np.array([*p, rng.uniform(-math.pi, math.pi)]), 1.0,
            np.eye(3) * 1e-4)
        for k, p in enumerate(rng.uniform(-70, 70, (60, 2)))
    )
    starts = rng.uniform(-70, 70, (400, 2))
    ends = starts + rng.uniform(-15, 15, (400, 2))
    ends[:20] = starts[:20]  # points
    sigmas = [None if k % 3 == 0 else s for k, s in enumerate(rng.uniform(0.0, 0.2, 400))]
    lines = tuple(Marking(a, b, 0.12, s) for a, b, s in zip(starts, ends, sigmas, strict=True))
    geometry = MapGeometry(SemanticMap(slots=slots, tags=tags, markings=lines))
    seen = {"corners": 0, "tags": 0, "lines": 0}
    localizer = LocalizerModel(fallback_below=2, map_floor_scale=1.0, marking_map_sigma=0.05,
                               line_own_sigma=True)
    models = (IDEAL, replace(IDEAL, tag_range_limit=8.0), localizer)
    for rule in ("corners", "entrance"):
        sensors = SensorModel(slot_rule=rule)
        for model in models:
            for point in rng.uniform(-70, 70, (40, 2)):
                near = geometry.around(point, sensors, model)
                assert len(near.corners) < len(geometry.corners)
                for yaw in (0.0, 1.0, 2.5, -2.0):
                    pose = np.array([*point, yaw])
                    whole, local = (_frame(g, pose, sensors, model) for g in (geometry, near))
                    for kind in ("slots", "tags", "lines", "floor"):
                        assert np.array_equal(getattr(whole, kind), getattr(local, kind))
                    assert whole.counts == local.counts
                    assert whole.lines_weight == local.lines_weight
                    for k in seen:
                        seen[k] += whole.counts[k]
    assert all(n > 0 for n in seen.values())
    nowhere = np.array([np.nan, 0.0, 0.0])
    frame = _frame(geometry.around(nowhere, SensorModel(), IDEAL), nowhere, SensorModel(), IDEAL)
    assert frame.counts == _frame(geometry, nowhere, SensorModel(), IDEAL).counts
    assert frame.counts == {"corners": 0, "slots": 0, "tags": 0, "lines": 0}
    empty = MapGeometry(SemanticMap())
    frame = _frame(empty.around(np.zeros(2), SensorModel(), IDEAL), np.zeros(3), SensorModel(),
                   IDEAL)
    assert frame.counts == {"corners": 0, "slots": 0, "tags": 0, "lines": 0}


def test_a_map_line_counts_with_its_own_sigma_where_larger_than_the_configured_one():
    """As the localizer: a line's own sigma replaces ``marking_map_sigma`` where larger, in
    the line's noise and in the position floor of frames with lines alone."""
    from dataclasses import replace

    from semslam.analysis.accuracy import LocalizerModel, _frame

    model = LocalizerModel(marking_sigma=math.hypot(0.03, 0.05), marking_map_sigma=0.05,
                           line_own_sigma=True, map_floor_scale=1.0, use_slots=False,
                           use_tags=False)
    sensors = SensorModel(marking_detection_rate=1.0)
    pose = np.zeros(3)
    frames = {}
    for own in (None, 0.01, 0.3):
        line = Marking(np.array([-3.0, 2.0]), np.array([3.0, 2.0]), 0.12, own)
        frames[own] = _frame(MapGeometry(SemanticMap(markings=(line,))), pose, sensors, model)
    assert frames[None].counts["lines"] == 1
    np.testing.assert_allclose(frames[0.01].lines, frames[None].lines)
    np.testing.assert_allclose(frames[0.01].floor, frames[None].floor)
    assert frames[None].floor[0, 0] == pytest.approx(0.05**2)
    ratio = (0.03**2 + 0.05**2) / (0.03**2 + 0.3**2)
    np.testing.assert_allclose(frames[0.3].lines, ratio * frames[None].lines, atol=1e-12)
    assert frames[0.3].floor[0, 0] == pytest.approx(0.3**2)
    ideal = _frame(MapGeometry(SemanticMap(markings=(line,))), pose, sensors,
                   replace(model, line_own_sigma=False))  # every line as marking_sigma says
    np.testing.assert_allclose(ideal.lines, frames[None].lines)


def test_a_map_line_counts_with_its_own_variance_where_each_end_point_falls_on_it():
    """A line surer at one end than the other (its ``across_covariance``): each visible end
    point weighs with the line's variance there, as the localizer's do, and the floor of a
    frame with lines alone is their mean."""
    from semslam.analysis.accuracy import LocalizerModel, _frame

    model = LocalizerModel(marking_sigma=math.hypot(0.03, 0.05), marking_map_sigma=0.05,
                           line_own_sigma=True, map_floor_scale=1.0, use_slots=False,
                           use_tags=False)
    sensors = SensorModel(marking_detection_rate=1.0)
    ends = np.diag([0.2**2, 0.4**2])
    line = Marking(np.array([-4.0, 2.0]), np.array([4.0, 2.0]), 0.12, 0.3, ends)
    frame = _frame(MapGeometry(SemanticMap(markings=(line,))), np.zeros(3), sensors, model)
    h_a, h_b = np.array([0.0, 1.0, -4.0]), np.array([0.0, 1.0, 4.0])  # d(across)/d(x, y, yaw)
    w_a, w_b = (1.0 / (0.03**2 + v) for v in (0.2**2, 0.4**2))
    np.testing.assert_allclose(frame.lines, w_a * np.outer(h_a, h_a) + w_b * np.outer(h_b, h_b),
                               rtol=1e-9)
    assert frame.floor[0, 0] == pytest.approx(0.5 * (0.2**2 + 0.4**2))
