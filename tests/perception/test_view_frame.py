"""Top views of other sizes and resolutions in the detectors' ps2.0 frame."""

import numpy as np
import pytest

from semslam.errors import PerceptionError
from semslam.perception.view_frame import ViewFrame, into_detector_frame, view_frame


def test_a_ps2_view_is_the_detectors_frame_itself():
    image = np.zeros((600, 600, 3), np.uint8)
    frame = view_frame(image.shape)
    assert frame.is_identity
    assert into_detector_frame(image, frame) is image


def test_a_resized_view_is_resampled_back_to_60_px_per_metre():
    frame = view_frame((512, 512, 3))
    assert frame.scale == (600 / 512, 600 / 512) and frame.offset == (0, 0)
    out = into_detector_frame(np.full((512, 512, 3), 7, np.uint8), frame)
    assert out.shape == (600, 600, 3) and (out == 7).all()


def test_a_narrow_view_is_padded_around_its_centre_where_the_car_is():
    frame = view_frame((600, 480, 3))
    assert frame.scale == (1.0, 1.0) and frame.offset == (60, 0)
    out = into_detector_frame(np.full((600, 480, 3), 9, np.uint8), frame)
    assert out.shape == (600, 600, 3)
    assert (out[:, :60] == 0).all() and (out[:, 540:] == 0).all() and (out[:, 60:540] == 9).all()
    # the image's centre is the detectors' centre, where the vehicle frame's origin is
    np.testing.assert_allclose(frame.to_detector([[239.5, 299.5]]), [[299.5, 299.5]])


def test_pixels_map_both_ways_with_pixel_centres():
    frame = view_frame((300, 300, 3))  # 30 px per metre: every pixel is two
    np.testing.assert_allclose(frame.to_detector([[0.0, 0.0], [299.0, 149.5]]),
                               [[0.5, 0.5], [598.5, 299.5]])
    uv = np.random.default_rng(1).uniform(0, 300, (20, 2))
    np.testing.assert_allclose(frame.to_image(frame.to_detector(uv)), uv, atol=1e-9)


def test_directions_follow_an_uneven_resampling():
    frame = ViewFrame((100, 100), (2.0, 1.0), (0, 0))
    assert frame.direction_to_image(0.0) == pytest.approx(0.0)
    # 45 deg in the detectors' frame is steeper in an image that was stretched along u
    assert frame.direction_to_image(np.pi / 4) == pytest.approx(np.arctan2(1.0, 0.5))
    d = np.linspace(-3, 3, 13)
    np.testing.assert_allclose(frame.direction_to_detector(frame.direction_to_image(d)), d)


def test_a_given_ground_resolution_is_used():
    frame = view_frame((400, 400, 3), px_per_m=80.0)  # 5 m across, padded to 10 m
    assert frame.scale == (0.75, 0.75) and frame.offset == (150, 150)


def test_a_view_wider_than_the_detectors_is_refused_with_its_size():
    with pytest.raises(PerceptionError, match=r"900 x 900 px at 60 px per metre covers 15.0 m"):
        view_frame((900, 900, 3), px_per_m=60.0)
    for bad in (0.0, -3.0, float("nan"), float("inf")):
        with pytest.raises(PerceptionError, match="--px-per-m"):
            view_frame((600, 600, 3), px_per_m=bad)


def test_a_view_too_small_or_too_coarse_is_refused():
    with pytest.raises(PerceptionError, match=r"8 x 8 px: too small"):
        view_frame((8, 8, 3))
    with pytest.raises(PerceptionError, match=r"80 x 80 px at 8 px per metre: too coarse"):
        view_frame((80, 80, 3))
    assert view_frame((100, 100, 3)).scale == (6.0, 6.0)  # 10 px per metre: read
    with pytest.raises(PerceptionError, match=r"covers 1e-303 m: too little ground"):
        view_frame((600, 600, 3), px_per_m=6e305)
    assert view_frame((600, 600, 3), px_per_m=600.0).scale == (0.1, 0.1)  # 1 m: read


def test_points_in_the_padding_are_dropped_with_their_slots():
    """A narrow view is padded to the detectors' square; a point found in the padding is not
    in the image, and a slot that uses it goes too (the others keep their points)."""
    from semslam.perception.marking_points import MarkingPoint
    from semslam.perception.slot_ids import SlotIdReading
    from semslam.perception.slots import DetectedSlot
    from semslam.perception.topview_perception import TopviewDetections
    from semslam.pipeline.detect import within_image
    from semslam.types import JunctionShape, SlotKind

    frame = view_frame((600, 480, 3))  # columns 60-539 of the detectors' frame are the image
    points = tuple(MarkingPoint(np.array(uv, float), 0.0, JunctionShape.T, 0.9)
                   for uv in ([30.0, 100.0], [200.0, 100.0], [200.0, 280.0], [400.0, 280.0]))
    corners = np.zeros((4, 2))
    slots = (DetectedSlot(0, 1, corners, SlotKind.PERPENDICULAR, 90.0, 0.8),
             DetectedSlot(2, 3, corners, SlotKind.PERPENDICULAR, 90.0, 0.7))
    ids = (SlotIdReading("A1", 0.9, (0.9, 0.9)), SlotIdReading("A2", 0.8, (0.9, 0.9)))
    kept = within_image(TopviewDetections(points, slots, ids), frame)
    assert [tuple(p.uv) for p in kept.points] == [(200.0, 100.0), (200.0, 280.0), (400.0, 280.0)]
    assert [(s.i, s.j) for s in kept.slots] == [(1, 2)] and kept.ids == ids[1:]
    whole = TopviewDetections(points[1:], (), ())
    assert within_image(whole, frame) is whole
