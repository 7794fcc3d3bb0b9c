"""Greedy tag placement on a straight route that leaves its only landmarks behind."""

import math

import numpy as np

from semslam.analysis import tag_placement
from semslam.analysis.accuracy import (
    GRADES,
    MapGeometry,
    RouteFilter,
    SensorModel,
    filter_route,
    position_sigma,
    position_sigmas,
    route_information,
    tag_information,
)
from semslam.analysis.tag_placement import (
    candidate_tags,
    coverage_placement,
    even_placement,
    greedy_placement,
    placement_spread,
    random_placement,
    resample_route,
    seen_often_enough,
    starts_covered,
    tag_visibility,
)
from semslam.types import SemanticMap, Slot, SlotKind


def _route():
    t = np.arange(0.0, 40.0, 0.1)
    poses = np.column_stack([2.0 * t, np.zeros_like(t), np.zeros_like(t)])
    return resample_route(poses, t, 1.0)


def _map():
    c = np.array([[1.0, 1.5], [3.5, 1.5], [3.5, 4.0], [1.0, 4.0]])
    return SemanticMap(slots=(Slot(1, None, 0.0, c, np.zeros((4, 2, 2)), SlotKind.PERPENDICULAR),))


def test_candidates_stand_beside_the_route_facing_the_oncoming_car():
    poses, _ = _route()
    cands = candidate_tags(poses, spacing=10.0, offset=3.0)
    assert len(cands) == 2 * 7  # 10, 20, ..., 70 m on both sides of a 79 m route
    np.testing.assert_allclose(np.abs(cands[:, 1]), 3.0)
    np.testing.assert_allclose(np.abs(cands[:, 2]), math.pi)


def test_greedy_tags_lower_the_worst_sigma_and_beat_even_spread():
    poses, t = _route()
    infos, _ = route_information(MapGeometry(_map()), poses)
    cands = candidate_tags(poses, spacing=5.0, offset=3.0)
    steps = greedy_placement(infos, poses, t, cands, 3, GRADES["automotive"])
    worst = [s.worst_m for s in steps]
    assert len(steps) == 4 and steps[0].tag is None
    assert all(b < a for a, b in zip(worst, worst[1:], strict=False))
    assert worst[-1] < 0.6 * worst[0]
    assert even_placement(infos, poses, t, cands, 3, GRADES["automotive"]).worst_m >= worst[-1]


def _greedy_by_hand(infos, poses, t, cands, count, grade):
    """Greedy placement refiltering the whole route for every candidate: the tags chosen."""
    chosen = []
    for _ in range(count):
        keys = {}
        for c in set(range(len(cands))) - set(chosen):
            added = tag_placement._expected_tag_information(poses, cands[c][None], SensorModel())
            if added.any():
                sigma = position_sigmas(filter_route(infos + added, poses, t, grade))
                keys[c] = (round(sigma.max(), tag_placement.SIGMA_DIGITS), sigma.mean())
        best = min(keys, key=lambda c: (keys[c], c))
        chosen.append(best)
        infos = infos + tag_placement._expected_tag_information(poses, cands[best][None],
                                                                SensorModel())
    return [tuple(cands[c]) for c in chosen]


def test_greedy_placement_chooses_as_refiltering_the_whole_route_does():
    poses, t = _route()
    infos, _ = route_information(MapGeometry(_map()), poses)
    cands = candidate_tags(poses, spacing=5.0, offset=3.0)
    grade = GRADES["automotive"]
    steps = greedy_placement(infos, poses, t, cands, 4, grade)
    assert [s.tag for s in steps[1:]] == _greedy_by_hand(infos, poses, t, cands, 4, grade)


def test_a_tag_is_refiltered_where_it_changes_the_filter_not_along_the_whole_route():
    """A tag seen on two short stretches of a long route (going out and coming back): its
    sigmas as refiltering the whole route gives them, for a fraction of the steps."""
    out = np.arange(0.0, 1000.0)  # one pose a second, 2 m/s, out and back
    x = np.concatenate([2.0 * out, 2000.0 - 2.0 * out])
    poses = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    t = np.arange(len(x), dtype=float)
    base = np.zeros((len(x), 3, 3))
    base[:] = np.diag([400.0, 400.0, 1e4])  # landmarks in view all along: 5 cm, 0.6 deg
    changed = np.concatenate([np.arange(100, 110), np.arange(1890, 1900)])
    added = np.repeat(np.diag([5000.0, 1000.0, 4e4])[None], len(changed), axis=0)
    full = base.copy()
    full[changed] += added
    grade = GRADES["automotive"]
    route = RouteFilter(poses, t, grade)
    states = route.states(base)
    steps = 0
    step = route.step

    def counted(*args):
        nonlocal steps
        steps += 1
        return step(*args)

    route.step = counted
    sigma = tag_placement._sigmas_changed(
        route, states, position_sigmas(states), base, changed, added
    )
    expected = position_sigmas(filter_route(full, poses, t, grade))
    np.testing.assert_allclose(sigma, expected, rtol=0, atol=1e-8)
    assert np.abs(expected - position_sigmas(states)).max() > 0.01  # the tag matters
    assert steps < len(x) / 4  # 304 of 2000


def test_random_tags_are_reproducible_and_greedy_beats_their_median_on_the_worst_5_percent():
    poses, t = _route()
    infos, _ = route_information(MapGeometry(_map()), poses)
    cands = candidate_tags(poses, spacing=5.0, offset=3.0)
    grade = GRADES["automotive"]
    rng = np.random.default_rng(0)
    draws = [random_placement(infos, poses, t, cands, 3, grade, rng) for _ in range(20)]
    again = random_placement(infos, poses, t, cands, 3, grade, np.random.default_rng(0))
    assert again == draws[0] and all(d.count == 3 for d in draws)
    assert len({d.p95_m for d in draws}) > 1  # the draws differ
    spread = placement_spread(draws)
    greedy = greedy_placement(infos, poses, t, cands, 3, grade)[-1]
    assert spread["p95_m"]["best"] <= spread["p95_m"]["median"] <= spread["p95_m"]["worst"]
    assert greedy.p95_m <= spread["p95_m"]["median"]
    assert greedy.worst5_mean_m < spread["worst5_mean_m"]["median"]
    assert greedy.p95_m <= greedy.worst5_mean_m <= greedy.worst_m
    assert greedy.worst_m < spread["worst_m"]["median"]


def test_random_placement_of_every_candidate_adds_all_their_information():
    poses, t = _route()
    infos, _ = route_information(MapGeometry(_map()), poses)
    cands = candidate_tags(poses, spacing=10.0, offset=3.0)
    step = random_placement(infos, poses, t, cands, 99, GRADES["automotive"],
                            np.random.default_rng(1))
    full = infos + tag_information(poses, cands)[0]
    sigma = [position_sigma(p) for p in filter_route(full, poses, t, GRADES["automotive"])]
    assert step.count == len(cands)
    np.testing.assert_allclose([step.worst_m, step.p95_m], [max(sigma), np.percentile(sigma, 95)],
                               rtol=1e-9)


def test_even_placement_places_as_many_tags_as_asked_up_to_every_candidate():
    poses, t = _route()
    infos, _ = route_information(MapGeometry(_map()), poses)
    cands = candidate_tags(poses, spacing=10.0, offset=3.0)  # 7 rows, 14 candidates
    grade = GRADES["automotive"]
    counts = [even_placement(infos, poses, t, cands, k, grade).count for k in (3, 7, 10, 14, 20)]
    assert counts == [3, 7, 10, 14, 14]
    every = random_placement(infos, poses, t, cands, 99, grade, np.random.default_rng(1))
    assert even_placement(infos, poses, t, cands, 14, grade).worst_m == every.worst_m


def test_a_placed_tag_counts_as_often_as_it_is_detected():
    """A candidate tag is worth the map's own tags' information times the detection rate."""

    poses, t = _route()
    infos, _ = route_information(MapGeometry(_map()), poses)
    cands = candidate_tags(poses, spacing=10.0, offset=3.0)
    grade = GRADES["automotive"]
    half = SensorModel(tag_detection_rate=0.5)
    step = random_placement(infos, poses, t, cands, 99, grade, np.random.default_rng(1), half)
    full = infos + 0.5 * tag_information(poses, cands, None, half)[0]
    sigma = [position_sigma(p) for p in filter_route(full, poses, t, grade)]
    np.testing.assert_allclose(step.worst_m, max(sigma), rtol=1e-9)
    first = greedy_placement(infos, poses, t, cands, 1, grade, half)[1]
    alone = random_placement(infos, poses, t, np.array([first.tag]), 1, grade,
                             np.random.default_rng(0), half)
    np.testing.assert_allclose(first.worst_m, alone.worst_m, rtol=1e-9)


def test_a_start_is_covered_when_a_landmark_comes_into_view_within_the_time_given():
    times = np.arange(8.0)  # one pose a second
    seen = np.array([0, 0, 0, 1, 0, 0, 0, 0], bool)
    np.testing.assert_array_equal(
        starts_covered(seen, times, 2.0), [0, 1, 1, 1, 0, 0, 0, 0]
    )
    np.testing.assert_array_equal(starts_covered(seen, times, 0.0), seen)
    assert not starts_covered(np.zeros(8, bool), times, 100.0).any()


def test_coverage_tags_cover_the_stretch_that_sees_nothing():
    """The straight route sees its one slot only in its first metres; tags chosen for
    coverage make every start see a slot or tag within 2 s, each tag needed."""
    poses, t = _route()
    _, counts = route_information(MapGeometry(_map()), poses)
    seen = (counts["slots"] > 0) | (counts["tags"] > 0)
    assert seen[:2].all() and not seen[10:].any()
    cands = candidate_tags(poses, spacing=5.0, offset=3.0)
    visible = tag_visibility(poses, cands, SensorModel())
    assert visible.shape == (len(cands), len(poses))
    chosen = coverage_placement(seen, t, visible, 50, 2.0)
    with_tags = seen | visible[chosen].any(axis=0)
    before, after = starts_covered(seen, t, 2.0), starts_covered(with_tags, t, 2.0)
    # every start but the last metres, where no candidate stands ahead within view
    assert after[poses[:, 0] <= 70.0].all() and after.sum() > before.sum() + 0.7 * len(t)
    for k in range(len(chosen)):  # every tag adds covered starts
        fewer = seen | visible[chosen[:k] + chosen[k + 1 :]].any(axis=0)
        assert starts_covered(fewer, t, 2.0).sum() < after.sum()
    assert coverage_placement(seen, t, visible, 2, 2.0) == chosen[:2]  # greedy: a prefix
    assert coverage_placement(with_tags, t, visible, 50, 2.0) == []  # nothing left to add


def test_only_candidates_the_mapping_drive_sees_often_enough_are_kept():
    """Candidates face cars driving +x: the same drive sees each, the drive back along it
    sees none, and a drive that stops short sees only the candidates within its camera's
    range."""
    poses, _ = _route()
    cands = candidate_tags(poses, spacing=10.0, offset=3.0)
    sensors = SensorModel(slot_rule="entrance")
    assert seen_often_enough(poses, cands, sensors, 3).all()
    back = poses[::-1].copy()
    back[:, 2] = math.pi
    assert not seen_often_enough(back, cands, sensors, 1).any()
    short = poses[poses[:, 0] <= 30.0]
    kept = seen_often_enough(short, cands, sensors, 3)  # the camera sees 20-25 m ahead
    assert kept[cands[:, 0] <= 30.0].all() and not kept[cands[:, 0] >= 60.0].any()
    counts = tag_visibility(short, cands, sensors).sum(axis=1)
    assert not seen_often_enough(short, cands, sensors, int(counts.max()) + 1).any()
