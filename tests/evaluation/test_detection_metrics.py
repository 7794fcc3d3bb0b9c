"""The ps2.0 metric on hand-made detections."""

import math

import numpy as np

from semslam.evaluation.detection_metrics import DetectionCounts, match_points, score_image

LABELLED = np.array([[100.0, 100.0], [200.0, 100.0], [300.0, 100.0]])
DOWN = np.full(3, math.pi / 2)  # separator lines pointing down the image
SLOTS = np.array([[1, 2, 1, 90], [2, 3, 1, 90]])


def test_a_point_hits_within_distance_and_angle_only():
    det = np.array([[105.0, 105.0], [200.0, 112.0], [300.0, 100.0]])
    dirs = np.array([math.pi / 2, math.pi / 2, math.pi / 2 + math.radians(40)])
    match = match_points(det, dirs, np.ones(3), LABELLED, DOWN)
    assert match.tolist() == [0, -1, -1]  # 7.07 px ok; 12 px too far; 40 deg too turned


def test_each_label_is_matched_once_by_confidence():
    det = np.array([[101.0, 100.0], [99.0, 100.0]])
    match = match_points(det, DOWN[:2], np.array([0.2, 0.9]), LABELLED, DOWN)
    assert match.tolist() == [-1, 0]


def test_slots_hit_when_both_entrance_points_hit_in_either_order():
    det = LABELLED + 2.0
    counts = score_image(
        det,
        DOWN,
        np.zeros(3),
        np.ones(3),
        np.array([[1, 0], [2, 0]]),
        LABELLED,
        DOWN,
        np.array([0, 0, 1]),
        SLOTS,
    )
    s = counts.summary()
    assert (s["point_precision"], s["point_recall"]) == (1.0, 1.0)
    assert s["slot_true_positives"] == 1 and s["slot_precision"] == 0.5
    assert s["slot_recall"] == 0.5
    assert s["shape_accuracy"] == 2 / 3


def test_counts_pool_over_images():
    total = DetectionCounts()
    total += score_image(
        LABELLED,
        DOWN,
        np.zeros(3),
        np.ones(3),
        np.zeros((0, 2)),
        LABELLED,
        DOWN,
        np.zeros(3),
        SLOTS,
    )
    total += score_image(
        np.zeros((0, 2)),
        np.zeros(0),
        np.zeros(0),
        np.zeros(0),
        np.zeros((0, 2)),
        LABELLED,
        DOWN,
        np.zeros(3),
        SLOTS,
    )
    s = total.summary()
    assert s["images"] == 2 and s["point_recall"] == 0.5 and s["point_precision"] == 1.0
    assert s["slot_recall"] == 0.0
