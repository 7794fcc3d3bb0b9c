"""Line landmarks of the mapper: a line's uncertainty across itself."""

import math

import numpy as np
import pytest

from semslam.mapping.lines import end_covariance, segment_sigma


def test_segment_sigma_is_the_mean_variance_of_the_across_offset_along_the_segment():
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
    sigma = segment_sigma(end_covariance(S, s0, s1))  # as the mapper exports it
    assert sigma == pytest.approx(math.sqrt(np.mean(variances)), rel=1e-3)
    assert segment_sigma(end_covariance(np.zeros((2, 2)), s0, s1)) == 0.0


def test_the_variance_at_each_point_follows_from_the_offsets_at_the_two_ends():
    """``end_covariance`` and ``across_variance`` give, at every point of the segment, the
    variance a numerical Jacobian of the across offset gives there; its mean along the
    segment is ``segment_sigma`` squared, and the ends differ (a line surer at one end)."""
    from semslam.line_uncertainty import across_variance

    theta, d, anchor = -0.7, 0.4, np.array([1.0, 3.0])
    root = np.array([[0.004, 0.0], [-0.2, 0.05]])
    S = root @ root.T
    normal = np.array([math.cos(theta), math.sin(theta)])
    u = np.array([-math.sin(theta), math.cos(theta)])
    s0, s1, h = -40.0, 200.0, 1e-6

    def across(point, th, dd):
        return float(np.array([math.cos(th), math.sin(th)]) @ (point - anchor) - dd)

    ends = end_covariance(S, s0, s1)
    lam = np.linspace(0.0, 1.0, 1001)
    expected = []
    for t in lam:
        p = anchor + d * normal + (s0 + t * (s1 - s0)) * u
        J = np.array([(across(p, theta + h, d) - across(p, theta - h, d)) / (2 * h),
                      (across(p, theta, d + h) - across(p, theta, d - h)) / (2 * h)])
        expected.append(J @ S @ J)
    np.testing.assert_allclose(across_variance(ends, lam), expected, rtol=1e-5, atol=1e-12)
    assert math.sqrt(np.mean(across_variance(ends, lam))) == pytest.approx(
        segment_sigma(ends), rel=1e-3)
    assert ends[1, 1] > 4 * ends[0, 0]
    # outside the segment the variance is the nearer end's (detections clamp there)
    assert across_variance(ends, np.array([-0.5, 1.5])) == pytest.approx(np.diag(ends))
