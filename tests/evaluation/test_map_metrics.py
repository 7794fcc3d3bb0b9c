"""Map evaluation: SE(2) fit, slot/tag/marking matching and every metric on edited true maps."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from semslam.evaluation import apply_se2, evaluate_map, fit_se2, transform_map
from semslam.evaluation.map_metrics import point_segment_distances
from semslam.geometry import inverse, wrap_angle
from semslam.simulation.world import make_world
from semslam.types import Marking, SemanticMap


@pytest.fixture(scope="module")
def truth() -> SemanticMap:
    return make_world("small", 0).to_map()


def _with_slots(m: SemanticMap, slots) -> SemanticMap:
    return replace(m, slots=tuple(slots))


def _row_neighbours(m: SemanticMap) -> tuple[int, int]:
    """Indices of two slots side by side in one row (sharing an entrance corner)."""
    for i, a in enumerate(m.slots):
        for j, b in enumerate(m.slots):
            if i != j and np.allclose(a.corners[1], b.corners[0]):
                return i, j
    raise AssertionError("no neighbours")


# --------------------------------------------------------------------------- fit_se2


def test_fit_se2_recovers_a_known_transform_exactly():
    rng = np.random.default_rng(1)
    src = rng.uniform(-20, 20, (10, 2))
    T = np.array([3.0, -7.5, 2.5])
    est = fit_se2(src, apply_se2(T, src))
    np.testing.assert_allclose(est, T, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    x=st.floats(-100, 100),
    y=st.floats(-100, 100),
    yaw=st.floats(-math.pi, math.pi),
    n=st.integers(2, 30),
    seed=st.integers(0, 2**32 - 1),
)
def test_fit_se2_property_recovers_any_transform(x, y, yaw, n, seed):
    src = np.random.default_rng(seed).uniform(-50, 50, (n, 2))
    T = np.array([x, y, yaw])
    est = fit_se2(src, apply_se2(T, src))
    np.testing.assert_allclose(est[:2], T[:2], atol=1e-7)
    assert abs(wrap_angle(est[2] - yaw)) < 1e-9


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 20))
def test_fit_se2_property_swapping_the_sets_inverts_the_transform(seed, n):
    rng = np.random.default_rng(seed)
    src = rng.uniform(-10, 10, (n, 2))
    dst = apply_se2(rng.uniform(-5, 5, 3), src) + rng.normal(0, 0.3, (n, 2))
    forward, backward = fit_se2(src, dst), fit_se2(dst, src)
    inv = inverse(forward)
    np.testing.assert_allclose(backward[:2], inv[:2], atol=1e-8)
    assert abs(wrap_angle(backward[2] - inv[2])) < 1e-10


def test_fit_se2_zero_weight_ignores_an_outlier_and_bad_input_is_refused():
    rng = np.random.default_rng(2)
    src = rng.uniform(-5, 5, (6, 2))
    T = np.array([1.0, 2.0, -0.4])
    dst = apply_se2(T, src)
    dst[0] += 50.0
    np.testing.assert_allclose(fit_se2(src, dst, [0, 1, 1, 1, 1, 1]), T, atol=1e-12)
    with pytest.raises(ValueError):
        fit_se2(src, dst[:3])
    with pytest.raises(ValueError):
        fit_se2(src, dst, np.zeros(6))


def test_fit_se2_single_point_is_translation_only():
    np.testing.assert_allclose(fit_se2([[1.0, 1.0]], [[3.0, -1.0]]), [2.0, -2.0, 0.0])


# --------------------------------------------------------------------------- slots


def test_identical_maps_score_perfectly(truth):
    m = evaluate_map(truth, truth)
    n = len(truth.slots)
    assert (m.slots_true, m.slots_mapped, m.slots_matched) == (n, n, n)
    assert m.corner_rmse_m == 0.0 and m.corner_p95_m == 0.0
    assert m.duplicate_slots == m.false_slots == m.missed_slots == m.wrong_merges == 0
    assert m.id_accuracy == 1.0 and m.id_labelled == n and m.id_accuracy_labelled == 1.0
    assert m.slot_precision == m.slot_recall == 1.0
    assert m.tags_matched == len(truth.tags) and m.tags_rmse_m == 0.0
    assert m.marking_endpoint_median_m == 0.0 and m.marking_endpoint_p95_m == 0.0
    assert m.alignment is None


def test_moving_every_corner_by_d_gives_corner_rmse_d(truth):
    d = 0.3
    offset = d * np.array([math.cos(0.7), math.sin(0.7)])
    moved = _with_slots(truth, [replace(s, corners=s.corners + offset) for s in truth.slots])
    m = evaluate_map(moved, truth)
    assert m.slots_matched == len(truth.slots)
    assert m.corner_rmse_m == pytest.approx(d)
    assert m.corner_p95_m == pytest.approx(d)


def test_corner_nees_is_the_error_in_the_metric_of_the_exported_covariance(truth):
    # each corner 0.3 m off along x; covariance sigma_x 0.1, sigma_y 1 m: NEES (0.3/0.1)^2 = 9;
    # a second map says sigma 0.3 along x (NEES 1); the truth's zero covariances are left out
    offset = np.array([0.3, 0.0])
    for sigma_x, nees in ((0.1, 9.0), (0.3, 1.0)):
        cov = np.array([[sigma_x**2, 0.0], [0.0, 1.0]])
        moved = _with_slots(truth, [replace(s, corners=s.corners + offset,
                                            corner_covariances=np.tile(cov, (4, 1, 1)))
                                    for s in truth.slots])
        m = evaluate_map(moved, truth)
        assert m.corner_nees_corners == 4 * len(truth.slots)
        assert m.corner_nees_mean == pytest.approx(nees)
        assert m.corner_nees_median == pytest.approx(nees)
    # a correlated covariance: e^T C^-1 e, not the diagonal alone
    cov = np.array([[0.04, 0.03], [0.03, 0.04]])
    e = np.array([0.2, -0.1])
    moved = _with_slots(truth, [replace(s, corners=s.corners + e,
                                        corner_covariances=np.tile(cov, (4, 1, 1)))
                                for s in truth.slots])
    assert evaluate_map(moved, truth).corner_nees_mean == pytest.approx(e @ np.linalg.solve(cov, e))
    exact = evaluate_map(truth, truth)  # covariances all zero: nothing to compute it over
    assert exact.corner_nees_corners == 0 and exact.to_dict()["corner_nees_mean"] is None


def test_corner_nees_follows_a_slot_mapped_entrance_to_rear(truth):
    # the estimate's corners come in the rotated order: their covariances must follow them
    # (only the true entrance-left corner is off, by 0.1 m, and its own sigma is 0.1 m)
    s = truth.slots[0]
    covs = np.array([np.eye(2) * v for v in (0.01, 0.04, 0.09, 0.16)])
    corners = s.corners.copy()
    corners[0] += [0.1, 0.0]
    flipped = replace(s, corners=corners[[2, 3, 0, 1]], corner_covariances=covs[[2, 3, 0, 1]])
    m = evaluate_map(_with_slots(truth, [flipped]), _with_slots(truth, [s]))
    assert m.slots_reversed == 1
    assert m.corner_nees_mean == pytest.approx(1.0 / 4)


def test_a_duplicated_slot_counts_once_as_duplicate(truth):
    copy = replace(truth.slots[5], id=999, corners=truth.slots[5].corners + [0.3, 0.0])
    m = evaluate_map(_with_slots(truth, [*truth.slots, copy]), truth)
    assert m.slots_matched == len(truth.slots)
    assert m.duplicate_slots == 1
    assert m.false_slots == 0 and m.wrong_merges == 0
    assert m.corner_rmse_m == 0.0  # the exact copy wins the one-to-one matching


def test_one_wrong_label_drops_id_accuracy_by_one_over_n(truth):
    n = len(truth.slots)
    slots = list(truth.slots)
    slots[3] = replace(slots[3], label="ZZ99")
    m = evaluate_map(_with_slots(truth, slots), truth)
    assert m.id_accuracy == pytest.approx(1.0 - 1.0 / n)


def test_an_unread_label_counts_wrong_but_not_in_the_labelled_accuracy(truth):
    n = len(truth.slots)
    slots = list(truth.slots)
    slots[0] = replace(slots[0], label=None)
    m = evaluate_map(_with_slots(truth, slots), truth)
    assert m.id_accuracy == pytest.approx(1.0 - 1.0 / n)
    assert m.id_labelled == n - 1 and m.id_accuracy_labelled == 1.0


def test_one_slot_spanning_two_true_slots_is_a_wrong_merge(truth):
    i, j = _row_neighbours(truth)
    merged = replace(truth.slots[i], corners=(truth.slots[i].corners + truth.slots[j].corners) / 2)
    slots = [merged if k == i else s for k, s in enumerate(truth.slots) if k != j]
    m = evaluate_map(_with_slots(truth, slots), truth)
    assert m.wrong_merges == 1
    assert m.false_slots == 0 and m.duplicate_slots == 0
    assert m.slots_matched == len(truth.slots) - 2 and m.missed_slots == 2


def test_a_missing_and_a_phantom_slot(truth):
    phantom = replace(truth.slots[0], id=1000, corners=truth.slots[0].corners + [0.0, 40.0])
    slots = [*truth.slots[1:], phantom]
    m = evaluate_map(_with_slots(truth, slots), truth)
    assert m.missed_slots == 1 and m.false_slots == 1 and m.wrong_merges == 0
    assert m.slot_precision == pytest.approx((len(slots) - 1) / len(slots))


def test_a_slot_mapped_entrance_to_rear_is_matched_and_counted(truth):
    slots = list(truth.slots)
    slots[2] = replace(slots[2], corners=slots[2].corners[[2, 3, 0, 1]])
    m = evaluate_map(_with_slots(truth, slots), truth)
    assert m.slots_matched == len(slots) and m.slots_reversed == 1
    assert m.corner_rmse_m == 0.0


def test_slots_true_seen_restricts_recall(truth):
    seen = {s.id for s in truth.slots[:10]}
    m = evaluate_map(_with_slots(truth, truth.slots[:8]), truth, slots_true_seen=seen)
    assert m.slots_true_seen == 10 and m.missed_slots == 2
    assert m.slot_recall == pytest.approx(0.8)
    with pytest.raises(ValueError, match="not in the truth"):
        evaluate_map(truth, truth, slots_true_seen={123456})


def test_bad_radius_is_refused(truth):
    with pytest.raises(ValueError, match="match_radius"):
        evaluate_map(truth, truth, match_radius=0.0)


# --------------------------------------------------------------------------- alignment


@pytest.mark.parametrize("start", ["tags", "labels", "one_tag"])
def test_rotated_and_translated_copy_aligns_to_zero_error(truth, start):
    T = np.array([4.0, -2.5, math.radians(12.0)])
    moved = transform_map(inverse(T), truth)  # truth = T * moved
    if start == "labels":  # no tags: slots matched by their unique labels start the fit
        moved = replace(moved, tags=())
    if start == "one_tag":  # one tag and no labels: the tag's pose starts the fit
        unlabelled = tuple(replace(s, label=None) for s in moved.slots)
        moved = replace(moved, tags=moved.tags[:1], slots=unlabelled)
    m = evaluate_map(moved, truth, align=True)
    assert m.alignment is not None
    np.testing.assert_allclose(m.alignment, [4.0, -2.5, 12.0], atol=1e-9)
    assert m.slots_matched == len(truth.slots)
    assert m.corner_rmse_m < 1e-9 and m.marking_endpoint_p95_m < 1e-9
    if start == "tags":
        assert m.tags_rmse_m < 1e-9 and m.tags_yaw_rmse_deg < 1e-9
    unaligned = evaluate_map(moved, truth)
    assert unaligned.slots_matched < len(truth.slots)


def test_small_offset_without_tags_or_labels_aligns_by_nearest_slots(truth):
    T = np.array([0.6, 0.4, math.radians(1.0)])
    moved = transform_map(inverse(T), truth)
    moved = replace(moved, tags=(), slots=tuple(replace(s, label=None) for s in moved.slots))
    m = evaluate_map(moved, truth, align=True)
    np.testing.assert_allclose(m.alignment, [0.6, 0.4, 1.0], atol=1e-9)
    assert m.corner_rmse_m < 1e-9


# --------------------------------------------------------------------------- empty, tags, markings


def test_empty_estimate_gives_zero_matches_and_none_metrics(truth):
    m = evaluate_map(SemanticMap(), truth, align=True)
    assert m.slots_matched == 0 and m.slots_mapped == 0 and m.missed_slots == len(truth.slots)
    assert m.alignment is None and "not aligned" in m.alignment_skipped
    assert evaluate_map(truth, truth).alignment_skipped is None  # not asked
    d = m.to_dict()
    for key in (
        "corner_rmse_m",
        "corner_p95_m",
        "id_accuracy",
        "tags_rmse_m",
        "marking_endpoint_median_m",
        "slot_precision",
    ):
        assert d[key] is None, key
    assert d["slot_recall"] == 0.0
    assert evaluate_map(SemanticMap(), SemanticMap()).to_dict()["slot_recall"] is None


def test_tags_are_matched_by_family_and_id(truth):
    tags = list(truth.tags)
    tags[0] = replace(tags[0], mTt=tags[0].mTt + [0.3, -0.4, math.radians(2.0)])
    tags[1] = replace(tags[1], tag_id=tags[1].tag_id + 5000)  # unknown ID: not matched
    tags = [tags[3], tags[2], tags[1], tags[0]]  # order does not matter
    m = evaluate_map(replace(truth, tags=tuple(tags)), truth)
    assert (m.tags_true, m.tags_mapped, m.tags_matched) == (4, 4, 3)
    assert m.tags_rmse_m == pytest.approx(0.5 / math.sqrt(3))
    assert m.tags_yaw_rmse_deg == pytest.approx(2.0 / math.sqrt(3))


def test_marking_end_point_distances():
    def mk(a, b):
        return Marking(a=np.array(a, dtype=float), b=np.array(b, dtype=float), width=0.15)

    true = SemanticMap(markings=(mk([0, 0], [10, 0]), mk([0, 20], [0, 30])))
    mapped = SemanticMap(
        markings=(
            mk([1, 0.1], [9, 0.1]),  # both ends 0.1 m off the first segment
            mk([0.2, 22], [0.2, 25]),  # both ends 0.2 m off the second
            mk([-3, 0], [10, 4]),  # 3 m beyond an end, 4 m beside
        )
    )
    m = evaluate_map(mapped, true)
    assert (m.markings_true, m.markings_mapped) == (2, 3)
    dist = np.array([0.1, 0.1, 0.2, 0.2, 3.0, 4.0])
    assert m.marking_endpoint_median_m == pytest.approx(np.median(dist))
    assert m.marking_endpoint_p95_m == pytest.approx(np.percentile(dist, 95))


def test_marking_nees_measures_each_lines_end_offsets_against_its_covariance():
    """Each mapped line with an ``across_covariance`` C: its ends' offsets e across the
    nearest parallel true line, e^T C^-1 e; lines without C, turned across every true line
    or further off than MARKING_MATCH_M are not counted."""
    from semslam.evaluation.map_metrics import MARKING_MATCH_M

    def mk(a, b, cov=None):
        return Marking(np.array(a, dtype=float), np.array(b, dtype=float), 0.15, None,
                       None if cov is None else np.array(cov, dtype=float))

    C1 = [[0.01, 0.002], [0.002, 0.04]]
    C2 = [[0.09, 0.0], [0.0, 0.09]]
    true = SemanticMap(markings=(mk([0, 0], [20, 0]), mk([0, 3], [20, 3]), mk([30, 0], [30, 20])))
    mapped = SemanticMap(markings=(
        mk([2, 0.1], [18, -0.3], C1),  # the first line, ends +0.1 / -0.3 across it
        mk([0, 2.9], [20, 3.2], C2),  # the second (the first lies 2.9 m off: not it)
        mk([1, 1.5], [19, 1.5]),  # no covariance: not counted
        mk([30.4, 2], [30.4, 18], C2),  # the third, 0.4 m off both ends
        mk([10, -5], [10.5, -9], C1),  # across the first: no parallel true line near
        mk([0, 0.5 + 3 + MARKING_MATCH_M], [20, 0.5 + 3 + MARKING_MATCH_M], C2),  # too far
    ))
    m = evaluate_map(mapped, true)
    e1, e2, e3 = np.array([0.1, -0.3]), np.array([-0.1, 0.2]), np.array([0.4, 0.4])
    expected = [e @ np.linalg.solve(np.array(C), e) for e, C in ((e1, C1), (e2, C2), (e3, C2))]
    assert m.marking_nees_lines == 3
    assert m.marking_nees_mean == pytest.approx(np.mean(expected))
    assert m.marking_nees_median == pytest.approx(np.median(expected))
    assert math.isnan(evaluate_map(replace(mapped, markings=mapped.markings[2:3]),
                                   true).marking_nees_mean)


def test_point_segment_distance_cases():
    a = np.array([[0.0, 0.0], [5.0, 5.0]])
    b = np.array([[2.0, 0.0], [5.0, 5.0]])  # second is a point
    pts = np.array([[1.0, 1.0], [3.0, 0.0], [-1.0, 0.0], [5.0, 6.0], [1.0, 0.0]])
    np.testing.assert_allclose(point_segment_distances(pts, a, b), [1.0, 1.0, 1.0, 1.0, 0.0])


def test_label_confidences_are_scored_against_the_labels_being_right(truth):
    """id_brier and id_confident_accuracy, counted by hand on a map with one sure wrong
    label, one unsure right label and one unread slot."""
    n = len(truth.slots)
    slots = [replace(s, label_confidence=1.0) for s in truth.slots]
    slots[0] = replace(slots[0], label=None, label_confidence=0.0)
    slots[1] = replace(slots[1], label="ZZ99", label_confidence=0.95)
    slots[2] = replace(slots[2], label_confidence=0.6)
    m = evaluate_map(_with_slots(truth, slots), truth)
    assert m.id_labelled == n - 1
    assert m.id_brier == pytest.approx((0.95**2 + 0.4**2) / (n - 1))
    assert m.id_confident == n - 2
    assert m.id_confident_accuracy == pytest.approx((n - 3) / (n - 2))
