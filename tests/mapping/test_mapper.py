"""The mapper on small simulated drives where the right answer is known."""

import dataclasses
import math

import numpy as np
import pytest

from semslam.config import MappingConfig, SimulationConfig
from semslam.evaluation.map_metrics import evaluate_map
from semslam.geometry import rotation_variance
from semslam.mapping.mapper import Mapper, SightingStatus
from semslam.simulation.scenario import simulate_drive
from semslam.types import FrameObservations


@pytest.fixture(scope="module")
def small():
    sim_cfg = SimulationConfig()
    sim_cfg = sim_cfg.model_copy(
        update={"drive": sim_cfg.drive.model_copy(update={"max_duration": 40.0})}
    )
    return simulate_drive("small", 2, 0, sim_cfg)


def _map(sim, frames, **overrides):
    cfg = MappingConfig(**overrides)
    rec = sim.record
    mapper = Mapper(cfg, sim.frame_poses[0], rec.t, rec.odo_speed, rec.odo_yaw_rate)
    for frame in frames:
        mapper.add_frame(frame)
    return mapper.finish()


def _seen_truth(sim):
    """The true map restricted to the slots the drive saw (exactly)."""
    seen = {o.label for f in sim.exact for o in f.slots}
    world = sim.world.to_map()
    return dataclasses.replace(world, slots=tuple(s for s in world.slots if s.label in seen))


def test_exact_observations_give_an_accurate_complete_map(small):
    result = _map(small, small.exact)
    m = evaluate_map(result.map, _seen_truth(small))
    assert m.slots_matched == m.slots_true
    assert m.duplicate_slots == 0 and m.false_slots == 0 and m.wrong_merges == 0
    assert m.corner_rmse_m < 0.03
    assert m.id_accuracy == 1.0
    assert result.statistics["odometry_scale"] == pytest.approx(1.0, abs=0.03)


def test_noisy_observations_robust_map_beats_odometry_only(small):
    robust = evaluate_map(_map(small, small.noisy).map, _seen_truth(small))
    dead = evaluate_map(_map(small, small.noisy, optimizer="none").map, _seen_truth(small))
    assert robust.duplicate_slots == 0 and robust.wrong_merges == 0
    assert robust.false_slots == 0
    assert robust.id_accuracy >= 0.95
    assert robust.corner_rmse_m < 0.06
    assert robust.corner_rmse_m < dead.corner_rmse_m


def test_a_graph_whose_marginals_gtsam_refuses_still_exports_covariances(small, monkeypatch):
    """When gtsam's Marginals refuse the whole graph (`large` world 3 did), every slot and tag
    takes the fallback of a refused clique, and the count says so; the map never carries
    zero covariances as if it were exact."""
    from semslam.mapping.graph import Graph

    monkeypatch.setattr(Graph, "marginals", lambda self: None)
    result = _map(small, small.noisy)
    slots, tags = result.map.slots, result.map.tags
    assert slots and tags
    for slot in slots:
        assert all(np.linalg.eigvalsh(c).min() > 0 for c in slot.corner_covariances)
    assert any(np.trace(tag.covariance) > 0 for tag in tags)  # a tag seen once has no spread
    assert result.statistics["marginal_fallbacks"] >= len(slots) + len(tags)


def test_a_landmark_whose_own_marginal_is_refused_is_as_uncertain_as_where_it_was_seen(
    small, monkeypatch
):
    """A slot or painted line whose marginal gtsam refuses at every tier takes its sightings'
    noise on the position marginal of the keyframe that saw it nearest: about what the graph
    gives when it answers (the noise alone is several times surer on any drive with drift)."""
    import gtsam

    import semslam.mapping.mapper as mapper_module

    own = _map(small, small.noisy)
    answer = mapper_module._marginal

    def refuse_landmarks(marginals, keys):
        key = keys[0] if isinstance(keys, list) else keys
        if chr(gtsam.Symbol(key).chr()).upper() in "CL":  # slot corners, painted lines
            return None
        return answer(marginals, keys)

    monkeypatch.setattr(mapper_module, "_marginal", refuse_landmarks)
    refused = _map(small, small.noisy)
    assert refused.statistics["marginal_fallbacks"] >= len(own.map.slots) + len(
        own.map.markings)
    ratios = [np.trace(b.corner_covariances.mean(axis=0)) / np.trace(
        a.corner_covariances.mean(axis=0)) for a, b in zip(own.map.slots, refused.map.slots,
                                                           strict=True)]
    assert min(ratios) > 0.8 and max(ratios) < 4.0
    sigmas = [b.sigma / a.sigma for a, b in zip(own.map.markings, refused.map.markings,
                                               strict=True)]
    assert min(sigmas) > 0.6 and max(sigmas) < 1.5


def test_each_slot_carries_the_heading_variance_of_its_corners(small):
    """The joint marginal of a slot's four corners gives its orientation's variance; the
    slots' orientation errors against the truth agree with it."""
    result = _map(small, small.noisy)
    truth = {s.label: s for s in _seen_truth(small).slots}
    normalised, independent = [], []
    for slot in result.map.slots:
        assert slot.heading_variance is not None and slot.heading_variance > 0
        independent.append(rotation_variance(slot.corners, slot.corner_covariances))
        true = truth.get(slot.label)
        if true is not None:
            a = slot.corners - slot.corners.mean(axis=0)
            b = true.corners - true.corners.mean(axis=0)
            H = b.T @ a
            error = math.atan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1])
            normalised.append(error**2 / slot.heading_variance)
    assert len(normalised) > 30
    assert 0.3 < np.mean(normalised) < 2.0  # 1 = consistent
    # the corners' errors are correlated (measured together): taken as independent, they
    # would claim several times the heading uncertainty
    headings = [s.heading_variance for s in result.map.slots]
    assert np.mean(independent) > 2 * np.mean(headings)


def test_a_confidently_wrong_id_ends_on_the_null_hypothesis(small):
    # every frame also reports a ghost of a real slot 2.5 m away, labelled (with high
    # confidence) as the slot next to it: a wrong ID and a wrong place at once
    frames = []
    for frame in small.exact:
        ghosts = []
        for obs in frame.slots[:1]:
            along = obs.vCorners[1] - obs.vCorners[0]
            ghosts.append(
                dataclasses.replace(obs, vCorners=obs.vCorners + along * 0.5, label_confidence=0.99)
            )
        frames.append(
            FrameObservations(frame.t, frame.slots + tuple(ghosts), frame.tags, frame.markings)
        )
    result = _map(small, frames)
    m = evaluate_map(result.map, _seen_truth(small))
    assert m.false_slots == 0 and m.duplicate_slots == 0 and m.wrong_merges == 0
    assert m.corner_rmse_m < 0.05
    ghost_fates = [s.status for s in result.sightings if s.observation.label_confidence == 0.99]
    assert ghost_fates.count(SightingStatus.NULL) + ghost_fates.count(SightingStatus.POOLED) == len(
        ghost_fates
    )


def test_plain_least_squares_is_bent_by_the_same_ghosts(small):
    frames = [
        FrameObservations(
            f.t,
            f.slots
            + tuple(
                dataclasses.replace(o, vCorners=o.vCorners + (o.vCorners[1] - o.vCorners[0]) * 0.35)
                for o in f.slots[:1]
            ),
            f.tags,
            f.markings,
        )
        for f in small.exact
    ]
    robust = evaluate_map(_map(small, frames).map, _seen_truth(small))
    plain = evaluate_map(_map(small, frames, robust="none").map, _seen_truth(small))
    assert plain.corner_rmse_m > 2 * robust.corner_rmse_m


def test_overlap_ratio_separates_neighbours_from_ghosts():
    from semslam.mapping.landmarks import overlap_ratio

    slot = np.array([[0, 0], [2.5, 0], [2.5, 5], [0, 5]], dtype=float)
    assert overlap_ratio(slot, slot) == pytest.approx(1.0)
    assert overlap_ratio(slot, slot + [2.5, 0]) == pytest.approx(0.0, abs=1e-6)  # neighbour
    assert overlap_ratio(slot, slot + [1.25, 0]) == pytest.approx(0.5, abs=1e-3)  # ghost


def _distance_to_segments(points, markings):
    """Distance of each point (N, 2) to the nearest of the segments."""
    a = np.array([m.a for m in markings])
    b = np.array([m.b for m in markings])
    ab = b - a
    t = np.clip(np.einsum("nsk,sk->ns", points[:, None] - a, ab) / (ab * ab).sum(1), 0, 1)
    closest = a + t[..., None] * ab
    return np.linalg.norm(points[:, None] - closest, axis=-1).min(axis=1)


@pytest.mark.parametrize("observations", ["exact", "noisy"])
def test_painted_lines_are_mapped_where_they_are(small, observations):
    result = _map(small, getattr(small, observations))
    mapped = result.map.markings
    assert len(mapped) >= 20
    ends = np.array([[m.a, m.b] for m in mapped]).reshape(-1, 2)
    off = _distance_to_segments(ends, small.world.to_map().markings)
    assert np.percentile(off, 95) < (0.05 if observations == "exact" else 0.10)
    assert np.median([np.linalg.norm(m.b - m.a) for m in mapped]) > 0.5


def test_odometry_only_maps_lines_by_merging_placed_detections(small):
    """Without the graph the lines sit where dead reckoning put them: near the paint
    (0.22 m at the 95th percentile on this drive, its odometry drift), merged into few."""
    result = _map(small, small.exact, optimizer="none")
    mapped = result.map.markings
    assert 20 <= len(mapped) <= 40
    ends = np.array([[m.a, m.b] for m in mapped]).reshape(-1, 2)
    off = _distance_to_segments(ends, small.world.to_map().markings)
    assert np.median(off) < 0.05 and np.percentile(off, 95) < 0.4


def test_a_tag_seen_with_another_size_is_reported_not_used(small):
    seen = [i for i, f in enumerate(small.exact) if f.tags]
    half = seen[len(seen) // 2]  # from here on every tag reports 1.5 times its size
    frames = [
        FrameObservations(f.t, f.slots, tuple(dataclasses.replace(t, size=t.size * 1.5)
                                              for t in f.tags) if i > half else f.tags, f.markings)
        for i, f in enumerate(small.exact)
    ]
    result = _map(small, frames)
    assert result.statistics["tag_size_mismatches"] > 0
    assert all(t.size == small.world.to_map().tags[0].size for t in result.map.tags)


def test_one_tag_id_at_two_places_keeps_the_first_and_reports_the_other(small):
    """Tags are trusted by ID (no null): the same ID printed twice, 9 m apart, used to drag
    the map (on another drive: every slot lost, odometry scale -0.1). Sightings placing the
    tag beyond ``tag_conflict_distance`` from its estimate are reported and left out."""
    frames = [
        FrameObservations(f.t, f.slots, tuple(dataclasses.replace(t, tag_id=284)
                                              if t.tag_id == 545 else t for t in f.tags),
                          f.markings)
        for f in small.noisy
    ]
    truth = {t.tag_id: t.mTt for t in small.world.to_map().tags}
    kept = _map(small, frames)
    assert kept.statistics["tag_conflicts"] > 10
    (tag,) = kept.map.tags
    assert min(np.hypot(*(tag.mTt[:2] - truth[i][:2])) for i in (284, 545)) < 0.2
    assert abs(kept.statistics["odometry_scale"] - 1.0) < 0.02
    fused = _map(small, frames, tag_conflict_distance=10.0)  # the check off at 9 m apart
    assert fused.statistics["tag_conflicts"] == 0
    (wrong,) = fused.map.tags  # pulled between the two places
    assert min(np.hypot(*(wrong.mTt[:2] - truth[i][:2])) for i in (284, 545)) > 1.0
    assert evaluate_map(kept.map, _seen_truth(small)).corner_rmse_m < 0.06


def test_a_tag_sighting_sure_on_one_axis_only_still_exports_a_readable_graph(small):
    """A sighting's covariance may be semi-definite (variances 1e6, 1e-9, 1): with only an
    absolute 1e-8 added its graph edge had condition number 9e13, and ``semslam map`` ended
    with the g2o export refusing its own output (found by semantic fuzzing). The edge now gets
    a floor relative to its largest variance; the slots are mapped as before."""
    from semslam.io.g2o import format_g2o, parse_g2o
    from semslam.mapping.export import to_pose_graph

    lopsided = np.diag([1e6, 1e-9, 1.0])
    frames = [
        FrameObservations(f.t, f.slots, tuple(dataclasses.replace(t, covariance=lopsided)
                                              for t in f.tags), f.markings)
        for f in small.exact
    ]
    result = _map(small, frames)
    assert result.map.tags
    graph = parse_g2o(format_g2o(to_pose_graph(result)))
    assert len(graph.edges) > 0
    assert evaluate_map(result.map, _seen_truth(small)).corner_rmse_m < 0.06


def test_an_unsolvable_graph_is_a_one_line_mapping_error():
    import gtsam

    from semslam.errors import MappingError
    from semslam.mapping.graph import Graph

    X = gtsam.symbol_shorthand.X
    graph = Graph()
    graph.add_pose(X(0), np.zeros(3))
    graph.add_pose(X(1), np.array([1.0, 0.0, 0.0]))  # no prior: the whole graph floats
    graph.add_factor(gtsam.BetweenFactorPose2(
        X(0), X(1), gtsam.Pose2(1, 0, 0), gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    with pytest.raises(MappingError) as error:
        graph.update()
    assert "could not be solved" in str(error.value) and "\n" not in str(error.value)


def test_a_heading_jump_is_closed_by_agreeing_ids():
    """An unmodelled 6 deg heading jump half way: the revisited rows come back metres off,
    beyond the association gates. Without ID loop closures they are mapped again (false
    slots); with them the second pass lands on the first."""
    sim = simulate_drive("small", 2, 0, SimulationConfig())
    rec = sim.record
    rate = np.array(rec.odo_yaw_rate, dtype=float)
    i0 = int(np.searchsorted(rec.t, 0.45 * rec.t[-1]))
    rate[i0 : i0 + 50] += np.radians(6.0) / (50 * (rec.t[1] - rec.t[0]))
    results = {}
    for radius in (30.0, 0.0):
        mapper = Mapper(
            MappingConfig(loop_closure_radius=radius), sim.frame_poses[0], rec.t, rec.odo_speed,
            rate,
        )
        for frame in sim.noisy:
            mapper.add_frame(frame)
        result = mapper.finish()
        results[radius] = (result, evaluate_map(result.map, sim.world.to_map()))
    closed, metrics = results[30.0]
    assert closed.statistics["loop_closures_by_id"] >= 1
    assert metrics.false_slots == 0 and metrics.duplicate_slots == 0 and metrics.wrong_merges == 0
    assert results[0.0][1].false_slots > 0


def test_a_line_detection_is_weighted_by_the_sigma_it_declares():
    from semslam.types import MarkingObservation

    t = np.array([0.0, 1.0])
    mapper = Mapper(MappingConfig(marking_sigma=0.05), np.zeros(3), t, np.ones(2), np.zeros(2))
    a, b = np.array([1.0, 1.0]), np.array([3.0, 1.0])
    assert mapper._line_sigma(MarkingObservation(a, b, 0.15, 1.0)) == pytest.approx(0.05)
    assert mapper._line_sigma(MarkingObservation(a, b, 0.15, 1.0, 0.2)) == pytest.approx(0.2)
    assert mapper._line_sigma(MarkingObservation(a, b, 0.15, 0.25, 0.2)) == pytest.approx(0.4)



def test_mapped_lines_carry_the_uncertainty_of_their_position(small):
    """Each graph line exports the 1-sigma of its position across itself (from its
    marginal); its end points' distances from the true lines are of that size (0.91 times
    it here)."""
    mapped = _map(small, small.noisy).map.markings
    sigma = np.array([m.sigma for m in mapped])
    assert np.all(sigma > 0.0) and np.all(sigma < 0.2)
    ends = np.array([[m.a, m.b] for m in mapped]).reshape(-1, 2)
    off = _distance_to_segments(ends, small.world.to_map().markings)
    assert 0.5 < np.sqrt(np.mean(off**2) / np.mean(sigma**2)) < 2.0
    # and at its two ends: the mean along the segment of (1 - t)^2 C_aa + 2 t (1 - t) C_ab
    # + t^2 C_bb, (C_aa + C_ab + C_bb) / 3, is sigma squared
    for m in mapped:
        C = m.across_covariance
        assert C.shape == (2, 2)
        assert (C[0, 0] + C[0, 1] + C[1, 1]) / 3.0 == pytest.approx(m.sigma**2, rel=1e-9)
    off_a, off_b = _distance_to_segments(ends[0::2], small.world.to_map().markings), \
        _distance_to_segments(ends[1::2], small.world.to_map().markings)
    var_a = np.array([m.across_covariance[0, 0] for m in mapped])
    var_b = np.array([m.across_covariance[1, 1] for m in mapped])
    assert 0.5 < np.sqrt(np.mean(np.r_[off_a, off_b] ** 2) / np.mean(np.r_[var_a, var_b])) < 2.0
    dead = _map(small, small.noisy, optimizer="none").map.markings
    assert all(m.sigma is None and m.across_covariance is None for m in dead)


@pytest.mark.parametrize("optimizer", ["none", "isam2"])
def test_a_tag_facing_back_across_pi_gets_a_small_yaw_variance(optimizer):
    """Sightings 0.02 rad apart on both sides of the +-pi cut are one heading."""
    from semslam.types import TagObservation

    t = np.arange(0, 10, 0.02)
    mapper = Mapper(MappingConfig(optimizer=optimizer), np.zeros(3), t, np.ones_like(t),
                    np.zeros_like(t))
    for k in range(30):
        yaw = np.pi - 0.01 if k % 2 else -np.pi + 0.01
        seen = np.array([6.0 - 0.1 * k, 1.0, yaw])
        mapper.add_frame(FrameObservations(k * 0.1, tags=(
            TagObservation("tag36h11", 3, 0.16, seen, 1.0, np.diag([1e-4, 1e-4, 1e-4])),)))
    (tag,) = mapper.finish().map.tags
    assert abs(abs(tag.mTt[2]) - np.pi) < 0.02
    assert tag.covariance[2, 2] < 1e-3


def test_each_exported_odometry_edge_is_corrected_by_its_own_calibration_window():
    from semslam.mapping.mapper import K

    cfg = SimulationConfig()
    cfg = cfg.model_copy(update={"drive": cfg.drive.model_copy(update={"max_duration": 30.0})})
    sim = simulate_drive("small", 2, 0, cfg)
    mcfg = MappingConfig(calibration_window=8)
    rec = sim.record
    mapper = Mapper(mcfg, sim.frame_poses[0], rec.t, rec.odo_speed, rec.odo_yaw_rate)
    for frame in sim.noisy:
        mapper.add_frame(frame)
    result = mapper.finish()
    windows = {b // 8 for _, b, *_ in mapper.odometry_edges}
    assert len(windows) > 3
    for (_, b, d, _, J), (_, _, exported, _) in zip(
        mapper.odometry_edges, result.odometry_edges, strict=True
    ):
        own = mapper.graph.vector(K(b // 8))
        np.testing.assert_allclose(exported, d + J @ (own - [1.0, 0.0]), atol=1e-12)


def test_the_g2o_export_carries_each_slot_factors_own_information(small):
    from semslam.mapping.export import CORNER_ID_OFFSET, to_pose_graph

    result = _map(small, small.noisy)
    edges = {(e.a, e.b): e.information for e in to_pose_graph(result).point_edges}
    checked = differs = 0
    for s in result.sightings:
        slot_id = result.slot_of_landmark.get(s.landmark) if s.landmark is not None else None
        if s.status not in (SightingStatus.ACCEPTED, SightingStatus.REASSIGNED) or slot_id is None:
            continue
        info = edges[(s.keyframe, CORNER_ID_OFFSET + 4 * slot_id)]
        np.testing.assert_allclose(info, np.eye(2) / s.sigma**2)
        checked += 1
        differs += not math.isclose(s.sigma, s.observation.corner_sigma)
    assert checked > 20 and differs > 0


def test_a_line_detection_with_a_nan_end_is_left_out(small):
    """As the localizer does: a detection of no length is no line (a NaN end point crashed
    the line landmarks' spatial hash)."""
    from semslam.types import MarkingObservation

    bad = MarkingObservation(np.array([1.0, 2.0]), np.array([np.nan, -2.0]), 0.12, 0.9)
    frames = [dataclasses.replace(f, markings=(*f.markings, bad)) for f in small.exact[:200]]
    result = _map(small, frames)
    assert all(np.isfinite([m.a, m.b]).all() for m in result.map.markings)


def test_a_slot_read_once_unsurely_exports_that_doubt(small):
    """A slot whose ID is read in one frame, at 0.02, exports its label at about 0.02 (the
    share of the votes gave 1.0); a slot read in many frames is sure of its label."""
    label = next(o.label for f in small.exact for o in f.slots if o.label)
    reads = [(i, j) for i, f in enumerate(small.exact) for j, o in enumerate(f.slots)
             if o.label == label]
    once = reads[len(reads) // 2]
    frames = []
    for i, frame in enumerate(small.exact):
        slots = tuple(
            o if o.label != label
            else dataclasses.replace(o, label_confidence=0.02) if (i, j) == once
            else dataclasses.replace(o, label=None, label_confidence=0.0)
            for j, o in enumerate(frame.slots)
        )
        frames.append(FrameObservations(frame.t, slots, frame.tags, frame.markings))
    slots = {s.label: s for s in _map(small, frames).map.slots}
    assert slots[label].label_confidence == pytest.approx(0.02)
    others = [s for s in slots.values() if s.label not in (None, label)]
    assert others and all(s.label_confidence > 0.99 for s in others)


def _declaring(frames, weight, own, shared):
    """The frames' slot detections weighted at ``weight`` and declaring own and shared errors
    (per corner, m)."""
    return [dataclasses.replace(f, slots=tuple(
        dataclasses.replace(s, corner_sigma=weight, corner_sigma_own=own,
                            corner_sigma_shared=shared) for s in f.slots)) for f in frames]


def test_declared_own_and_shared_errors_set_the_corner_covariances_not_the_map(
    small, monkeypatch
):
    """Detections weighted at 0.3 m that declare a small own error and a shared one: the same
    corners, covariances about the declared errors (not the weight's), never below the
    shared error; a graph too large for the dense solve keeps the graph's marginals."""
    import semslam.mapping.shared_error as shared_error

    plain = _map(small, _declaring(small.noisy, 0.3, None, None))
    declared = _map(small, _declaring(small.noisy, 0.3, (0.05,) * 4, (0.01, 0.01, 0.02, 0.02)))
    assert declared.statistics["slot_covariance_s"] > 0
    assert len(declared.map.slots) == len(plain.map.slots)
    for a, b in zip(declared.map.slots, plain.map.slots, strict=True):
        np.testing.assert_array_equal(a.corners, b.corners)
        variances = np.array([np.diag(c) for c in a.corner_covariances])  # (4, 2)
        before = np.array([np.diag(c) for c in b.corner_covariances])
        assert np.all(variances < before)
        assert np.all(variances[:2] >= 0.01**2) and np.all(variances[2:] >= 0.02**2)
    monkeypatch.setattr(shared_error, "MAX_UNKNOWNS", 10)
    too_large = _map(small, _declaring(small.noisy, 0.3, (0.05,) * 4, (0.01,) * 4))
    for a, b in zip(too_large.map.slots, plain.map.slots, strict=True):
        np.testing.assert_allclose(a.corner_covariances, b.corner_covariances)


def test_a_long_standstill_costs_each_frame_only_its_own_odometry(small, monkeypatch):
    """Found by fuzzing: each frame integrated the odometry from the last keyframe, so a car
    standing still (no new keyframe) cost each frame all the samples since it stopped. The
    frames are those of ``small`` with 60 s of standing at 10 Hz put in front."""
    import semslam.mapping.odometry as odometry

    rec = small.record
    stand = 60.0
    t = np.concatenate([np.arange(0.0, stand, 0.02), np.asarray(rec.t) + stand])
    speed = np.concatenate([np.zeros(int(stand / 0.02)), rec.odo_speed])
    rate = np.concatenate([np.zeros(int(stand / 0.02)), rec.odo_yaw_rate])
    frames = [FrameObservations(t=float(s)) for s in np.arange(0.0, stand, 0.1)] + [
        dataclasses.replace(f, t=f.t + stand) for f in small.noisy
    ]
    integrated = []
    segment = odometry._segment
    monkeypatch.setattr(
        odometry, "_segment",
        lambda *a: integrated.append(len((s := segment(*a))[0])) or s,  # type: ignore[func-returns-value]
    )
    mapper = Mapper(MappingConfig(), small.frame_poses[0], t, speed, rate)
    keyframes = [mapper.add_frame(f) for f in frames]
    assert sum(integrated) < 4 * len(t)  # linear: about one pass per use (frame, keyframe)
    assert sum(keyframes[: int(stand / 0.1)]) == 1  # standing: the first frame only
    # the same keyframes as integrating each frame from its keyframe, as before
    expected, last = [], None
    for f in frames:
        if last is None:
            expected.append(True)
            last = f.t
            continue
        delta, _ = odometry.odometry_between(t, speed, rate, last, f.t, 0.1, 0.01, 0.01)
        cfg = MappingConfig()
        step = (math.hypot(delta[0], delta[1]) >= cfg.keyframe_distance
                or abs(math.degrees(delta[2])) >= cfg.keyframe_angle_deg)
        expected.append(step)
        last = f.t if step else last
    assert keyframes == expected


def _with_scattered_ghosts(frames, per_frame, copies=1, seed=0):
    """Each frame's first slot also seen ``per_frame`` times shifted half a slot width
    sideways, give or take 0.15 of a width (each ghost ``copies`` times, to the digit):
    false slots that pile up between two neighbours, inconsistent from one to the next."""
    rng = np.random.default_rng(seed)
    out = []
    for f in frames:
        ghosts = tuple(
            dataclasses.replace(o, vCorners=o.vCorners + shift, label=None, label_confidence=0.0)
            for o in f.slots[:1]
            for shift in [(o.vCorners[1] - o.vCorners[0]) * rng.uniform(0.35, 0.65)
                          for _ in range(per_frame)]
            for _ in range(copies)
        )
        out.append(FrameObservations(f.t, f.slots + ghosts, f.tags, f.markings))
    return out


def test_ghosts_that_disagree_with_each_other_do_not_become_a_slot(small):
    """Ghosts twice as frequent as the slots they shadow would be confirmed first and then
    refuse the real slots as overlapping them; a pooled slot becomes a landmark only when
    its last M sightings agree as their corner sigmas say."""
    result = _map(small, _with_scattered_ghosts(small.exact, 2))
    m = evaluate_map(result.map, _seen_truth(small))
    assert m.slots_matched == m.slots_true
    assert m.wrong_merges == 0 and m.false_slots == 0 and m.duplicate_slots == 0


def test_ghosts_seen_several_at_once_do_not_become_a_slot(small):
    """Three copies of one ghost in a frame agree to the digit, but a slot is seen once
    per keyframe: M sightings confirm a slot only from M keyframes."""
    result = _map(small, _with_scattered_ghosts(small.exact, 1, copies=3))
    m = evaluate_map(result.map, _seen_truth(small))
    assert m.slots_matched == m.slots_true
    assert m.wrong_merges == 0 and m.false_slots == 0 and m.duplicate_slots == 0
