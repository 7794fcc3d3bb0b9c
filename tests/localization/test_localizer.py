"""The localizer on short simulated drives against the true map of their world."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from semslam.config import LocalizationConfig, SimulationConfig
from semslam.errors import DriveError
from semslam.localization.localizer import Localizer, positive_part_2x2, unsure_labels_dropped
from semslam.simulation.scenario import simulate_drive
from semslam.types import FrameObservations, TagObservation


@pytest.fixture(scope="module")
def sim():
    cfg = SimulationConfig()
    cfg = cfg.model_copy(update={"drive": cfg.drive.model_copy(update={"max_duration": 60.0})})
    return simulate_drive("small", 3, 0, cfg)


def _run(sim, frames=None, initial="truth", **overrides):
    cfg = LocalizationConfig(**overrides)
    rec = sim.record
    start = sim.frame_poses[0] if isinstance(initial, str) else initial
    loc = Localizer(sim.world.to_map(), cfg, rec.t, rec.odo_speed, rec.odo_yaw_rate, start)
    return loc, [loc.step(f) for f in (frames if frames is not None else sim.noisy)]


def _errors(sim, estimates):
    poses = np.array([e.pose for e in estimates])
    pos = np.hypot(*(poses[:, :2] - sim.frame_poses[: len(poses), :2]).T)
    yaw = np.abs(np.remainder(poses[:, 2] - sim.frame_poses[: len(poses), 2] + np.pi,
                              2 * np.pi) - np.pi)
    return pos, np.degrees(yaw)


@pytest.mark.parametrize("update", ["ekf", "sigma"])
def test_tracks_a_turning_drive_with_noisy_observations(sim, update):
    turned = np.ptp(np.unwrap(sim.frame_poses[:, 2]))
    assert turned > math.radians(80)  # the drive turns
    _, estimates = _run(sim, update=update)
    pos, yaw = _errors(sim, estimates)
    assert np.sqrt(np.mean(pos**2)) < 0.08
    assert np.sqrt(np.mean(yaw**2)) < 0.5
    assert sum(e.status == "tracking" for e in estimates) > 0.8 * len(estimates)


def test_converges_from_a_wrong_start(sim):
    start = sim.frame_poses[0] + np.array([0.4, -0.3, math.radians(4)])
    _, estimates = _run(sim, initial=start)
    pos, yaw = _errors(sim, estimates)
    assert np.all(pos[30:] < 0.15) and np.all(yaw[30:] < 1.0)


def test_covariance_stays_symmetric_positive_definite(sim):
    loc, estimates = _run(sim)
    for e in estimates[::10]:
        np.testing.assert_allclose(e.covariance, e.covariance.T, atol=1e-15)
        assert np.all(np.linalg.eigvalsh(e.covariance) > 0)
    assert np.all(np.linalg.eigvalsh(loc.filter.P) > 0)


def test_a_wrong_tag_association_is_rejected_by_the_gate(sim):
    tag = sim.world.to_map().tags[0]
    liar = TagObservation(tag.family, tag.tag_id, tag.size, np.array([6.0, 3.0, 0.5]), tag.height,
                          np.diag([0.02**2, 0.02**2, math.radians(2) ** 2]))
    frames = [dataclasses.replace(f, tags=f.tags + (liar,)) for f in sim.noisy]
    loc, estimates = _run(sim, frames)
    pos, _ = _errors(sim, estimates)
    assert np.sqrt(np.mean(pos**2)) < 0.08
    assert all(e.rejected >= 1 for e in estimates)
    assert (tag.family, tag.tag_id) in loc._suspect_tags  # never in a global fix again


def test_finds_its_pose_with_no_start_and_recovers_from_a_kidnap(sim):
    loc, estimates = _run(sim, frames=sim.noisy[:300], initial=None)
    first = next(i for i, e in enumerate(estimates) if np.all(np.isfinite(e.pose)))
    assert estimates[first].status == "relocalized"
    assert sim.noisy[first].t - sim.noisy[0].t < 3.0
    pos, _ = _errors(sim, estimates[first:][:1])
    assert pos[0] < 0.3
    # kidnap where slots are in view: the filter now believes it is 10 m away
    k = next(i for i in range(300, len(sim.noisy)) if all(
        len(f.slots) >= 2 for f in sim.noisy[i : i + 20]))
    estimates += [loc.step(f) for f in sim.noisy[300:k]]
    loc.filter.x[:2] += [10.0, 0.0]
    after = [loc.step(f) for f in sim.noisy[k:]]
    pos, _ = _errors(sim, [*estimates, *after])
    assert pos[k] > 9
    back = next(i for i in range(k, len(pos)) if pos[i] < 0.3)
    assert sim.noisy[back].t - sim.noisy[k].t < 3.0
    assert any(e.status == "relocalized" for e in after)


def _only_tag(frame, tag_id, shift=None, yaw=0.0, keep_slots=False):
    """``frame`` with no painted line, no slot (unless ``keep_slots``) and only tag
    ``tag_id``; that tag seen as if moved by ``shift`` (2,) m in the map frame, the car
    heading ``yaw`` (rad)."""
    tags = [t for t in frame.tags if t.tag_id == tag_id]
    if shift is not None:
        c, s = math.cos(yaw), math.sin(yaw)
        dv = np.array([c * shift[0] + s * shift[1], -s * shift[0] + c * shift[1]])
        tags = [dataclasses.replace(t, vTt=t.vTt + np.array([*dv, 0.0])) for t in tags]
    if keep_slots:
        others = tuple(t for t in frame.tags if t.tag_id != tag_id)
        return dataclasses.replace(frame, tags=others + tuple(tags))
    return dataclasses.replace(frame, slots=(), tags=tuple(tags), markings=())


@pytest.mark.parametrize("lone_tag_after", [1.0, 0.0])
def test_a_kidnap_that_one_tag_alone_sees_is_recovered(sim, lone_tag_after):
    """From frame k - 25 on the car sees one tag and nothing else; at k it is kidnapped 10 m.
    The tag contradicts it at every check; once no slot or tag has been applied for
    ``lone_tag_after`` s, the tag alone may move it (0: never, the car coasts on)."""
    k, tag_id = 160, 418
    seen = [any(t.tag_id == tag_id for t in f.tags) for f in sim.noisy[k - 25 : k + 30]]
    assert np.mean(seen) > 0.9  # the tag is in (almost) every frame
    frames = list(sim.noisy[: k - 25]) + [_only_tag(f, tag_id) for f in sim.noisy[k - 25 : k + 50]]
    loc, estimates = _run(sim, frames=frames[:k], lone_tag_after=lone_tag_after)
    loc.filter.x[:2] += [10.0, 0.0]
    after = [loc.step(f) for f in frames[k:]]
    pos, _ = _errors(sim, [*estimates, *after])
    if lone_tag_after:
        back = next(i for i in range(k, len(pos)) if pos[i] < 0.3)
        assert sim.noisy[back].t - sim.noisy[k].t < 3.0
        assert "relocalized" in {e.status for e in after[: back - k + 1]}
    else:
        assert np.all(pos[k:] > 9)
        assert {e.status for e in after} == {"coasting"}


def test_a_moved_tag_seen_alone_misleads_the_car_only_until_slots_return(sim):
    """Tag 418 moved 3 m; the car sees it alone for 4.5 s, so it may jump there, but the
    slots put it back, and the tag, rejected where they are applied, is suspect: it no
    longer takes part in global fixes."""
    k, tag_id = 160, 418
    poses = sim.frame_poses
    frames = (
        list(sim.noisy[: k - 25])
        + [_only_tag(sim.noisy[i], tag_id, (3.0, 0.0), poses[i, 2]) for i in range(k - 25, k + 20)]
        + [_only_tag(sim.noisy[i], tag_id, (3.0, 0.0), poses[i, 2], keep_slots=True)
           for i in range(k + 20, 300)]
    )
    loc, estimates = _run(sim, frames=frames)
    pos, _ = _errors(sim, estimates)
    assert pos[k - 25 : k + 20].max() > 2  # the jump: the tag alone was all it saw
    back = next(i for i in range(k + 20, len(pos)) if np.all(pos[i:] < 0.1))
    assert sim.noisy[back].t - sim.noisy[k + 20].t < 3.0
    assert tag_id in {key[1] for key in loc._suspect_tags}


def test_markings_alone_keep_it_on_track(sim):
    _, estimates = _run(sim, use_slots=False, use_tags=False)
    pos, _ = _errors(sim, estimates)
    assert np.sqrt(np.mean(pos**2)) < 0.2


def _lines_only(frames, turn=0.0):
    """The frames with their slots and tags taken away and each painted line turned by
    ``turn`` (rad) about its middle."""
    c, s = math.cos(turn), math.sin(turn)

    def changed(m):
        a, b = np.asarray(m.vA, float), np.asarray(m.vB, float)
        mid = (a + b) / 2
        R = np.array([[c, -s], [s, c]])
        return dataclasses.replace(m, vA=mid + R @ (a - mid), vB=mid + R @ (b - mid))

    return [dataclasses.replace(f, slots=(), tags=(), markings=tuple(map(changed, f.markings)))
            for f in frames]


def test_lines_that_fit_no_map_line_in_view_are_lost_lines_where_the_map_has_none_are_not(sim):
    frames = sim.noisy[:60]
    assert sum(len(f.markings) >= 2 for f in frames) >= 20
    _, askew = _run(sim, frames=_lines_only(frames, turn=math.radians(30)))
    assert "lost" in {e.status for e in askew}  # on the map's lines, but 30 deg off them
    _, straight = _run(sim, frames=_lines_only(frames))
    assert "lost" not in {e.status for e in straight}
    # the same lines against a map that lost its lines near the first 60 frames: coasting
    near = sim.frame_poses[:60, :2]
    world = sim.world.to_map()
    far_lines = tuple(m for m in world.markings if min(
        np.hypot(*(near - (np.asarray(m.a) + np.asarray(m.b)) / 2).T).min(),
        np.hypot(*(near - m.a).T).min(), np.hypot(*(near - m.b).T).min()) > 25.0)
    assert 0 < len(far_lines) < len(world.markings)
    rec = sim.record
    lines_lost = dataclasses.replace(world, markings=far_lines)
    cfg = LocalizationConfig(slot_sides_as_markings=False)  # the map's lines alone
    loc = Localizer(lines_lost, cfg, rec.t, rec.odo_speed, rec.odo_yaw_rate, sim.frame_poses[0])
    unheld = [loc.step(f) for f in _lines_only(frames)]
    assert {e.status for e in unheld} == {"coasting"}
    assert sum(e.rejected for e in unheld) >= 40  # seen and refused, without alarm
    # the map's slots still hold the separators among those lines: they are used
    loc = Localizer(lines_lost, LocalizationConfig(), rec.t, rec.odo_speed, rec.odo_yaw_rate,
                    sim.frame_poses[0])
    sides = [loc.step(f) for f in _lines_only(frames)]
    assert np.mean([e.status == "tracking" for e in sides]) > 0.8


def test_time_going_backwards_is_refused(sim):
    loc, _ = _run(sim, frames=sim.noisy[:5])
    with pytest.raises(DriveError, match="time went back"):
        loc.step(FrameObservations(sim.noisy[2].t))


def test_a_frame_time_that_is_not_a_number_is_refused(sim):
    loc, _ = _run(sim, frames=sim.noisy[:3])
    with pytest.raises(DriveError, match="not a finite number"):
        loc.step(FrameObservations(float("nan")))


def test_a_frame_before_the_first_odometry_sample_is_refused(sim):
    """The drive's start pose is the pose at the first odometry sample: a frame before it
    has no pose to start from (the mapper refuses it too)."""
    rec = sim.record
    loc = Localizer(sim.world.to_map(), LocalizationConfig(), rec.t[5:], rec.odo_speed[5:],
                    rec.odo_yaw_rate[5:], sim.frame_poses[0])
    with pytest.raises(DriveError, match="before the odometry"):
        loc.step(FrameObservations(float(rec.t[0])))


def test_two_agreeing_tags_correct_a_wrong_start_where_no_slot_is_used(sim):
    """Tags only, the start 6 m off: a fix from two agreeing tags may move the car far,
    where one tag alone may not."""
    start = sim.frame_poses[0] + np.array([6.0, 0.0, 0.0])
    _, estimates = _run(sim, initial=start, use_slots=False, use_markings=False)
    pos, _ = _errors(sim, estimates)
    assert "relocalized" in {e.status for e in estimates}
    assert pos[-1] < 0.5


def test_a_frame_with_only_a_tag_updates_the_filter(sim):
    frame, tag = next((f, t) for f in sim.exact for t in f.tags if np.hypot(*t.vTt[:2]) < 15)
    only_tag = FrameObservations(frame.t, (), (tag,), ())
    loc, _ = _run(sim, frames=[f for f in sim.noisy if f.t < frame.t])
    estimate = loc.step(only_tag)
    assert estimate.associated == 1 and estimate.status == "tracking"


def test_learns_the_wheel_scale_and_gyro_bias_of_the_drive(sim):
    rec = sim.record
    speed, rate = rec.odo_speed * 1.03, rec.odo_yaw_rate + 0.003  # and the drive's own errors
    dt = np.diff(rec.t)
    true_scale = np.sum(speed[:-1] * dt) / np.sum(rec.speed[:-1] * dt) - 1
    true_bias = np.sum((rate - rec.yaw_rate)[:-1] * dt) / (rec.t[-1] - rec.t[0])
    loc = Localizer(sim.world.to_map(), LocalizationConfig(), rec.t, speed, rate,
                    sim.frame_poses[0])
    estimates = [loc.step(f) for f in sim.noisy]
    assert loc.filter.x[5] == pytest.approx(true_scale, abs=0.004)
    assert loc.filter.x[6] == pytest.approx(true_bias, abs=5e-4)
    pos, _ = _errors(sim, estimates)
    assert np.sqrt(np.mean(pos**2)) < 0.08
    fixed = Localizer(sim.world.to_map(), LocalizationConfig(estimate_odometry_errors=False),
                      rec.t, speed, rate, sim.frame_poses[0])
    assert len(fixed.filter.x) == 5


def test_the_heading_is_never_surer_than_the_slots_it_was_measured_against(sim):
    """Map errors do not average out: after an update with slots, the heading variance is
    at least the mean orientation variance of those slots (times map_floor_scale)."""
    world = sim.world.to_map()
    heading_sigma = math.radians(0.3)
    unsure = dataclasses.replace(world, slots=tuple(
        dataclasses.replace(s, heading_variance=heading_sigma**2) for s in world.slots))
    rec = sim.record
    for semantic_map, floored in ((unsure, True), (world, False)):
        loc = Localizer(semantic_map, LocalizationConfig(), rec.t, rec.odo_speed,
                        rec.odo_yaw_rate, sim.frame_poses[0])
        estimates = [loc.step(f) for f in sim.noisy]
        yaw_sigma = np.sqrt([e.covariance[2, 2] for e in estimates if e.status == "tracking"])
        if floored:  # frames updated with tags or lines alone carry no slot floor
            assert np.mean(yaw_sigma >= heading_sigma * (1 - 1e-9)) > 0.8
        else:  # the true map is exact: the heading is known far better
            assert np.median(yaw_sigma) < heading_sigma / 3


def test_the_reported_heading_holds_the_maps_heading_error_where_lines_alone_update(sim):
    """With slots and tags switched off the filter follows painted lines, which carry no
    covariance: the reported heading variance is raised to the orientation variance of the
    map's slots near the car, and only the report is: the poses are the same to the bit."""
    world = sim.world.to_map()
    heading_sigma = math.radians(0.3)
    unsure = dataclasses.replace(world, slots=tuple(
        dataclasses.replace(s, heading_variance=heading_sigma**2) for s in world.slots))
    rec = sim.record
    runs = {}
    for radius in (0.0, 5.0):
        cfg = LocalizationConfig(use_slots=False, use_tags=False, map_heading_radius=radius)
        loc = Localizer(unsure, cfg, rec.t, rec.odo_speed, rec.odo_yaw_rate, sim.frame_poses[0])
        runs[radius] = [loc.step(f) for f in sim.noisy]
    near = np.array([loc.local_map.heading_variance_near(e.pose, 5.0) is not None
                     for e in runs[5.0]])
    assert 0.2 < near.mean() < 1.0  # some frames have a map slot within 5 m, some not
    for off, on, has_slot in zip(runs[0.0], runs[5.0], near, strict=True):
        np.testing.assert_array_equal(off.pose, on.pose)
        if has_slot:
            assert on.covariance[2, 2] == pytest.approx(max(off.covariance[2, 2],
                                                            heading_sigma**2))
        else:
            np.testing.assert_array_equal(on.covariance, off.covariance)
    raised = [on.covariance[2, 2] > off.covariance[2, 2]
              for off, on in zip(runs[0.0], runs[5.0], strict=True)]
    assert np.mean(raised) > 0.2  # lines alone make the filter surer than the map


def test_positive_part_2x2_matches_the_eigendecomposition():
    rng = np.random.default_rng(3)
    for _ in range(200):
        B = rng.normal(size=(2, 2))
        A = B + B.T
        w, V = np.linalg.eigh(A)
        expected = (V * np.maximum(w, 0.0)) @ V.T
        np.testing.assert_allclose(positive_part_2x2(A), expected, atol=1e-12)
    np.testing.assert_array_equal(positive_part_2x2(-np.eye(2)), np.zeros((2, 2)))


def test_map_labels_the_mapper_was_unsure_of_are_not_used(sim):
    """A map slot whose label is less likely than map_label_confidence_min to be right
    counts as unlabelled, for association and relocalization alike; the slot stays."""
    world = sim.world.to_map()
    slots = list(world.slots)
    slots[0] = dataclasses.replace(slots[0], label_confidence=0.3)
    slots[1] = dataclasses.replace(slots[1], label_confidence=0.7)
    unsure = dataclasses.replace(world, slots=tuple(slots))
    kept = unsure_labels_dropped(unsure, 0.5)
    assert len(kept.slots) == len(world.slots)
    assert kept.slots[0].label is None and kept.slots[0].label_confidence == 0.0
    assert kept.slots[1].label == world.slots[1].label
    rec = sim.record
    loc = Localizer(unsure, LocalizationConfig(), rec.t, rec.odo_speed, rec.odo_yaw_rate)
    assert loc.local_map.slots[0].label is None
    assert loc.local_map.slots[1].label == world.slots[1].label
    everything = Localizer(unsure, LocalizationConfig(map_label_confidence_min=0.0), rec.t,
                           rec.odo_speed, rec.odo_yaw_rate)
    assert everything.local_map.slots[0].label == world.slots[0].label


def test_a_map_whose_slot_ids_contradict_every_reading_is_lost_not_tracked(sim):
    """A map of another garage that happens to fit the geometry: every confidently read ID
    differs from the map slot it was associated with. It used to be 'tracking' throughout;
    the label check calls it lost (and relocalization finds nothing to agree with)."""
    world = sim.world.to_map()
    other = dataclasses.replace(
        world, tags=(),
        slots=tuple(dataclasses.replace(s, label=f"q{i}") for i, s in enumerate(world.slots)),
    )
    rec = sim.record
    cfg = LocalizationConfig()
    wrong = Localizer(other, cfg, rec.t, rec.odo_speed, rec.odo_yaw_rate, sim.frame_poses[0])
    statuses = [wrong.step(f).status for f in sim.noisy]
    first = statuses.index("lost")
    assert first < 60 and statuses[first:].count("lost") > 0.95 * len(statuses[first:])
    _, estimates = _run(sim)  # the right map, 20 % of the IDs misread: never
    assert all(e.status != "lost" for e in estimates)


def test_the_position_is_never_surer_than_the_painted_lines_it_follows(sim):
    """Painted lines whose own sigma (the map's drift where they lie) exceeds the configured
    one floor the position covariance at it in frames the lines alone update."""
    world = sim.world.to_map()
    line_sigma = 0.3
    unsure = dataclasses.replace(world, markings=tuple(
        dataclasses.replace(m, sigma=line_sigma) for m in world.markings))
    rec = sim.record
    cfg = LocalizationConfig(use_slots=False, use_tags=False, slot_sides_as_markings=False)
    for semantic_map, floored in ((unsure, True), (world, False)):
        loc = Localizer(semantic_map, cfg, rec.t, rec.odo_speed, rec.odo_yaw_rate,
                        sim.frame_poses[0])
        updated = [e for e in (loc.step(f) for f in sim.noisy) if e.associated > 0]
        assert len(updated) > 0.5 * len(sim.noisy)
        smallest = np.array([np.linalg.eigvalsh(e.covariance[:2, :2]).min() for e in updated])
        if floored:
            assert np.all(smallest >= line_sigma**2 * (1 - 1e-9))
        else:  # the true map's lines carry no sigma: the configured 5 cm
            assert np.median(np.sqrt(smallest)) < 0.1
