"""Recent frames merged into one for relocalization (semslam.localization.recent)."""

import numpy as np

from semslam.localization.recent import RecentFrames
from semslam.types import FrameObservations, SlotKind, SlotObservation

SLOT = np.array([[3.0, 1.0], [3.0, -1.5], [8.0, -1.5], [8.0, 1.0]])


def _frame(t, label, x_offset=0.0):
    obs = SlotObservation(SLOT - [x_offset, 0.0], SlotKind.PERPENDICULAR, label, 0.9, 1.0, 0.05)
    return FrameObservations(t, (obs,), (), ())


def test_merged_slot_counts_the_readings_of_its_label():
    recent = RecentFrames(window=2.0)
    labels = ["A7", "A7", "A1", "A7", None, "A7"]
    for i, label in enumerate(labels):
        x = 0.2 * i  # the car drives 0.2 m per frame; the slot stays put in the world
        recent.add(np.array([x, 0.0, 0.0]), _frame(0.1 * i, label, x))
    (slot,) = recent.merged().slots
    assert slot.label == "A7" and slot.label_reads == 4
    np.testing.assert_allclose(slot.vCorners, SLOT - [1.0, 0.0], atol=1e-12)
    assert slot.label_confidence < 0.9  # one dissenting reading discounts it


def test_labels_read_with_confidence_zero_merge_to_confidence_zero():
    recent = RecentFrames(window=2.0)
    for i in range(4):
        obs = SlotObservation(SLOT, SlotKind.PERPENDICULAR, "A7", 0.0, 1.0, 0.05)
        recent.add(np.zeros(3), FrameObservations(0.1 * i, (obs,), (), ()))
    (slot,) = recent.merged().slots  # it divided by the zero sum of the votes
    assert slot.label == "A7" and slot.label_confidence == 0.0 and slot.label_reads == 4


def test_old_frames_leave_the_window():
    recent = RecentFrames(window=1.0)
    for i in range(30):
        recent.add(np.array([0.0, 0.0, 0.0]), _frame(0.1 * i, "B2"))
    (slot,) = recent.merged().slots
    assert 10 <= slot.label_reads <= 11  # the frames within 1 s of the newest


def test_a_tag_seen_before_a_turn_moves_with_its_covariance_turned_whole():
    """The car turns 90 deg left between the sighting and the newest frame: the sighting's
    pose and its covariance, cross terms too, are the same tag seen from the new pose."""
    from semslam.types import TagObservation

    cov = np.array([[0.01, 0.0, 0.001], [0.0, 1e-4, 0.0], [0.001, 0.0, 1e-4]])
    tag = TagObservation("tag36h11", 4, 0.2, np.array([5.0, 1.0, 3.0]), 1.5, cov)
    recent = RecentFrames(window=5.0)
    recent.add(np.zeros(3), FrameObservations(0.0, (), (tag,), ()))
    now = np.array([2.0, 1.0, np.pi / 2])
    recent.add(now, FrameObservations(1.0, (), (), ()))
    (moved,) = recent.merged().tags
    # worked out by hand: the tag at (5, 1) in the old frame is 3 m ahead of the old origin
    # and 1 m to the right of the new car at (2, 1) facing +y: (0, -3), yaw 3 - pi/2
    np.testing.assert_allclose(moved.vTt, [0.0, -3.0, 3.0 - np.pi / 2], atol=1e-12)
    # turned by -90 deg: the old x (variance 0.01) is the new -y; the x-yaw covariance
    # 0.001 becomes a y-yaw covariance of -0.001
    expected = np.array([[1e-4, 0.0, 0.0], [0.0, 0.01, -0.001], [0.0, -0.001, 1e-4]])
    np.testing.assert_allclose(moved.covariance, expected, atol=1e-15)
    assert np.linalg.eigvalsh(moved.covariance).min() > 0


def test_the_memory_keeps_frames_a_tenth_of_a_second_apart_whatever_the_frame_rate():
    """At 10 Hz every frame of the window is kept; at 50 Hz about one in four, the newest
    always; a slot's readings count frames a tenth of a second apart either way."""
    reads = {}
    for rate in (10, 50):
        recent = RecentFrames(window=2.0)
        for i in range(4 * rate + 1):
            recent.add(np.zeros(3), _frame(i / rate, "B2"))
        kept = [f.t for _, f, _ in recent._frames]
        assert kept[-1] == 4.0 and kept[0] >= 2.0 - 1e-9
        assert min(np.diff(kept[:-1])) >= 0.08 - 1e-9  # at 50 Hz: 0.08 s apart
        (slot,) = recent.merged().slots
        reads[rate] = slot.label_reads
    assert reads[10] == 21  # every frame from 2.0 s to 4.0 s
    assert 20 <= reads[50] <= 27
