"""The localizer's slot association: the gate's distance, the local map, labels."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from semslam.config import LocalizationConfig
from semslam.geometry import rotation
from semslam.localization.association import LocalMap
from semslam.localization.measurements import PointMeasurement, point_jacobian
from semslam.types import (
    FrameObservations,
    Marking,
    MarkingObservation,
    SemanticMap,
    Slot,
    SlotObservation,
)

CFG = LocalizationConfig()
SIGMA = 0.05  # corner sigma the observations declare (above the configured floor)
RECTANGLE = np.array([[0.0, 0.0], [2.5, 0.0], [2.5, 5.0], [0.0, 5.0]])


def _slot(i: int, origin, label=None, covariance=None) -> Slot:
    cov = np.tile(np.diag([0.02**2, 0.005**2]), (4, 1, 1)) if covariance is None else covariance
    return Slot(i, label, 0.99 if label else 0.0, RECTANGLE + origin, cov, "perpendicular", 5)


def _seen(slot: Slot, pose, offset=None, label=None, confidence=0.0) -> SlotObservation:
    """``slot`` seen from ``pose``, its corners moved by ``offset`` (8,) in the vehicle frame."""
    vP = (slot.corners - pose[:2]) @ rotation(pose[2])
    if offset is not None:
        vP = vP + offset.reshape(4, 2)
    return SlotObservation(vP, "perpendicular", label, confidence, 0.9, SIGMA)


def _reference_d2(slot: Slot, pose, P, observed: SlotObservation) -> float:
    """The gate's distance written out in the vehicle frame, as the EKF sees it."""
    H = point_jacobian(pose, slot.corners)
    Rv = rotation(pose[2]).T
    R = np.zeros((8, 8))
    for k in range(4):
        R[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = (
            CFG.map_covariance_scale * Rv @ slot.corner_covariances[k] @ Rv.T
            + SIGMA**2 * np.eye(2)
        )
    r = observed.vCorners.ravel() - ((slot.corners - pose[:2]) @ rotation(pose[2])).ravel()
    return float(r @ np.linalg.solve(H @ P @ H.T + R, r))


def test_the_gate_distance_is_the_vehicle_frame_mahalanobis_distance():
    # an anisotropic map covariance and a turned car: a frame mix-up would move the border
    slot = _slot(0, (6.0, 2.0))
    local = LocalMap(SemanticMap(slots=(slot,)), CFG)
    pose = np.array([1.0, -0.5, 0.7])
    P = np.array([[0.04, 0.01, 0.002], [0.01, 0.02, -0.001], [0.002, -0.001, 0.0004]])
    gate = chi2.ppf(CFG.slot_gate, 8)
    direction = np.random.default_rng(3).normal(size=8)
    unit = _reference_d2(slot, pose, P, _seen(slot, pose, direction))  # d2 grows as scale^2
    for factor, accepted in ((0.95, 1), (1.05, 0)):
        seen = _seen(slot, pose, direction * math.sqrt(factor * gate / unit))
        assert math.isclose(_reference_d2(slot, pose, P, seen), factor * gate, rel_tol=1e-9)
        out = local.associate(FrameObservations(0.0, slots=(seen,)), pose, P)
        assert out.count == accepted
        assert out.rejected["slot"] == 1 - accepted


def test_the_local_map_follows_the_car():
    far = 60.0  # metres between the two slots: far beyond one local map
    slots = (_slot(0, (3.0, 3.0)), _slot(1, (far + 3.0, 3.0)))
    local = LocalMap(SemanticMap(slots=slots), CFG)
    P = np.diag([0.01, 0.01, 1e-4])
    for slot in (*slots, slots[0]):  # there, over there, and back
        pose = np.array([slot.corners[0, 0] - 3.0, 0.0, 0.0])
        out = local.associate(FrameObservations(0.0, slots=(_seen(slot, pose),)), pose, P)
        assert out.slots == [slot.id]


def test_a_confident_label_picks_its_slot_and_a_misread_falls_back_to_geometry():
    # two slots side by side; the car's pose is off by half a slot width, so by geometry
    # alone the observation of B2 sits between the two and the ratio test refuses it
    slots = (_slot(0, (0.0, 3.0), "B1"), _slot(1, (2.5, 3.0), "B2"))
    local = LocalMap(SemanticMap(slots=slots), CFG)
    truth = np.array([2.5, 0.0, 0.0])
    believed = truth + [-1.25, 0.0, 0.0]
    P = np.diag([1.0, 1.0, 1e-4])  # an unsure filter
    frame = [_seen(slots[1], truth, label=label, confidence=conf)
             for label, conf in (("B2", 0.99), (None, 0.0), ("C9", 0.99))]
    by_label, unread, misread = (
        local.associate(FrameObservations(0.0, slots=(o,)), believed, P) for o in frame
    )
    assert by_label.slots == [1]
    assert unread.slots == [] and unread.rejected["slot"] == 1
    assert misread.slots == [] and misread.rejected["slot"] == 1


def test_the_slot_measurement_carries_its_own_linearisation_at_the_pose():
    slots = (_slot(0, (4.0, 2.0)), _slot(1, (6.5, 2.0)), _slot(2, (-3.0, -8.0)))
    local = LocalMap(SemanticMap(slots=slots), CFG)
    pose, P = np.array([0.5, -1.0, 0.6]), np.diag([0.01, 0.02, 1e-4])
    rng = np.random.default_rng(5)
    seen = tuple(_seen(s, pose, rng.normal(scale=0.03, size=8)) for s in slots)
    m = local.associate(FrameObservations(0.0, slots=seen), pose, P).measurements[0]
    fresh = PointMeasurement(m.z, m.R, m.mP, turn=m.turn)  # no cached linearisation
    for got, expected in zip(m.linearise(pose), fresh.linearise(pose), strict=True):
        np.testing.assert_allclose(got, expected, atol=1e-12)
    np.testing.assert_allclose(m.residual(m.predict(pose)[0]), m.linearise(pose)[0], atol=1e-12)


def test_a_map_tags_covariance_enters_the_measurement_noise_through_the_measurement():
    """R of a tag sighting = its own covariance + the map tag's, carried by the first-order
    derivative of the predicted sighting with respect to the map pose (cross terms too)."""
    from semslam.localization.measurements import TagMeasurement
    from semslam.types import Tag, TagObservation

    mTt = np.array([4.0, -2.0, 2.9])
    C_map = np.array([[4e-4, 0.0, 1.5e-4], [0.0, 1e-4, 0.0], [1.5e-4, 0.0, 1e-4]])
    pose = np.array([1.0, -1.0, 1.3])
    seen = TagMeasurement(np.zeros(3), np.eye(3), mTt).predict(pose)[0]
    obs = TagObservation("tag36h11", 3, 0.2, seen, 0.5, np.diag([1e-4, 1e-4, 1e-5]))
    local = LocalMap(SemanticMap(tags=(Tag("tag36h11", 3, 0.2, mTt, 0.5, C_map),)), CFG)
    out = local.associate(FrameObservations(0.0, tags=(obs,)), pose, np.eye(3) * 1e-4)
    J = np.zeros((3, 3))
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1e-6
        J[:, k] = (TagMeasurement(np.zeros(3), np.eye(3), mTt + e).predict(pose)[0]
                   - TagMeasurement(np.zeros(3), np.eye(3), mTt - e).predict(pose)[0]) / 2e-6
    expected = obs.covariance + CFG.map_covariance_scale * J @ C_map @ J.T
    np.testing.assert_allclose(out.measurements[0].R, expected, atol=1e-10)


def test_rejected_lines_are_unmapped_paint_only_where_the_map_holds_no_line_in_view():
    line = Marking(np.array([0.0, 0.0]), np.array([10.0, 0.0]), 0.15)
    local = LocalMap(SemanticMap(markings=(line,)), CFG)
    P = np.diag([0.01, 0.01, 1e-4])

    def seen(y: float) -> MarkingObservation:  # 4 m of paint along the car, y m to its left
        return MarkingObservation(np.array([-2.0, y]), np.array([2.0, y]), 0.15, 0.9, 0.02)

    beside = np.array([5.0, -2.0, 0.0])  # the map line 2 m to the left
    out = local.associate(FrameObservations(0.0, markings=(seen(2.0),)), beside, P)
    assert out.count == 1 and out.unmapped == 0  # the map line itself
    out = local.associate(FrameObservations(0.0, markings=(seen(2.8), seen(-3.0))), beside, P)
    assert out.rejected["marking"] == 2 and out.unmapped == 0  # the map's line in view: misfits
    away = np.array([5.0, -20.0, 0.0])  # the map line 20 m off, beyond what the car sees
    out = local.associate(FrameObservations(0.0, markings=(seen(2.8), seen(-3.0))), away, P)
    assert out.rejected["marking"] == 2 and out.unmapped == 2  # paint the map does not hold


def test_the_maps_heading_error_near_a_point_is_the_mean_over_the_slots_within_reach():
    # slot centres at (1.25, 2.5) and (11.25, 2.5), orientation variances 1e-6 and 4e-6;
    # (6.25, 2.5) lies 5 m from both
    slots = tuple(
        Slot(i, None, 0.0, RECTANGLE + (10.0 * i, 0.0), np.zeros((4, 2, 2)), "perpendicular",
             5, heading_variance=v)
        for i, v in enumerate((1e-6, 4e-6))
    )
    local = LocalMap(SemanticMap(slots=slots), CFG)
    assert local.heading_variance_near(np.array([1.25, 2.5, 0.3]), 5.0) == 1e-6
    assert local.heading_variance_near(np.array([6.25, 2.5]), 5.0) == pytest.approx(2.5e-6)
    assert local.heading_variance_near(np.array([6.25, 9.0]), 5.0) is None
    assert local.heading_variance_near(np.array([1.25, 2.5]), 0.0) is None
    assert LocalMap(SemanticMap(), CFG).heading_variance_near(np.zeros(2), 5.0) is None


def test_a_separator_the_map_holds_only_through_its_slots_is_associated_with_their_side():
    slots = tuple(_slot(i, (2.5 * i, 0.0)) for i in range(3))  # separators at x = 0 .. 7.5
    pose = np.array([3.75, -3.0, math.pi / 2])  # in the aisle, facing the row (+y)
    P = np.diag([0.01, 0.01, 1e-4])
    # the x = 2.5 separator from 3.5 to 7.5 m ahead, 1.25 m to the car's left
    frame = FrameObservations(0.0, markings=(
        MarkingObservation(np.array([3.5, 1.25]), np.array([7.5, 1.25]), 0.1, 0.9, 0.02),))
    cfg = CFG.model_copy(update={"use_slots": False, "use_tags": False})
    with_sides = LocalMap(SemanticMap(slots=slots), cfg).associate(frame, pose, P)
    assert with_sides.count == 1 and with_sides.kinds == ["marking"]
    off = cfg.model_copy(update={"slot_sides_as_markings": False})
    assert LocalMap(SemanticMap(slots=slots), off).associate(frame, pose, P).count == 0


def test_a_painted_line_in_two_pieces_end_to_end_is_no_rival_to_itself():
    # one painted line as two pieces meeting at x = 5 (3 cm apart across: two separators
    # back to back), and a parallel line 0.3 m away
    pieces = (Marking(np.array([0.0, 2.0]), np.array([5.0, 2.0]), 0.12),
              Marking(np.array([5.0, 2.03]), np.array([10.0, 2.03]), 0.12))
    P = np.diag([0.01, 0.01, 1e-4])
    car = np.array([3.0, 0.0, 0.0])
    seen = FrameObservations(0.0, markings=(  # 3 m of it ending at the joint, 2 m to the left
        MarkingObservation(np.array([-1.0, 2.0]), np.array([2.0, 2.0]), 0.12, 0.9, 0.02),))
    out = LocalMap(SemanticMap(markings=pieces), CFG).associate(seen, car, P)
    assert out.count == 1 and out.rejected["marking"] == 0
    # a truly different line as near is still a rival: the ratio test refuses the choice
    rivals = (pieces[0], Marking(np.array([0.0, 2.3]), np.array([10.0, 2.3]), 0.12))
    out = LocalMap(SemanticMap(markings=rivals), CFG).associate(seen, car, np.diag(
        [0.09, 0.09, 1e-4]))
    assert out.count == 0 and out.rejected["marking"] == 1


def test_a_map_line_is_as_uncertain_as_the_map_says_and_at_least_as_configured():
    """A line whose own sigma exceeds the configured ``marking_map_sigma`` enters the noise
    (and the frame's floor) with its own; one surer than that, or with none, with the
    configured one."""
    P = np.diag([0.01, 0.01, 1e-4])
    car = np.array([5.0, 0.0, 0.0])
    seen = FrameObservations(0.0, markings=(  # 4 m of the line 2 m to the car's left
        MarkingObservation(np.array([-2.0, 2.0]), np.array([2.0, 2.0]), 0.12, 0.9, 0.02),))
    for own, expected in ((0.4, 0.4), (0.01, CFG.marking_map_sigma), (None, CFG.marking_map_sigma)):
        line = Marking(np.array([0.0, 2.0]), np.array([10.0, 2.0]), 0.12, own)
        out = LocalMap(SemanticMap(markings=(line,)), CFG).associate(seen, car, P)
        assert out.kinds == ["marking"]
        np.testing.assert_allclose(np.diag(out.measurements[0].R), 0.02**2 + expected**2)
        assert out.marking_map_var == pytest.approx(expected**2)


def test_a_map_line_is_as_uncertain_where_it_is_seen_as_the_map_says_there():
    """A long line the map holds surely at ``a`` (2 cm) and loosely at ``b`` (0.6 m): end
    points seen near ``a`` enter with the configured floor, near ``b`` with about 0.6 m,
    in the middle with the variance its end covariance gives there; its RMS ``sigma``
    alone (the same everywhere) would give every end point the same."""
    P = np.diag([0.01, 0.01, 1e-4])
    ends = np.array([[0.02**2, 0.0], [0.0, 0.6**2]])  # offsets at a and b independent
    line = Marking(np.array([0.0, 2.0]), np.array([100.0, 2.0]), 0.12, 0.35, ends)
    local = LocalMap(SemanticMap(markings=(line,)), CFG)
    seen = FrameObservations(0.0, markings=(  # 4 m of the line 2 m to the car's left
        MarkingObservation(np.array([-2.0, 2.0]), np.array([2.0, 2.0]), 0.12, 0.9, 0.02),))
    variances = {}
    for x in (3.0, 50.0, 97.0):
        out = local.associate(seen, np.array([x, 0.0, 0.0]), P)
        assert out.kinds == ["marking"]
        variances[x] = np.diag(out.measurements[0].R) - 0.02**2
        lam = (np.array([x - 2.0, x + 2.0])) / 100.0
        own = (1 - lam) ** 2 * ends[0, 0] + lam**2 * ends[1, 1]
        np.testing.assert_allclose(variances[x], np.maximum(own, CFG.marking_map_sigma**2))
        assert out.marking_map_var == pytest.approx(variances[x].mean())
    assert variances[3.0] == pytest.approx(CFG.marking_map_sigma**2)
    assert variances[97.0] == pytest.approx(0.6**2, rel=0.1)
    assert variances[50.0].mean() < 0.35**2 < variances[97.0].mean()
