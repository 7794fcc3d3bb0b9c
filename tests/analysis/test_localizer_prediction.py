"""The predicted accuracy of semslam's own localizer: its process noise as a grade, its
marking fallback, its covariance floor, the simulator's detectors."""

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from semslam.analysis.accuracy import (
    GRADES,
    IDEAL,
    LocalizerModel,
    MapGeometry,
    SensorModel,
    filter_route,
    frame_information,
    localizer_grade,
    localizer_model,
    predicted_along_route,
    simulated_sensors,
)
from semslam.cli import app
from semslam.config import LocalizationConfig, ObservationNoiseConfig
from semslam.errors import ConfigError
from semslam.io import save_map, write_tum
from semslam.localization.association import LocalMap
from semslam.localization.filter import CtrvFilter, ProcessNoise
from semslam.pipeline.accuracy import predicted_accuracy, prediction_model
from semslam.types import Marking, SemanticMap, Slot, SlotKind

RATE = 50.0  # odometry, Hz


def _slot(x: float, y: float, sid: int, cov: float = 0.0) -> Slot:
    corners = np.array([[x, y], [x + 2.5, y], [x + 2.5, y + 5.0], [x, y + 5.0]])
    return Slot(sid, None, 0.0, corners, np.tile(np.eye(2) * cov, (4, 1, 1)),
                SlotKind.PERPENDICULAR)


def _coast_localizer(cfg: LocalizationConfig, yaw: float, speed: float, seconds: float):
    """The localizer's own filter (its prediction and odometry updates, no frame): the
    pose covariance after ``seconds`` of straight driving."""
    noise = ProcessNoise(cfg.acceleration_sigma, cfg.yaw_acceleration_sigma,
                         cfg.position_walk, cfg.yaw_walk, cfg.speed_scale_walk,
                         cfg.gyro_bias_walk)
    n = 7 if cfg.estimate_odometry_errors else 5
    P = np.zeros((n, n))
    P[3, 3], P[4, 4] = cfg.speed_sigma**2, cfg.yaw_rate_sigma**2
    if n == 7:  # the localizer's priors on the wheel scale and the gyro bias
        P[5, 5], P[6, 6] = cfg.speed_scale_prior_sigma**2, cfg.gyro_bias_prior_sigma**2
    f = CtrvFilter(np.array([0.0, 0.0, yaw, speed, 0.0, 0.0, 0.0][:n]), P, noise)
    for _ in range(round(seconds * RATE)):
        f.predict(1 / RATE)
        f.update_odometry(speed, 0.0, cfg.speed_sigma, cfg.yaw_rate_sigma)
    return f.pose_covariance


@pytest.mark.parametrize("walk, calibrated", [(0.0, False), (0.02, False), (0.05, False),
                                               (0.0, True), (0.02, True)])
def test_localizer_grade_grows_like_the_localizers_own_filter(walk, calibrated):
    cfg = LocalizationConfig(position_walk=walk, estimate_odometry_errors=calibrated)
    yaw, speed, seconds = 0.5, 2.0, 10.0
    expected = _coast_localizer(cfg, yaw, speed, seconds)
    t = np.arange(0.0, seconds + 1e-9, 0.1)  # frames at 10 Hz, nothing seen after the first
    poses = np.column_stack([speed * t * math.cos(yaw), speed * t * math.sin(yaw),
                             np.full_like(t, yaw)])
    infos = np.zeros((len(t), 3, 3))
    infos[0] = np.diag([1e12, 1e12, 1e12])  # a perfectly known start, as the coast's
    P = filter_route(infos, poses, t, localizer_grade(cfg, RATE))[-1]
    u = np.array([math.cos(yaw), math.sin(yaw)])
    v = np.array([-u[1], u[0]])
    for got, want in ((u @ P[:2, :2] @ u, u @ expected[:2, :2] @ u),
                      (v @ P[:2, :2] @ v, v @ expected[:2, :2] @ v), (P[2, 2], expected[2, 2])):
        assert got == pytest.approx(want, rel=0.03)
    if calibrated:  # coasting with the prior scale error: 2 % of 20 m dominates
        assert u @ P[:2, :2] @ u == pytest.approx((0.02 * speed * seconds) ** 2, rel=0.1)
        return
    # Hofmann's automotive grade is not this filter: 20x the along-track variance
    auto = filter_route(infos, poses, t, GRADES["automotive"])[-1]
    assert u @ auto[:2, :2] @ u > 2 * u @ P[:2, :2] @ u


def test_localizer_grade_rejects_a_bad_odometry_rate():
    with pytest.raises(ValueError, match="odometry rate"):
        localizer_grade(LocalizationConfig(), 0.0)


def test_predicted_sigma_among_slots_grows_with_the_position_walk():
    m = MapGeometry(SemanticMap(slots=tuple(_slot(3.0 * k, 2.0, k) for k in range(12))))
    t = np.arange(0.0, 15.0, 0.1)
    poses = np.column_stack([2.0 * t, np.zeros_like(t), np.zeros_like(t)])  # slots in view
    sensors = simulated_sensors(ObservationNoiseConfig())
    sigmas = []
    for walk in (0.0, 0.02, 0.04):
        cfg = LocalizationConfig(position_walk=walk)
        r = predicted_along_route(m, poses, t, localizer_grade(cfg, RATE), sensors,
                                  localizer_model(cfg))
        assert r["slots"][50] >= 2
        sigmas.append(float(np.median(r["filtered_sigma"][20:])))
    assert sigmas[0] < sigmas[1] < sigmas[2] < 0.05
    assert sigmas[2] > 1.3 * sigmas[0]


def _slots_and_line():
    """Three slots ahead-left of the car and a painted line on its right, all in view."""
    line = Marking(np.array([-4.0, -2.5]), np.array([4.0, -2.5]), 0.12)
    slots = tuple(_slot(-3.0 + 2.5 * k, 1.2, k) for k in range(3))
    return SemanticMap(slots=slots), SemanticMap(markings=(line,)), SemanticMap(
        slots=slots, markings=(line,))


def test_lines_are_a_fallback_the_localizer_uses_only_with_few_slots():
    slots, line, both = (MapGeometry(m) for m in _slots_and_line())
    pose = np.zeros(3)
    model = localizer_model(LocalizationConfig())  # fallback_below = 2
    sure = SensorModel(slot_rule="entrance")  # every landmark in view detected
    info_slots, counts = frame_information(slots, pose, sure, model)
    info_both, counts_both = frame_information(both, pose, sure, model)
    assert counts["slots"] == 3 and counts_both["lines"] == 1
    np.testing.assert_allclose(info_both, info_slots)  # the line is ignored among slots
    info_line, _ = frame_information(line, pose, sure, model)
    assert info_line[1, 1] == pytest.approx(2 / model.marking_sigma**2)  # across: y
    # Hofmann's ideal filter uses the line as well
    ideal_both, _ = frame_information(both, pose, sure)
    ideal_slots, _ = frame_information(slots, pose, sure)
    assert ideal_both[1, 1] > ideal_slots[1, 1] + 1.0
    # slots missed 20 % of the time: lines are used when fewer than 2 of 3 are detected
    rates = replace(sure, slot_detection_rate=0.8, marking_detection_rate=0.9)
    info_rates, _ = frame_information(both, pose, rates, model)
    fewer_than_two = 0.2**3 + 3 * 0.8 * 0.2**2
    want = 0.8 * info_slots + 0.9 * fewer_than_two * info_line
    np.testing.assert_allclose(info_rates, want, rtol=1e-9)


def test_kinds_switched_off_are_not_used_and_lines_then_fall_back_alone():
    _, _, both = _slots_and_line()
    g = MapGeometry(both)
    pose, sure = np.zeros(3), SensorModel(slot_rule="entrance")
    cfg = LocalizationConfig(use_slots=False, use_tags=False)
    model = localizer_model(cfg)
    assert not model.use_slots and not model.use_tags and model.use_markings
    info, counts = frame_information(g, pose, sure, model)
    assert counts["slots"] == counts["corners"] == 0 and counts["lines"] == 1
    line_only, _ = frame_information(MapGeometry(_slots_and_line()[1]), pose, sure, model)
    np.testing.assert_allclose(info, line_only)  # the slots no longer hold the line back
    off = localizer_model(LocalizationConfig(use_markings=False))
    info, counts = frame_information(MapGeometry(_slots_and_line()[1]), pose, sure, off)
    assert counts["lines"] == 0 and not info.any()


def test_the_slots_separators_join_the_lines_as_the_localizers_do():
    slots, _, _ = _slots_and_line()  # three slots side by side, no painted line mapped
    plain = MapGeometry(slots)
    model = localizer_model(LocalizationConfig(use_slots=False, use_tags=False))
    assert model.slot_sides and not len(plain.lines)
    sided = MapGeometry.for_model(slots, model)
    assert len(sided.lines) == 4  # the three slots' six sides, the shared ones once
    assert len(MapGeometry.for_model(slots, replace(model, slot_sides=False)).lines) == 0
    sure = SensorModel(slot_rule="entrance")
    info, counts = frame_information(sided, np.zeros(3), sure, model)
    assert counts["lines"] == 4 and info[0, 0] > 0  # separators across x fix x
    # a map that holds the separators already gets none twice
    held = SemanticMap(slots=slots.slots, markings=tuple(
        Marking(np.array(a, float), np.array(b, float), 0.1) for a, b in sided.lines))
    assert len(MapGeometry.for_model(held, model).lines) == 4


def test_the_heading_is_reported_at_least_at_the_map_slots_heading_error_near_the_car():
    slots = tuple(_slot(-3.0 + 2.5 * k, 1.2, k, cov=0.05**2) for k in range(3))
    cross = (Marking(np.array([-4.0, -2.0]), np.array([4.0, -2.0]), 0.1),
             Marking(np.array([3.0, -4.0]), np.array([3.0, -1.0]), 0.1))
    m = SemanticMap(slots=slots, markings=cross)
    cfg = LocalizationConfig(use_slots=False, use_tags=False)  # lines alone update the filter
    model = localizer_model(cfg)
    assert model.map_heading_radius == cfg.map_heading_radius > 0
    geometry = MapGeometry.for_model(m, model)
    # the same slots near a point as the localizer's own local map finds
    local = LocalMap(m, cfg)
    for point in ([0.0, 0.0], [1.0, 3.0], [30.0, 0.0]):
        assert geometry.heading_variance_near(np.array(point), 5.0) == (
            local.heading_variance_near(np.array(point), 5.0))
    t = np.arange(0.0, 10.0, 0.1)
    poses = np.column_stack([0.1 * t, np.zeros_like(t), np.zeros_like(t)])
    sure, grade = SensorModel(slot_rule="entrance"), localizer_grade(cfg, RATE)
    reported = predicted_along_route(geometry, poses, t, grade, sure, model)["covariance"]
    held = predicted_along_route(geometry, poses, t, grade, sure,
                                 replace(model, map_heading_radius=0.0))["covariance"]
    heading = cfg.map_floor_scale * np.mean([s.orientation_variance for s in slots])
    assert held[-1, 2, 2] < 0.5 * heading  # the lines make the filter surer than the map
    np.testing.assert_allclose(reported[:, 2, 2], np.maximum(held[:, 2, 2], heading))
    np.testing.assert_array_equal(reported[:, :2, :2], held[:, :2, :2])  # the report only


def test_whole_slots_by_their_entrance_like_the_simulator():
    deep = SemanticMap(slots=(_slot(-1.0, 2.0, 1),))  # far corners at y = 7: outside the view
    g = MapGeometry(deep)
    _, by_corner = frame_information(g, np.zeros(3), SensorModel())
    _, whole = frame_information(g, np.zeros(3), SensorModel(slot_rule="entrance"))
    assert by_corner["corners"] == 2 and whole["corners"] == 4 and whole["slots"] == 1
    # an entrance corner in the ego box: not detected
    _, under = frame_information(MapGeometry(SemanticMap(slots=(_slot(-1.0, 0.5, 1),))),
                                 np.zeros(3), SensorModel(slot_rule="entrance"))
    assert under["slots"] == 0
    with pytest.raises(ValueError, match="slot_rule"):
        frame_information(g, np.zeros(3), SensorModel(slot_rule="bogus"))
    sim = simulated_sensors(ObservationNoiseConfig(slot_miss_rate=0.25))
    assert sim.slot_rule == "entrance" and sim.slot_detection_rate == 0.75
    assert sim.tag_fov_deg == pytest.approx(90.0, abs=0.1)


def test_the_covariance_floor_follows_the_map():
    t = np.arange(0.0, 5.0, 0.1)
    poses = np.column_stack([t, np.zeros_like(t), np.zeros_like(t)])
    sure = SensorModel(slot_rule="entrance")
    model = localizer_model(LocalizationConfig())  # floor: a multiple of the map's uncertainty
    scale = LocalizationConfig().map_floor_scale
    grade = localizer_grade(LocalizationConfig(), RATE)
    slots = MapGeometry(SemanticMap(slots=tuple(_slot(-2.0 + 2.5 * k, 1.2, k, cov=0.04**2)
                                                for k in range(4))))
    r = predicted_along_route(slots, poses, t, grade, sure, model)
    floor = scale * 0.04**2
    smallest = np.linalg.eigvalsh(r["covariance"][1:, :2, :2])[:, 0]
    assert smallest.min() == pytest.approx(floor, rel=1e-6)
    free = predicted_along_route(slots, poses, t, grade, sure, replace(model, map_floor_scale=0))
    assert np.linalg.eigvalsh(free["covariance"][-1, :2, :2])[0] < 0.5 * floor
    # the heading: the slots' orientation variance (here their corners taken as independent)
    heading = np.mean([s.orientation_variance for s in SemanticMap(slots=tuple(
        _slot(-2.0 + 2.5 * k, 1.2, k, cov=0.04**2) for k in range(4))).slots])
    assert r["covariance"][1:, 2, 2].min() == pytest.approx(scale * heading, rel=1e-6)
    assert free["covariance"][-1, 2, 2] < 0.5 * scale * heading
    # painted lines alone (a crossing pair): the configured marking uncertainty
    cross = SemanticMap(markings=(Marking(np.array([-4.0, 2.0]), np.array([4.0, 2.0]), 0.1),
                                  Marking(np.array([3.0, -4.0]), np.array([3.0, 4.0]), 0.1)))
    r = predicted_along_route(MapGeometry(cross), poses[:10], t[:10], grade, sure, model)
    assert np.linalg.eigvalsh(r["covariance"][-1, :2, :2])[0] >= scale * 0.05**2 * (1 - 1e-9)
    assert LocalizerModel() == IDEAL and IDEAL.map_floor_scale == 0


def test_accuracy_command_takes_the_localizer_grade(tmp_path):
    m = SemanticMap(slots=tuple(_slot(3.0 * k, 2.0, k) for k in range(6)))
    save_map(tmp_path / "map.json", m)
    t = np.arange(0.0, 8.0, 0.5)
    write_tum(tmp_path / "route.tum", t,
              np.column_stack([2.0 * t, np.zeros_like(t), np.zeros_like(t)]))
    runner = CliRunner()
    result = runner.invoke(app, ["accuracy", str(tmp_path / "map.json"), "--route",
                                 str(tmp_path / "route.tum"), "-o", str(tmp_path / "acc"),
                                 "--grid-step", "4", "--grade", "localizer", "--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert doc["grade"] == "localizer" and doc["odometry"]["scale_sigma"] == 0.02
    written = json.loads((tmp_path / "acc" / "config.json").read_text())  # what it predicted for
    assert written["localization"] == LocalizationConfig().model_dump(mode="json")
    hofmann = predicted_accuracy(tmp_path / "map.json", tmp_path / "h", tmp_path / "route.tum",
                                 grid_step=4.0)
    assert hofmann["odometry"]["scale_sigma"] == 0.0
    assert not (tmp_path / "h" / "config.json").exists()  # Hofmann's grades read no config
    with pytest.raises(ConfigError, match="--grade: choose one of automotive, precise, "
                                          "localizer, got 'bad'"):
        prediction_model("bad")
    result = runner.invoke(app, ["plan-tags", str(tmp_path / "map.json"), "--route",
                                 str(tmp_path / "route.tum"), "-o", str(tmp_path / "p"),
                                 "--grade", "localizer"])
    assert result.exit_code == 2  # the planner's information has no marking fallback


def test_accuracy_command_predicts_the_localizer_of_a_config_file(tmp_path):
    slots, _, _ = _slots_and_line()
    save_map(tmp_path / "map.json", slots)
    t = np.arange(0.0, 4.0, 0.5)
    write_tum(tmp_path / "route.tum", t, np.column_stack([0.2 * t, np.zeros_like(t),
                                                          np.zeros_like(t)]))
    (tmp_path / "lines.json").write_text('{"localization": {"use_slots": false}}')
    runner = CliRunner()

    def route_sigma(out, *extra):
        result = runner.invoke(app, ["accuracy", str(tmp_path / "map.json"), "--route",
                                     str(tmp_path / "route.tum"), "-o", str(out), "--grid-step",
                                     "4", "--grade", "localizer", "--json", *extra])
        assert result.exit_code == 0, result.output
        return json.loads(result.stdout)["route"]["filtered_sigma_median_m"]

    with_slots = route_sigma(tmp_path / "a")
    out = tmp_path / "b"
    lines_only = route_sigma(out, "--config", str(tmp_path / "lines.json"))
    # the slots' separators alone fix the pose across them only: less sure than the corners
    assert lines_only > with_slots
    written = json.loads((out / "config.json").read_text())
    assert written["localization"]["use_slots"] is False
    # a re-run with the config the last one wrote back replaces it by the same
    assert route_sigma(out, "--config", str(out / "config.json")) == lines_only
    result = runner.invoke(app, ["accuracy", str(tmp_path / "map.json"), "-o",
                                 str(tmp_path / "h"), "--config", str(tmp_path / "lines.json")])
    assert result.exit_code == 2 and "only --grade localizer" in result.output
