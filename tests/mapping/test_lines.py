"""Line landmarks of the mapper: a line's uncertainty across itself."""

import math

import numpy as np
import pytest

from semslam.mapping.lines import across_sigma


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
