"""Merging map-frame marking observations into the map's line markings."""

import math

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from semslam.config import SimulationConfig
from semslam.geometry import inverse_transform_points, transform_points
from semslam.mapping import markings
from semslam.mapping.markings import _Rule, merge_marking_observations
from semslam.simulation.scenario import simulate_drive

NOISE = 0.03  # m, the simulator's marking end-point noise


def _pieces(a, b, rng, n=30, half=5.0, noise=NOISE, t_range=None):
    """Views of the painted line a-b as a car passing along it sees them: each the part
    within ``half`` of a car position, clipped, with end-point noise. (n, 2, 2)"""
    a, b = np.asarray(a, float), np.asarray(b, float)
    length = float(np.linalg.norm(b - a))
    lo, hi = t_range if t_range is not None else (-half + 0.5, length + half - 0.5)
    out = []
    for s in np.linspace(lo, hi, n):
        t0, t1 = max(0.0, s - half), min(length, s + half)
        if t1 - t0 < 0.4:
            continue
        ends = a + np.outer([t0, t1], b - a) / length
        out.append(ends + rng.normal(0.0, noise, (2, 2)))
    return np.array(out)


def _merge(segments, rng, width=0.15, **kwargs):
    n = len(segments)
    return merge_marking_observations(
        segments, np.full(n, width), rng.uniform(0.5, 1.0, n), **kwargs
    )


def _end_error(marking, a, b):
    """Largest end-point error of a merged marking against a-b, either orientation."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    same = max(np.linalg.norm(marking.a - a), np.linalg.norm(marking.b - b))
    swapped = max(np.linalg.norm(marking.a - b), np.linalg.norm(marking.b - a))
    return min(same, swapped)


def _point_segment_distance(p, a, b):
    d = b - a
    t = np.clip((p - a) @ d / (d @ d), 0.0, 1.0)
    return np.linalg.norm(p - (a + np.outer(t, d)), axis=1)


# --------------------------------------------------------------------------- inputs


def test_no_observations_give_no_markings():
    assert merge_marking_observations(np.zeros((0, 2, 2)), np.zeros(0), np.zeros(0)) == ()
    assert merge_marking_observations([], [], []) == ()


@pytest.mark.parametrize(
    ("segments", "widths", "confidences"),
    [
        (np.zeros((3, 2)), np.zeros(3), np.zeros(3)),
        (np.zeros((3, 2, 3)), np.zeros(3), np.zeros(3)),
        (np.zeros((3, 2, 2)), np.zeros(2), np.zeros(3)),
        (np.zeros((3, 2, 2)), np.zeros(3), np.zeros((3, 1))),
        (np.full((3, 2, 2), np.nan), np.zeros(3), np.zeros(3)),
    ],
)
def test_bad_shapes_are_refused(segments, widths, confidences):
    with pytest.raises(ValueError, match="segments|widths|confidences"):
        merge_marking_observations(segments, widths, confidences)


def test_low_confidence_observations_are_ignored():
    rng = np.random.default_rng(0)
    segs = _pieces((0, 0), (8, 0), rng)
    conf = np.full(len(segs), 0.2)
    assert merge_marking_observations(segs, np.full(len(segs), 0.1), conf) == ()
    assert len(merge_marking_observations(segs, np.full(len(segs), 0.1), conf + 0.5)) == 1


# --------------------------------------------------------------------------- geometry


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_noisy_clipped_pieces_of_one_line_become_one_marking(seed):
    rng = np.random.default_rng(seed)
    a, b = np.array([2.0, 1.0]), np.array([14.0, 4.5])
    segs = _pieces(a, b, rng, n=30)
    merged = _merge(segs, rng, width=0.12)
    assert len(merged) == 1
    assert _end_error(merged[0], a, b) < 0.05
    assert merged[0].width == pytest.approx(0.12)


def test_parallel_lines_30_cm_apart_stay_two():
    rng = np.random.default_rng(4)
    lines = [((0.0, 0.0), (10.0, 0.0)), ((0.0, 0.3), (10.0, 0.3))]
    segs = np.concatenate([_pieces(a, b, rng) for a, b in lines])
    merged = _merge(segs, rng)
    assert len(merged) == 2
    for m, (a, b) in zip(merged, lines, strict=True):
        assert _end_error(m, a, b) < 0.05


def test_t_junction_stays_two_lines():
    rng = np.random.default_rng(5)
    lines = [((0.0, 0.0), (10.0, 0.0)), ((5.0, 0.0), (5.0, 5.0))]
    segs = np.concatenate([_pieces(a, b, rng) for a, b in lines])
    merged = _merge(segs, rng)
    assert len(merged) == 2
    for a, b in lines:
        assert min(_end_error(m, a, b) for m in merged) < 0.05


def test_a_single_false_segment_is_dropped():
    rng = np.random.default_rng(6)
    false = np.array([[[3.0, 2.0], [4.5, 3.1]]])
    assert _merge(false, rng) == ()
    segs = np.concatenate([_pieces((0, 0), (10, 0), rng), false])
    merged = _merge(segs, rng)
    assert len(merged) == 1
    assert _end_error(merged[0], (0, 0), (10, 0)) < 0.05


def test_a_line_seen_in_pieces_with_a_30_cm_gap_is_one_line():
    rng = np.random.default_rng(7)
    # a hole 0.3 m long (a worn patch, a stain): no view sees across it
    left = _pieces((0, 0), (4.85, 0), rng, n=15)
    right = _pieces((5.15, 0), (10, 0), rng, n=15)
    merged = _merge(np.concatenate([left, right]), rng)
    assert len(merged) == 1
    assert _end_error(merged[0], (0, 0), (10, 0)) < 0.05


def test_a_false_segment_chaining_two_collinear_stubs_does_not_join_them():
    rng = np.random.default_rng(8)
    stubs = [((0.0, 0.0), (0.9, 0.0)), ((2.4, 0.0), (3.3, 0.0))]
    segs = [_pieces(a, b, rng, n=20, noise=0.01) for a, b in stubs]
    bridge = np.array([[[0.5, 0.01], [2.8, -0.01]]])
    merged = _merge(np.concatenate([*segs, bridge]), rng)
    assert len(merged) == 2
    for m, (a, b) in zip(merged, stubs, strict=True):
        assert _end_error(m, a, b) < 0.05


def test_a_collinear_false_segment_beyond_a_hole_does_not_stretch_the_line():
    rng = np.random.default_rng(11)
    segs = _pieces((0, 0), (10, 0), rng)
    beyond = np.array([[[10.3, 0.01], [12.0, -0.02]]])  # joins (gap 0.3 m), seen once
    merged = _merge(np.concatenate([segs, beyond]), rng)
    assert len(merged) == 1
    assert _end_error(merged[0], (0, 0), (10, 0)) < 0.05


def test_output_is_sorted_and_independent_of_input_order():
    rng = np.random.default_rng(9)
    lines = [((10.0, 0.0), (10.0, 5.0)), ((0.0, 0.0), (8.0, 0.0)), ((3.0, 6.0), (0.0, 2.0))]
    segs = np.concatenate([_pieces(a, b, rng) for a, b in lines])
    n = len(segs)
    widths, conf = np.full(n, 0.1), rng.uniform(0.5, 1.0, n)
    first = merge_marking_observations(segs, widths, conf)
    perm = rng.permutation(n)
    flipped = segs[perm][:, ::-1]  # other order, other end first
    second = merge_marking_observations(flipped, widths[perm], conf[perm])
    assert len(first) == len(second) == 3
    starts = [tuple(m.a) for m in first]
    assert starts == sorted(starts)
    for m1, m2 in zip(first, second, strict=True):
        assert np.allclose(m1.a, m2.a, atol=1e-9) and np.allclose(m1.b, m2.b, atol=1e-9)
        assert m1.a[0] <= m1.b[0]


@pytest.mark.parametrize("window", [1, 3])
def test_grid_neighbours_give_the_clusters_of_all_pairs(monkeypatch, window):
    """The grid search finds exactly the single-link components of the rule over all pairs
    (with a first-pass window of 1 the second pass has links to add)."""
    monkeypatch.setattr(markings, "_WINDOW", window)
    rng = np.random.default_rng(10)
    n = 600
    # segments near a few lines, with offsets, angles and gaps around the tolerances
    base = rng.integers(0, 6, n)
    angle = base * 0.5 + rng.normal(0.0, math.radians(4.0), n)
    u = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    normal = np.stack([-u[:, 1], u[:, 0]], axis=1)
    centre = rng.uniform(0.0, 12.0, (n, 2)) * 0.2 + normal * rng.normal(0.0, 0.1, (n, 1))
    centre += base[:, None] * 3.0
    along = rng.uniform(-4.0, 4.0, (n, 1))
    half = rng.uniform(0.2, 3.0, (n, 1))
    segs = np.stack([centre + (along - half) * u, centre + (along + half) * u], axis=1)
    rule = _Rule(segs, math.radians(5.0), 0.1, 0.5)
    grid = rule.components()
    i, j = np.triu_indices(n, 1)
    ok = rule.compatible(i, j)
    brute = connected_components(coo_matrix((np.ones(ok.sum()), (i[ok], j[ok])), shape=(n, n)))[1]
    assert 20 < len(set(brute.tolist())) < n - 20  # a mix of joins and splits
    # same partition: labels map one to one
    pairs = set(zip(grid.tolist(), brute.tolist(), strict=True))
    assert len(pairs) == len(set(grid.tolist())) == len(set(brute.tolist()))


# --------------------------------------------------------------------------- simulated drive


@pytest.fixture(scope="module")
def small_drive():
    return simulate_drive("small", 0, 0, SimulationConfig())


def _seen_pieces(marking, poses, half, min_visible, gap, step=0.02):
    """Parts (t0, t1) along a world marking (m from its ``a``) that some frame's top view
    showed with at least ``min_visible`` of the marking inside it, holes up to ``gap`` joined."""
    length = float(np.linalg.norm(marking.b - marking.a))
    t = np.arange(0.0, length + step / 2, step)
    pts = marking.a + np.outer(t, marking.b - marking.a) / length
    near = np.linalg.norm(poses[:, :2] - pts.mean(axis=0), axis=1) < length / 2 + 2 * half
    seen = np.zeros(t.size, dtype=bool)
    for pose in poses[near]:
        inside = np.all(np.abs(inverse_transform_points(pose, pts)) <= half, axis=1)
        if inside.sum() * step >= min_visible:
            seen |= inside
    pieces: list[list[float]] = []
    for k in np.flatnonzero(seen):
        if pieces and t[k] - pieces[-1][1] <= gap:
            pieces[-1][1] = t[k]
        else:
            pieces.append([t[k], t[k]])
    return [tuple(p) for p in pieces]


@pytest.mark.parametrize("kind", ["exact", "noisy"])
def test_observations_of_a_drive_merge_into_the_world_markings(small_drive, kind):
    """Exact observations placed by the true poses, and noisy ones (misses, false segments,
    3 cm end points) too: the merged lines are the world's markings as far as seen."""
    sim = small_drive
    poses = sim.frame_poses
    frames = sim.exact if kind == "exact" else sim.noisy
    obs = [(pose, m) for pose, frame in zip(poses, frames, strict=True) for m in frame.markings]
    segs = np.array([transform_points(pose, np.array([m.vA, m.vB])) for pose, m in obs])
    widths = np.array([m.width for _, m in obs])
    merged = merge_marking_observations(segs, widths, np.array([m.confidence for _, m in obs]))
    world = sim.world.markings
    assert len(merged) > 20

    # every merged line is real: all along it within 5 cm of some world marking
    for line in merged:
        pts = line.a + np.linspace(0.0, 1.0, 40)[:, None] * (line.b - line.a)
        d = np.min([_point_segment_distance(pts, m.a, m.b) for m in world], axis=0)
        assert d.max() < 0.05
        assert line.width == pytest.approx(world[0].width, abs=1e-9 if kind == "exact" else 0.02)

    # every world marking over 1 m passed within 5 m: what the drive saw of it is a merged line
    half = sim.rig.topview.half_extent_m
    min_visible = SimulationConfig().observation_noise.marking_min_length
    checked = 0
    for m in world:
        length = float(np.linalg.norm(m.b - m.a))
        if length <= 1.0:
            continue
        passed = np.min(_point_segment_distance(poses[:, :2], m.a, m.b))
        if passed > 5.0:
            continue
        u = (m.b - m.a) / length
        for t0, t1 in _seen_pieces(m, poses, half, min_visible, gap=0.5):
            if t1 - t0 < 0.6:
                continue  # too short for a line of min_length after the end tolerances
            checked += 1
            found = False
            for line in merged:
                v = (line.b - line.a) / np.linalg.norm(line.b - line.a)
                if abs(float(v @ u)) < math.cos(math.radians(1.0)):
                    continue
                rel = np.array([line.a - m.a, line.b - m.a])
                if np.max(np.abs(rel[:, 0] * u[1] - rel[:, 1] * u[0])) > 0.05:
                    continue
                s = np.sort(rel @ u)
                s0, s1 = max(s[0], 0.0), min(s[1], length)  # the part on this marking
                found = found or (abs(s0 - t0) < 0.1 and abs(s1 - t1) < 0.1)
            assert found, f"world marking {m.a} -> {m.b}, seen {t0:.2f}..{t1:.2f} m: no line"
    assert checked > 30


def test_robust_extent_follows_the_pile_of_ends_not_a_stray_one() -> None:
    rng = np.random.default_rng(3)
    # clipped views end anywhere inside; every unclipped one ends at 0 or 4 m (noise 3 cm)
    inner = rng.uniform(0.5, 3.5, 40)
    ends = np.concatenate([rng.normal(0.0, NOISE, 20), rng.normal(4.0, NOISE, 20)])
    t = np.concatenate([inner, ends, [-0.9]])  # and one stray observation 0.9 m beyond
    t0, t1 = markings.robust_extent(t)
    assert abs(t0) < 0.03 and abs(t1 - 4.0) < 0.03
    assert t0 > t.min() + 0.8  # a plain minimum would follow the stray end
