import math

import numpy as np

from semslam.evaluation.map_metrics import point_segment_distances
from semslam.simulation.topview_samples import (
    PaintVariation,
    random_slot_pose,
    sample_topviews,
    vary_paint,
)
from semslam.simulation.world import make_world
from semslam.types import SlotKind


def _length(m) -> float:
    return float(np.hypot(*(np.asarray(m.b, float) - np.asarray(m.a, float))))


def test_vary_paint_thins_lines_and_cuts_separators_to_stubs() -> None:
    world = make_world("small", 3)
    varied = vary_paint(world, PaintVariation(thin_share=1.0, stub_share=1.0,
                                              stub_length=(0.5, 0.5)), np.random.default_rng(0))
    assert len(varied.markings) == len(world.markings)
    assert all(0.05 <= m.width <= 0.10 for m in varied.markings)
    starts = {(round(float(p.position[0]), 6), round(float(p.position[1]), 6)): p.direction
              for p in world.marking_points}
    cut = 0
    for before, after in zip(world.markings, varied.markings, strict=True):
        np.testing.assert_array_equal(after.a, before.a)
        key = (round(float(before.a[0]), 6), round(float(before.a[1]), 6))
        d = np.asarray(before.b, float) - np.asarray(before.a, float)
        is_separator = key in starts and abs(
            math.remainder(math.atan2(d[1], d[0]) - starts[key], math.tau)) < 1e-6
        if is_separator and _length(before) > 0.5:
            assert math.isclose(_length(after), 0.5, abs_tol=1e-9)
            cut += 1
        else:
            np.testing.assert_array_equal(after.b, before.b)
    assert cut == len(world.marking_points)  # every junction's separator
    # the labels are the junctions, untouched
    assert varied.marking_points == world.marking_points


def test_vary_paint_never_is_the_same_world_and_poses_do_not_move() -> None:
    world = make_world("small", 3)
    assert vary_paint(world, PaintVariation(thin_share=0.0, stub_share=0.0),
                      np.random.default_rng(0)) is world
    plain = list(sample_topviews([5, 6], 2, 9))
    varied = list(sample_topviews([5, 6], 2, 9, paint=PaintVariation(1.0, (0.05, 0.05), 1.0)))
    for a, b in zip(plain, varied, strict=True):
        np.testing.assert_array_equal(a.mTv, b.mTv)
        np.testing.assert_array_equal(a.annotation.points, b.annotation.points)
        if len(a.annotation.points):  # junctions in view: their paint differs
            assert not np.array_equal(a.image, b.image)
    assert sum(len(a.annotation.points) > 0 for a in plain) >= 1


def test_vary_paint_crosses_t_junctions_separators_over_the_entrance_line() -> None:
    world = make_world("small", 3)
    varied = vary_paint(world, PaintVariation(thin_share=0.0, stub_share=0.0, cross_share=1.0,
                                              cross_length=(0.3, 0.3)), np.random.default_rng(0))
    t_starts = {(round(float(p.position[0]), 6), round(float(p.position[1]), 6)): p.direction
                for p in world.marking_points if p.shape == "T"}
    crossed = 0
    for before, after in zip(world.markings, varied.markings, strict=True):
        np.testing.assert_array_equal(after.b, before.b)
        key = (round(float(before.a[0]), 6), round(float(before.a[1]), 6))
        d = np.asarray(before.b, float) - np.asarray(before.a, float)
        heading = math.atan2(d[1], d[0])
        if key in t_starts and abs(math.remainder(heading - t_starts[key], math.tau)) < 1e-6:
            # painted on 0.3 m behind the junction, on the separator's own line
            back = np.asarray(before.a, float) - np.asarray(after.a, float)
            assert math.isclose(float(np.hypot(*back)), 0.3, abs_tol=1e-9)
            assert math.isclose(math.atan2(back[1], back[0]), heading, abs_tol=1e-9)
            crossed += 1
        else:
            np.testing.assert_array_equal(after.a, before.a)
    assert crossed == len(t_starts) > 0  # every T junction, no L junction
    assert varied.marking_points == world.marking_points


def test_vary_paint_wears_the_paint_faint_towards_grey() -> None:
    world = make_world("small", 3)
    varied = vary_paint(world, PaintVariation(thin_share=0.0, stub_share=0.0, faint_share=1.0,
                                              faint_mix=(0.5, 0.5)), np.random.default_rng(0))
    assert varied.line_colour == tuple(int(round((c + 128) / 2)) for c in world.line_colour)
    assert varied.line_colour != world.line_colour
    assert varied.markings == world.markings  # only the colour, the lines where they were
    assert varied.marking_points == world.marking_points


def test_vary_paint_wears_separators_away_from_their_junction() -> None:
    world = make_world("small", 3)
    varied = vary_paint(world, PaintVariation(thin_share=0.0, stub_share=0.0, worn_share=1.0,
                                              worn_length=(0.8, 0.8)), np.random.default_rng(0))
    starts = {(round(float(p.position[0]), 6), round(float(p.position[1]), 6)): p.direction
              for p in world.marking_points}
    kept = iter(varied.markings)
    worn = 0
    for before in world.markings:
        key = (round(float(before.a[0]), 6), round(float(before.a[1]), 6))
        d = np.asarray(before.b, float) - np.asarray(before.a, float)
        is_separator = key in starts and abs(
            math.remainder(math.atan2(d[1], d[0]) - starts[key], math.tau)) < 1e-6
        if is_separator and _length(before) <= 0.8:
            continue  # worn away whole
        after = next(kept)
        np.testing.assert_array_equal(after.b, before.b)
        if is_separator:  # its first 0.8 m gone, the rest where it was
            assert math.isclose(_length(before) - _length(after), 0.8, abs_tol=1e-9)
            worn += 1
        else:
            np.testing.assert_array_equal(after.a, before.a)
    assert next(kept, None) is None
    assert worn > 0
    assert varied.marking_points == world.marking_points  # the labels stay


def test_vary_paint_dashes_entrance_lines_across_junctions_joined_by_faint_yellow() -> None:
    world = make_world("small", 3)
    varied = vary_paint(world, PaintVariation(thin_share=0.0, stub_share=0.0, dash_share=1.0,
                                              dash_length=(1.0, 1.0), dash_shift=0.0,
                                              gap_share=1.0, gap_faint=(0.5, 0.5)),
                        np.random.default_rng(0))
    assert varied.marking_points == world.marking_points  # the labels stay
    assert len(varied.marking_colours) == len(varied.markings) > len(world.markings)
    yellow = tuple(int(round((c + 128) / 2)) for c in (40, 200, 230))
    assert set(varied.marking_colours) == {None, yellow}
    junctions = np.array([p.position for p in world.marking_points], float)
    for m, colour in zip(varied.markings, varied.marking_colours, strict=True):
        if colour == yellow:  # a gap: no junction under it
            a, b = np.asarray(m.a, float)[None], np.asarray(m.b, float)[None]
            assert point_segment_distances(junctions, a, b).min() > 0.05
    # white dashes 1 m long centred on junctions, for most of them (not those at a line's end)
    dashes = [m for m, c in zip(varied.markings, varied.marking_colours, strict=True)
              if c is None and _length(m) <= 1.0 + 1e-9
              and min(float(np.hypot(*(0.5 * (np.asarray(m.a) + np.asarray(m.b)) - q)))
                      for q in junctions) < 1e-6]
    assert len(dashes) >= len(world.marking_points) // 2
    # without gaps the lines between the dashes are bare: fewer markings, none coloured
    bare = vary_paint(world, PaintVariation(thin_share=0.0, stub_share=0.0, dash_share=1.0,
                                            gap_share=0.0), np.random.default_rng(0))
    assert bare.marking_colours == ()
    assert len(bare.markings) < len(varied.markings)


def test_the_renderer_paints_a_marking_in_its_own_colour() -> None:
    from dataclasses import replace

    from semslam.simulation.render_topview import TopviewRenderer

    world = make_world("small", 3)
    pose = random_slot_pose(world, np.random.default_rng(1))
    plain, _ = TopviewRenderer(world, jpeg=False).render(pose, 5)
    own = replace(world, marking_colours=(None,) * len(world.markings))
    same, _ = TopviewRenderer(own, jpeg=False).render(pose, 5)
    np.testing.assert_array_equal(same, plain)
    red = replace(world, marking_colours=((0, 0, 255),) * len(world.markings))
    other, _ = TopviewRenderer(red, jpeg=False).render(pose, 5)
    changed = np.any(other != plain, axis=2)
    assert changed.any()
    # the changed paint is redder than it was
    assert (other[changed][:, 2].astype(int) - other[changed][:, 0]).mean() > \
        (plain[changed][:, 2].astype(int) - plain[changed][:, 0]).mean()


def test_a_slot_pose_parks_into_a_free_slot_along_its_depth() -> None:
    world = make_world("garage", 12)
    rng = np.random.default_rng(4)
    cars = np.array([c.centre for c in world.parked_cars])
    for _ in range(20):
        x, y, yaw = random_slot_pose(world, rng)
        inside = [s for s in world.slots
                  if _slot_depth_coordinate(s, (x, y)) is not None]
        assert len(inside) == 1  # within one slot's width, from 1.5 m before its entrance
        slot = inside[0]
        assert slot.kind != SlotKind.PARALLEL
        c = np.asarray(slot.corners, float)
        assert not ((cars >= c.min(axis=0)) & (cars <= c.max(axis=0))).all(axis=1).any()
        depth = 0.5 * (c[2] + c[3]) - 0.5 * (c[0] + c[1])
        off = math.remainder(yaw - math.atan2(depth[1], depth[0]), math.pi)
        assert abs(off) <= math.radians(8.0) + 1e-9  # nose in or reversing in


def _slot_depth_coordinate(slot, p) -> float | None:
    """How far ``p`` lies into ``slot`` along its depth, if it lies within its width (less
    the sampler's 0.3 m) and between 1.5 m before the entrance and the rear."""
    c = np.asarray(slot.corners, float)
    entrance = 0.5 * (c[0] + c[1])
    depth = 0.5 * (c[2] + c[3]) - entrance
    u = depth / np.hypot(*depth)
    d = np.asarray(p, float) - entrance
    along, across = float(d @ u), float(d @ np.array([-u[1], u[0]]))
    inside = -1.5 - 1e-9 <= along <= np.hypot(*depth) and abs(across) <= 0.3 + 1e-9
    return along if inside else None


def test_slot_share_takes_views_in_slots_and_leaves_the_aisle_views_alone() -> None:
    before = list(sample_topviews([5, 6], 2, 9))
    assert all(np.array_equal(a.mTv, b.mTv) and np.array_equal(a.image, b.image)
               for a, b in zip(before, sample_topviews([5, 6], 2, 9, slot_share=0.0),
                               strict=True))
    in_slots = list(sample_topviews([5, 6], 2, 9, slot_share=1.0))
    for sample in in_slots:
        world = make_world(sample.preset, sample.world_seed)
        assert any(_slot_depth_coordinate(s, sample.mTv[:2]) is not None for s in world.slots)
