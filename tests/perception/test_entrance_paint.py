"""The entrance check on hand-drawn top views: junctions keep, bare line ends go."""

import math

import cv2
import numpy as np
import pytest

from semslam.perception.entrance_paint import bare_line_ends, entrance_scores

GROUND, PAINT = 90, 220


def _view(*segments) -> np.ndarray:
    """A 600 x 600 grey floor with 10 px wide white lines ((u0, v0), (u1, v1))."""
    img = np.full((600, 600, 3), GROUND, np.uint8)
    for a, b in segments:
        cv2.line(img, tuple(map(int, a)), tuple(map(int, b)), (PAINT,) * 3, 10)
    return img


POINT = np.array([[300.0, 300.0]])
INTO_SLOT = np.array([-math.pi / 2])  # the separator runs up from the point


def test_a_t_junction_has_its_entrance_line():
    img = _view(((300, 300), (300, 100)), ((150, 300), (450, 300)))
    assert entrance_scores(img, POINT, INTO_SLOT)[0] > 0.9
    assert not bare_line_ends(img, POINT, INTO_SLOT)[0]


def test_an_l_junction_has_it_on_one_side():
    img = _view(((300, 300), (300, 100)), ((300, 300), (450, 300)))
    assert not bare_line_ends(img, POINT, INTO_SLOT)[0]


def test_a_slanted_junction_at_50_degrees_keeps():
    end = (300 + 200 * math.cos(math.radians(-50)), 300 + 200 * math.sin(math.radians(-50)))
    img = _view(((300, 300), end), ((150, 300), (450, 300)))
    assert not bare_line_ends(img, POINT, np.array([math.radians(-50)]))[0]


@pytest.mark.parametrize("gap", [0, 40])
def test_the_end_of_a_bare_line_goes(gap):
    # a separator that stops in the aisle (gap 0), or a long line broken by a gap
    segments = [((300, 300), (300, 100))]
    if gap:
        segments.append(((300, 300 + gap), (300, 560)))
    img = _view(*segments)
    assert entrance_scores(img, POINT, INTO_SLOT)[0] < 0.1
    assert bare_line_ends(img, POINT, INTO_SLOT)[0]


def test_undecided_points_are_kept():
    faint = np.full((600, 600, 3), GROUND, np.uint8)
    cv2.line(faint, (300, 300), (300, 100), (GROUND + 5,) * 3, 10)  # below MIN_CONTRAST
    assert np.isnan(entrance_scores(faint, POINT, INTO_SLOT)[0])
    assert not bare_line_ends(faint, POINT, INTO_SLOT)[0]
    at_border = _view(((5, 300), (5, 100)))  # the entrance side would leave the view
    left = np.array([[5.0, 300.0]])
    assert np.isnan(entrance_scores(at_border, left, INTO_SLOT)[0])
    assert not bare_line_ends(at_border, left, INTO_SLOT)[0]


def test_no_points_and_deterministic():
    img = _view(((300, 300), (300, 100)))
    assert entrance_scores(img, np.zeros((0, 2)), np.zeros(0)).shape == (0,)
    a = entrance_scores(img, POINT, INTO_SLOT)
    assert np.array_equal(a, entrance_scores(img, POINT, INTO_SLOT), equal_nan=True)
