"""Line landmarks of the mapper: which line a detection joins, and a line's uncertainty."""

import math

import numpy as np
import pytest

from semslam.mapping.lines import LineLandmarks, across_sigma


def _line_along_x(lines: LineLandmarks, y: float, x0: float, x1: float) -> int:
    """A line y = ``y`` from x0 to x1 (map frame), started from one detection."""
    return lines.start(np.array([[x0, y], [x1, y]]), keyframe=0).index


def _pick(lines: LineLandmarks, detection: np.ndarray, sigma: float = 0.05):
    return lines.pick(detection, lines.candidates(detection), sigma)


def test_the_nearest_line_takes_a_detection():
    lines = LineLandmarks(distance_gate=0.5)
    near, _ = _line_along_x(lines, 0.0, 0.0, 4.0), _line_along_x(lines, 0.4, 0.0, 4.0)
    assert _pick(lines, np.array([[1.0, 0.03], [3.0, 0.03]])) == near


def test_a_detection_between_two_lines_is_left_out():
    lines = LineLandmarks(distance_gate=0.5)
    _line_along_x(lines, 0.0, 0.0, 4.0)
    _line_along_x(lines, 0.3, 0.0, 4.0)
    assert _pick(lines, np.array([[1.0, 0.14], [3.0, 0.14]])) is None


def test_two_lines_the_detection_cannot_tell_apart_give_it_to_the_one_it_reaches():
    """Two collinear pieces 2 cm apart across (within the detection's sigma): the nearer
    across ends 1 m before the detection, the other covers it and takes it."""
    lines = LineLandmarks(distance_gate=0.5, gap=1.5)
    short = _line_along_x(lines, 0.0, 0.0, 2.0)
    covering = _line_along_x(lines, 0.02, 2.5, 6.0)
    detection = np.array([[3.0, 0.005], [5.0, 0.005]])
    assert [c for c, _ in lines.candidates(detection)] == [short, covering]
    assert _pick(lines, detection) == covering
    assert _pick(lines, detection, sigma=0.01) is None  # a sharper detection tells them apart


def test_across_sigma_is_the_mean_variance_of_the_across_offset_along_the_segment():
    """Against a numerical Jacobian of the across offset at points along the line, with
    the variance averaged over a fine grid of the segment."""
    theta, d, anchor = 0.3, 1.2, np.array([2.0, -1.0])
    root = np.array([[0.02, 0.0], [0.5, 0.03]])
    S = root @ root.T  # (theta, d) covariance, correlated

    def across(point, th, dd):
        return float(np.array([math.cos(th), math.sin(th)]) @ (point - anchor) - dd)

    normal = np.array([math.cos(theta), math.sin(theta)])
    u = np.array([-math.sin(theta), math.cos(theta)])
    s0, s1, h = -3.0, 5.0, 1e-6
    variances = []
    for s in np.linspace(s0, s1, 2001):
        p = anchor + d * normal + s * u
        J = np.array([(across(p, theta + h, d) - across(p, theta - h, d)) / (2 * h),
                      (across(p, theta, d + h) - across(p, theta, d - h)) / (2 * h)])
        variances.append(J @ S @ J)
    assert across_sigma(S, s0, s1) == pytest.approx(math.sqrt(np.mean(variances)), rel=1e-3)
    assert across_sigma(np.zeros((2, 2)), s0, s1) == 0.0
