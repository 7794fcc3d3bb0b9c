"""Trajectory metrics: known answers on synthetic cases, the file runner, the CLI, evo."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from semslam.errors import FormatError
from semslam.evaluation.map_metrics import point_segment_distances
from semslam.evaluation.trajectory_metrics import (
    CHI2_3DOF_95,
    evaluate_trajectory,
    interpolate_poses,
    map_segments,
    nearest_segment,
)
from semslam.geometry import wrap_angle
from semslam.io import Track, save_map, write_track_csv, write_tum
from semslam.types import Marking, SemanticMap, Slot, SlotKind, default_covariance


def straight_line(n: int = 201, dt: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Driving along +x at 1 m/s from the origin."""
    t = np.arange(n) * dt
    return t, np.column_stack([t, np.zeros(n), np.zeros(n)])


def curve(n: int = 300, dt: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """A smooth loop-ish drive whose yaw crosses +-pi."""
    t = np.arange(n) * dt
    yaw = np.asarray(wrap_angle(2.5 + 0.2 * t), dtype=float)
    return t, np.column_stack([10 * np.cos(0.1 * t), 5 * np.sin(0.2 * t) + t, yaw])


def json_ready(result: dict) -> None:
    assert json.loads(json.dumps(result, allow_nan=False)) == result
    for value in result.values():
        assert value is None or type(value) in (int, float, str, list, dict)


# --------------------------------------------------------------------------- known answers


def test_constant_cross_offset_on_a_straight_line_along_x():
    t, truth = straight_line()
    est = truth + [0.0, 0.1, 0.0]
    lane_lines = np.array([[[-5.0, 2.0], [40.0, 2.0]], [[-5.0, -2.0], [40.0, -2.0]]])
    for markings, reference in ((lane_lines, "markings"), (None, "heading")):
        result = evaluate_trajectory(t, est, t, truth, markings=markings)
        json_ready(result)
        assert result["split_reference"] == reference
        assert result["orthogonal_mean_m"] == pytest.approx(0.1, abs=1e-12)
        assert result["orthogonal_std_m"] == pytest.approx(0.0, abs=1e-12)
        assert result["parallel_mean_m"] == pytest.approx(0.0, abs=1e-12)
        assert result["parallel_std_m"] == pytest.approx(0.0, abs=1e-12)
        assert result["ate_rmse_m"] == pytest.approx(0.1, abs=1e-12)
        assert result["ate_median_m"] == result["ate_p95_m"] == pytest.approx(0.1)
        assert result["ate_max_m"] == pytest.approx(0.1)
        assert result["yaw_rmse_deg"] == 0.0
        assert result["rpe_trans_rmse_m"] == pytest.approx(0.0, abs=1e-12)
        assert result["rpe_pairs"] == len(t) - 10  # every frame with one 1 s later
        assert result["frames"] == result["frames_evaluated"] == len(t)
        assert result["frames_lost"] == result["frames_unmatched"] == 0
        assert result["nees_mean"] is None and result["nees_within_95"] is None
        assert result["alignment"] is None


def test_split_follows_the_nearest_marking_to_the_true_position():
    t, truth = straight_line()
    est = truth + [0.1, 0.0, 0.0]  # along x everywhere
    # along x near the start, across the path (a stop line) further on
    markings = np.array([[[0.0, 1.0], [8.0, 1.0]], [[15.0, -3.0], [15.0, 3.0]]])
    result = evaluate_trajectory(t, est, t, truth, markings=markings)
    # reference: nearest segment per frame, one at a time
    near_h = point_segment_distances(truth[:, :2], markings[:1, 0], markings[:1, 1])
    near_v = point_segment_distances(truth[:, :2], markings[1:, 0], markings[1:, 1])
    along = np.where(near_h <= near_v, 0.1, 0.0)
    assert 0 < along.sum() < 0.1 * len(t)
    assert result["parallel_mean_m"] == pytest.approx(along.mean(), abs=1e-12)
    assert result["orthogonal_mean_m"] == pytest.approx(0.1 - along.mean(), abs=1e-12)
    assert result["parallel_std_m"] == pytest.approx(along.std(), abs=1e-12)


def test_nearest_segment_is_exact():
    rng = np.random.default_rng(4)
    segments = rng.uniform(-10, 10, size=(40, 2, 2))
    points = rng.uniform(-12, 12, size=(500, 2))
    k = nearest_segment(points, segments)
    d = np.column_stack([point_segment_distances(points, s[None, 0], s[None, 1]) for s in segments])
    np.testing.assert_allclose(d[np.arange(len(points)), k], d.min(axis=1), rtol=0, atol=1e-12)


def test_constant_yaw_offset():
    t, truth = curve()
    est = truth.copy()
    est[:, 2] = np.asarray(wrap_angle(est[:, 2] + math.radians(2.0)), dtype=float)
    result = evaluate_trajectory(t, est, t, truth)
    assert result["yaw_rmse_deg"] == pytest.approx(2.0, abs=1e-9)
    assert result["yaw_p95_deg"] == pytest.approx(2.0, abs=1e-9)
    assert result["ate_rmse_m"] == 0.0
    assert result["rpe_yaw_rmse_deg"] == pytest.approx(0.0, abs=1e-9)


def test_yaw_error_is_wrapped():
    t, truth = straight_line(20)
    truth[:, 2] = math.pi - 0.01
    est = truth.copy()
    est[:, 2] = -math.pi + 0.01  # 0.02 rad away across the cut
    result = evaluate_trajectory(t, est, t, truth)
    assert result["yaw_rmse_deg"] == pytest.approx(math.degrees(0.02), abs=1e-9)


def test_rpe_ignores_a_global_rigid_offset_that_ate_sees():
    t, truth = curve()
    T = np.array([3.0, -2.0, math.radians(20.0)])
    c, s = math.cos(T[2]), math.sin(T[2])
    est = np.column_stack(
        [
            T[0] + c * truth[:, 0] - s * truth[:, 1],
            T[1] + s * truth[:, 0] + c * truth[:, 1],
            wrap_angle(truth[:, 2] + T[2]),
        ]
    )
    result = evaluate_trajectory(t, est, t, truth)
    assert result["ate_rmse_m"] > 1.0 and result["yaw_rmse_deg"] == pytest.approx(20.0)
    assert result["rpe_trans_rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert result["rpe_yaw_rmse_deg"] == pytest.approx(0.0, abs=1e-9)


def test_rpe_sees_a_drift_step():
    t, truth = straight_line()
    est = truth.copy()
    est[t >= 10.0, 1] += 0.3  # one jump sideways at 10 s
    result = evaluate_trajectory(t, est, t, truth)
    jumped = np.sum((t < 10.0) & (t + 1.0 >= 10.0 - 1e-9))  # pairs straddling the jump
    expected = math.sqrt(jumped * 0.3**2 / result["rpe_pairs"])
    assert result["rpe_trans_rmse_m"] == pytest.approx(expected, rel=1e-9)


def test_nees_of_errors_drawn_from_the_stated_covariance_is_about_3():
    rng = np.random.default_rng(7)
    t, truth = curve(n=4000, dt=0.05)
    a = rng.normal(size=(len(t), 3, 3)) * [0.2, 0.2, 0.02]
    covs = a @ np.swapaxes(a, 1, 2) + np.diag([1e-3, 1e-3, 1e-5])  # correlated, all different
    errors = np.einsum("nij,nj->ni", np.linalg.cholesky(covs), rng.standard_normal((len(t), 3)))
    est = truth + errors
    result = evaluate_trajectory(t, est, t, truth, covariances=covs)
    assert result["nees_frames"] == len(t)
    assert result["nees_mean"] == pytest.approx(3.0, abs=0.15)  # sd of the mean: 0.04
    assert result["nees_within_95"] == pytest.approx(0.95, abs=0.015)  # sd 0.0034
    overconfident = evaluate_trajectory(t, est, t, truth, covariances=covs / 4)
    assert overconfident["nees_mean"] == pytest.approx(4 * result["nees_mean"])
    assert result["nees_position_mean"] == pytest.approx(2.0, abs=0.12)
    assert result["nees_heading_mean"] == pytest.approx(1.0, abs=0.08)  # sd 0.022
    surer_heading = covs.copy()
    surer_heading[:, 2, :] /= 2  # the heading's sigma halved, its correlations with it
    surer_heading[:, :, 2] /= 2
    turned = evaluate_trajectory(t, est, t, truth, covariances=surer_heading)
    assert turned["nees_heading_mean"] == pytest.approx(4 * result["nees_heading_mean"])
    assert turned["nees_position_mean"] == pytest.approx(result["nees_position_mean"])


def test_chi2_constant():
    # chi-square CDF with 3 degrees of freedom in closed form
    x = CHI2_3DOF_95
    cdf = math.erf(math.sqrt(x / 2)) - math.sqrt(2 * x / math.pi) * math.exp(-x / 2)
    assert cdf == pytest.approx(0.95, abs=1e-12)


def test_covariances_that_are_not_positive_definite_are_left_out_of_nees():
    t, truth = straight_line(10)
    covs = np.tile(np.eye(3), (10, 1, 1))
    covs[3] = 0.0
    est = truth + [0.0, 1.0, 0.0]
    result = evaluate_trajectory(t, est, t, truth, covariances=covs)
    assert result["nees_frames"] == 9 and result["nees_mean"] == pytest.approx(1.0)


def test_lost_and_initializing_frames_are_counted_but_not_scored():
    t, truth = straight_line(50)
    est = truth + [0.0, 0.2, 0.0]
    status = ["tracking"] * 50
    for k in (0, 1, 2):
        status[k] = "initializing"
        est[k] += [50.0, 50.0, 1.0]
    for k in (30, 31):
        status[k] = "lost"
        est[k] += [-9.0, 4.0, 2.0]
    status[32] = "relocalized"
    status[33] = "coasting"
    covs = np.tile(np.diag([0.04, 0.04, 0.01]), (50, 1, 1))
    result = evaluate_trajectory(t, est, t, truth, covariances=covs, status=status)
    json_ready(result)
    assert result["frames"] == 50
    assert result["frames_lost"] == 5
    assert result["frames_evaluated"] == 45
    assert result["status_counts"] == {
        "coasting": 1,
        "initializing": 3,
        "lost": 2,
        "relocalized": 1,
        "tracking": 43,
    }
    assert result["ate_max_m"] == pytest.approx(0.2)
    assert result["nees_mean"] == pytest.approx(1.0)


def test_truth_is_interpolated_at_off_grid_times():
    truth_t = np.arange(0.0, 20.0, 0.1)
    truth = np.column_stack(
        [2.0 * truth_t + 1.0, -truth_t, wrap_angle(math.pi - 0.3 + 0.2 * truth_t)]
    )
    t = np.arange(0.03, 19.9, 0.1)  # 30 ms after each true sample
    est = np.column_stack([2.0 * t + 1.0, -t, wrap_angle(math.pi - 0.3 + 0.2 * t)])
    result = evaluate_trajectory(t, est, truth_t, truth)
    assert result["frames_unmatched"] == 0
    assert result["ate_max_m"] == pytest.approx(0.0, abs=1e-9)
    assert result["yaw_max_deg"] == pytest.approx(0.0, abs=1e-9)
    # a hole in the truth from 5.0 to 6.0 s: frames more than 50 ms from both ends are unmatched
    hole = (truth_t > 5.05) & (truth_t < 5.95)
    holed = evaluate_trajectory(t, est, truth_t[~hole], truth[~hole])
    assert holed["frames_unmatched"] == 9  # 5.13 ... 5.93
    assert holed["frames_evaluated"] == len(t) - 9
    assert holed["ate_max_m"] == pytest.approx(0.0, abs=1e-9)  # 5.03 and 6.03: interpolated
    none = evaluate_trajectory(t + 100.0, est, truth_t, truth)
    assert none["frames_unmatched"] == len(t) and none["ate_rmse_m"] is None
    json_ready(none)


def test_interpolation_takes_the_short_way_round_in_yaw():
    poses, matched = interpolate_poses(
        [0.0, 1.0], [[0.0, 0.0, 3.1], [2.0, 4.0, -3.1]], [0.5, 0.25, -0.01, 1.01], 0.5
    )
    np.testing.assert_array_equal(matched, [True, True, False, False])  # outside the span
    np.testing.assert_allclose(poses[0, :2], [1.0, 2.0])
    assert abs(wrap_angle(poses[0, 2] - math.pi)) < 1e-12
    assert abs(wrap_angle(poses[1, 2] - (3.1 + 0.25 * (2 * math.pi - 6.2)))) < 1e-12
    _, matched = interpolate_poses([0.0, 1.0], [[0, 0, 0], [1, 0, 0]], [0.5, 1.0], 0.05)
    assert matched.tolist() == [False, True]  # 0.5 s from any sample; on the last sample
    _, matched = interpolate_poses([2.0], [[0, 0, 0]], [1.99, 2.0, 2.01], 0.05)
    assert matched.tolist() == [False, True, False]


def test_frames_outside_the_truth_span_are_unmatched():
    t, truth = straight_line(100)
    est_t = t - 2.0  # the first 2 s before the truth starts
    result = evaluate_trajectory(est_t, truth, t, truth)
    assert result["frames_unmatched"] == 20
    assert result["frames_evaluated"] == 80


def test_align_recovers_a_known_transform():
    rng = np.random.default_rng(1)
    t, truth = curve()
    T = np.array([4.0, -1.5, math.radians(-12.0)])
    c, s = math.cos(-T[2]), math.sin(-T[2])
    # the estimate is the truth seen through T^-1, plus small noise
    moved = truth[:, :2] - T[:2]
    est = np.column_stack(
        [
            c * moved[:, 0] - s * moved[:, 1],
            s * moved[:, 0] + c * moved[:, 1],
            wrap_angle(truth[:, 2] - T[2]),
        ]
    )
    exact = evaluate_trajectory(t, est, t, truth, align=True)
    np.testing.assert_allclose(exact["alignment"], [4.0, -1.5, -12.0], atol=1e-9)
    assert exact["ate_rmse_m"] < 1e-9 and exact["yaw_rmse_deg"] < 1e-9
    assert evaluate_trajectory(t, est, t, truth)["ate_rmse_m"] > 1.0
    assert "alignment_skipped" not in exact
    still = np.repeat(est[:1], len(t), axis=0)  # a car that never moves: nothing to fit
    skipped = evaluate_trajectory(t, still, t, truth, align=True)
    assert skipped["alignment"] is None and "not aligned" in skipped["alignment_skipped"]
    assert "alignment_skipped" not in evaluate_trajectory(t, still, t, truth)
    # with noise and an anisotropic covariance turned with the estimate: NEES as unaligned
    cov = np.diag([0.01, 0.0025, 1e-4])
    noise = rng.multivariate_normal(np.zeros(3), cov, size=len(t))
    R3 = np.eye(3)
    R3[:2, :2] = [[c, -s], [s, c]]
    noisy = est + noise @ R3.T
    covs = np.tile(R3 @ cov @ R3.T, (len(t), 1, 1))
    aligned = evaluate_trajectory(t, noisy, t, truth, covariances=covs, align=True)
    np.testing.assert_allclose(aligned["alignment"][:2], [4.0, -1.5], atol=0.03)
    assert aligned["alignment"][2] == pytest.approx(-12.0, abs=0.1)
    reference = evaluate_trajectory(
        t, truth + noise, t, truth, covariances=np.tile(cov, (len(t), 1, 1))
    )
    assert aligned["nees_mean"] == pytest.approx(reference["nees_mean"], rel=0.05)


def test_inputs_that_do_not_fit_are_refused():
    t, truth = straight_line(5)
    with pytest.raises(ValueError, match="covariances"):
        evaluate_trajectory(t, truth, t, truth, covariances=np.zeros((4, 3, 3)))
    with pytest.raises(ValueError, match="statuses"):
        evaluate_trajectory(t, truth, t, truth, status=["lost"])
    with pytest.raises(ValueError, match="strictly increasing"):
        evaluate_trajectory(t[::-1], truth, t, truth)


# --------------------------------------------------------------------------- map segments


def _slot(k: int, x: float) -> Slot:
    corners = np.array([[x, 0.0], [x + 2.5, 0.0], [x + 2.5, 5.0], [x, 5.0]])
    covs = np.stack([default_covariance(0.05)] * 4)
    return Slot(k, None, 0.0, corners, covs, SlotKind.PERPENDICULAR)


def test_map_segments():
    slots = (_slot(0, 0.0), _slot(1, 2.5))
    sides = map_segments(SemanticMap(slots=slots))
    assert sides.shape == (8, 2, 2)
    np.testing.assert_array_equal(sides[1], [[2.5, 0.0], [2.5, 5.0]])
    np.testing.assert_array_equal(sides[3], [[0.0, 5.0], [0.0, 0.0]])
    marking = Marking(np.array([0.0, -3.0]), np.array([9.0, -3.0]), 0.12)
    lines = map_segments(SemanticMap(slots=slots, markings=(marking,)))
    np.testing.assert_array_equal(lines, [[[0.0, -3.0], [9.0, -3.0]]])
    assert map_segments(SemanticMap()).shape == (0, 2, 2)


# --------------------------------------------------------------------------- files and CLI


def _write_run(folder: Path, status_lost: tuple[int, ...] = ()) -> tuple[Path, Path]:
    t, truth = straight_line(60)
    est = truth + [0.0, 0.1, 0.0]
    write_tum(folder / "gt.tum", t, truth)
    write_tum(folder / "run.tum", t, est)
    status = tuple("lost" if k in status_lost else "tracking" for k in range(len(t)))
    write_track_csv(
        folder / "run.csv",
        Track(
            t=t,
            poses=est,
            covariances=np.tile(np.diag([0.01, 0.01, 0.001]), (len(t), 1, 1)),
            status=status,
            associated=np.full(len(t), 4),
            rejected=np.zeros(len(t), dtype=int),
        ),
    )
    return folder / "run.tum", folder / "gt.tum"


def test_files_with_the_track_beside_and_a_map(tmp_path):
    from semslam.pipeline.evaluate import evaluate_trajectory_files

    traj, gt = _write_run(tmp_path, status_lost=(5, 6))
    save_map(tmp_path / "map.json", SemanticMap(slots=(_slot(0, -1.0), _slot(1, 30.0))))
    result = evaluate_trajectory_files(traj, gt, tmp_path / "map.json")
    json_ready(result)
    assert result["track"] == str(tmp_path / "run.csv")
    assert result["map"] == str(tmp_path / "map.json")
    assert result["split_reference"] == "markings"
    assert result["frames_lost"] == 2 and result["frames_evaluated"] == 58
    assert result["nees_mean"] == pytest.approx(1.0, abs=1e-6)  # 0.1^2 / 0.01
    (tmp_path / "run.csv").unlink()
    bare = evaluate_trajectory_files(traj, gt, align=True)
    assert bare["track"] is None and bare["nees_mean"] is None and bare["frames_lost"] == 0
    assert bare["split_reference"] == "heading" and bare["alignment"] is not None


def test_files_that_do_not_fit_are_one_line_errors(tmp_path):
    from semslam.pipeline.evaluate import evaluate_trajectory_files

    traj, gt = _write_run(tmp_path)
    with pytest.raises(FormatError, match=r"nope\.tum: file not found"):
        evaluate_trajectory_files(traj, tmp_path / "nope.tum")
    t, truth = straight_line(60)
    write_tum(traj, t + 0.5, truth)
    with pytest.raises(FormatError, match=r"run\.csv line 2: t 0\.0 differs from .*run\.tum"):
        evaluate_trajectory_files(traj, gt)
    write_tum(traj, t[:-1], truth[:-1])
    with pytest.raises(FormatError, match=r"run\.csv: 60 frames, but .*run\.tum has 59 poses"):
        evaluate_trajectory_files(traj, gt)


def test_cli_evaluate_trajectory(tmp_path):
    from semslam.cli import app

    runner = CliRunner()
    traj, gt = _write_run(tmp_path)
    out = runner.invoke(app, ["evaluate", "trajectory", str(traj), "--truth", str(gt), "--json"])
    assert out.exit_code == 0, out.output
    metrics = json.loads(out.stdout)
    assert metrics["ate_rmse_m"] == pytest.approx(0.1, abs=1e-6)
    table = runner.invoke(app, ["evaluate", "trajectory", str(traj), "--truth", str(gt), "--align"])
    assert table.exit_code == 0, table.output
    assert "ate_rmse_m" in table.stdout and "alignment" in table.stdout
    (tmp_path / "run.csv").write_text("t,x\n1,2\n")
    broken = runner.invoke(app, ["evaluate", "trajectory", str(traj), "--truth", str(gt)])
    assert broken.exit_code == 2
    assert "run.csv line 1" in broken.stderr and len(broken.stderr.strip().splitlines()) == 1


# --------------------------------------------------------------------------- evo


def test_ate_equals_evo_ape_translation(tmp_path):
    pytest.importorskip("evo")
    from evo.core import metrics, sync
    from evo.tools import file_interface

    rng = np.random.default_rng(3)
    truth_t, truth = curve(n=400)
    t = np.append(truth_t[20:390:2], [40.0, 41.0])  # every other true time, two past the end
    est = np.vstack([truth[20:390:2], truth[-2:]]) + rng.normal(size=(len(t), 3)) * [0.2, 0.1, 0.01]
    write_tum(tmp_path / "gt.tum", truth_t, truth)
    write_tum(tmp_path / "est.tum", t, est)

    traj_ref = file_interface.read_tum_trajectory_file(str(tmp_path / "gt.tum"))
    traj_est = file_interface.read_tum_trajectory_file(str(tmp_path / "est.tum"))
    traj_ref, traj_est = sync.associate_trajectories(traj_ref, traj_est)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((traj_ref, traj_est))
    evo_rmse = ape.get_statistic(metrics.StatisticsType.rmse)

    from semslam.pipeline.evaluate import evaluate_trajectory_files

    ours = evaluate_trajectory_files(tmp_path / "est.tum", tmp_path / "gt.tum")
    assert ours["frames_evaluated"] == traj_est.num_poses == len(t) - 2
    assert ours["frames_unmatched"] == 2
    assert ours["ate_rmse_m"] == pytest.approx(evo_rmse, abs=1e-6)
    assert ours["ate_max_m"] == pytest.approx(
        ape.get_statistic(metrics.StatisticsType.max), abs=1e-6
    )
