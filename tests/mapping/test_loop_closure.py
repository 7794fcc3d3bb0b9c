"""Loop closures by agreeing slot IDs (semslam.mapping.loop_closure)."""

import math

import numpy as np

from semslam.geometry import compose, inverse, transform_points
from semslam.mapping.loop_closure import ClosureVote, IdLoopClosure, correction_to

SLOT = np.array([[0.0, 0.0], [2.5, 0.0], [2.5, 5.0], [0.0, 5.0]])
POSE = np.array([20.0, 3.0, 0.1])


def _vote(k, landmark, correction, label=None):
    return ClosureVote(k, k, landmark, label or f"L{landmark}", np.asarray(correction, float))


def test_correction_moves_the_sighting_onto_the_landmark():
    T = np.array([3.0, -1.0, math.radians(4.0)])
    sighted = SLOT + [10.0, 2.0]
    landmark = transform_points(T, sighted)
    np.testing.assert_allclose(correction_to(sighted, landmark), T, atol=1e-12)


def test_three_ids_agreeing_on_a_shift_close_the_loop():
    closure = IdLoopClosure(window=20, support=3)
    shift = [4.0, 0.5, 0.02]
    for k, landmark in enumerate((1, 2, 3)):
        closure.vote(_vote(k, landmark, shift))
    closure.vote(_vote(3, 9, [-2.5, 0.0, 0.0]))  # a misread elsewhere
    agreed = closure.consensus(3, POSE)
    assert {v.landmark for v in agreed} == {1, 2, 3}
    assert closure.closures == 1 and closure.votes == []


def test_readings_that_agree_with_the_pose_are_no_closure():
    closure = IdLoopClosure(support=3)
    for k in range(5):
        closure.vote(_vote(k, k, [0.02, -0.01, 0.001]))
    assert closure.consensus(5, POSE) == []


def test_neighbour_misreads_must_outvote_the_right_readings():
    """Three misreads one slot pitch off agree with each other, but five right readings
    agree with the current pose: no closure."""
    closure = IdLoopClosure(support=3)
    for k in range(3):
        closure.vote(_vote(k, 10 + k, [-2.5, 0.0, 0.0]))
    for k in range(5):
        closure.vote(_vote(k, 20 + k, [0.0, 0.0, 0.0]))
    assert closure.consensus(6, POSE) == []


def test_one_landmark_read_many_times_is_one_vote():
    closure = IdLoopClosure(support=3)
    for k in range(6):
        closure.vote(_vote(k, 7, [5.0, 0.0, 0.0]))
    assert closure.consensus(6, POSE) == []


def test_old_votes_expire():
    closure = IdLoopClosure(window=10, support=3)
    closure.vote(_vote(0, 1, [4.0, 0.0, 0.0]))
    closure.vote(_vote(1, 2, [4.0, 0.0, 0.0]))
    closure.vote(_vote(30, 3, [4.0, 0.0, 0.0]))
    assert closure.consensus(30, POSE) == []
    assert len(closure.votes) == 1


def test_agreement_is_judged_at_the_newest_pose():
    """Corrections rotating about the map origin differ a lot in (x, y) but agree on where
    the car is; votes compare T * pose, not T."""
    target = np.array([24.0, 3.5, 0.12])
    closure = IdLoopClosure(support=3)
    for k, yaw in enumerate((0.0, 0.01, -0.01)):
        R = np.array([0.0, 0.0, yaw])
        T = compose(compose(target, R), inverse(POSE))  # T * POSE = target, turned a little
        closure.vote(_vote(k, k, T))
    assert len(closure.consensus(3, POSE)) == 3


def test_a_few_agreeing_among_many_scattered_votes_is_no_closure():
    """A confused stretch: twelve landmarks vote for scattered corrections, three of them
    happen to agree; they are not half of the voters."""
    closure = IdLoopClosure(support=3)
    rng = np.random.default_rng(4)
    for landmark in range(9):
        closure.vote(_vote(landmark, landmark, [*rng.uniform(-3, 3, 2), 0.0]))
    for landmark in (20, 21, 22):
        closure.vote(_vote(9, landmark, [6.0, 6.0, 0.0]))
    assert closure.consensus(10, POSE) == []


def _two_camps(first, second, pose):
    """Three IDs vote for ``first``, three others for ``second``; both orders of voting."""
    outcomes = []
    for camps in ((first, second), (second, first)):
        lc = IdLoopClosure(window=20, support=3, distance=0.5, yaw_deg=3.0)
        for n in range(6):
            correction, name = camps[n // 3], f"{'AB'[n // 3]}{n}"
            lc.vote(ClosureVote(10, n, n, name, np.asarray(correction, float)))
        outcomes.append(lc.consensus(10, pose))
    return outcomes


def test_an_equally_supported_rival_stops_a_closure_whichever_voted_first():
    """A rival that differs only in heading, or by 0.8 m (between one and two cluster
    radii), is a rival: no closure, in either order."""
    pose = np.array([10.0, 5.0, 0.3])
    turned = compose(compose(pose, [0.0, 0.0, math.radians(5.0)]), inverse(pose))
    for rival in (turned, np.array([0.8, 0.0, 0.0])):
        assert _two_camps(rival, np.zeros(3), pose) == [[], []]
