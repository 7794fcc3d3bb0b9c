"""Predicted accuracy against the filter's errors, and tag placement (issue 8, Hofmann / TiEV).

    PYTHONPATH=. python benchmarks/bench_predicted_accuracy.py [--seeds 1 2 3]
        [--counts 3 5 10] [--draws 20] [--no-placement] [--json out.json]

Per seed:

1. **Consistency.** Simulates drive 1 of the `garage` world (`semslam simulate --drive 1
   --no-images`), localizes it against the world's TRUE map (`semslam localize --map
   world.json --observations noisy`, with ``marking_map_sigma`` 0: the true map's lines
   are exact, and its slots carry zero covariance), and predicts the covariance along the
   true route
   (``groundtruth.tum``, every frame) with :mod:`semslam.analysis.accuracy`: Hofmann's
   ideal filter (default :class:`SensorModel`) with the ``simulator`` grade (the
   simulator's white wheel-speed and gyro noise in the grade's ``sigma^2 * t``
   convention, see :func:`simulator_grade`) and with the ``automotive`` grade; and the
   ``localizer`` grade, what ``semslam accuracy --grade localizer`` computes: semslam's
   localizer as configured (:func:`localizer_grade`, :func:`localizer_model`) on the
   simulator's detectors (:func:`simulated_sensors`). Per frame the position error ``e``
   (estimate minus truth, map frame, m) and ``NEES = e^T P[:2, :2]^-1 e`` against each
   prediction and against the filter's own covariance (the CSV beside the trajectory);
   the localizer grade's sigma against the filter's own frame by frame; the NEES split by
   what is in view. A consistent covariance gives mean NEES 2 and 95 % of frames under
   the chi-square(2) 95 % bound 5.991. Frames are correlated: the bounds on the mean are
   given for one independent sample per 1 s block (optimistic: the filter's errors last
   longer than that), for the effective number of independent samples (the frames over
   the NEES series' integrated autocorrelation time, :func:`correlation_time`) and per
   frame.
2. **Tag placement.** The same world's map without its tags, the drive's true route at
   1 m steps, candidates every 5 m, 3 m beside it; for K in ``--counts``: greedy,
   evenly spread and ``--draws`` random placements (seed 0): the worst, the 95th
   percentile and the mean over the worst 5 % of the route's poses of the filtered sigma
   (automotive grade).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import report, run_semslam
from scipy.stats import chi2

from semslam.analysis.accuracy import (
    GRADES,
    MapGeometry,
    OdometryGrade,
    filter_route,
    localizer_grade,
    localizer_model,
    predicted_along_route,
    route_information,
    simulated_sensors,
)
from semslam.analysis.tag_placement import (
    candidate_tags,
    even_placement,
    greedy_placement,
    placement_spread,
    random_placement,
    resample_route,
)
from semslam.config import load_config
from semslam.evaluation.trajectory_metrics import interpolate_poses
from semslam.io import Drive, load_map, read_track_csv, read_tum
from semslam.types import SemanticMap

SITUATIONS = ("slots/tags >= 2", "1 slot/tag", "lines only", "nothing")

BOUND_95 = float(chi2.ppf(0.95, 2))  # 5.991
EXACT_LINES = {"SEMSLAM_LOCALIZATION__MARKING_MAP_SIGMA": "0"}


def simulator_grade() -> OdometryGrade:
    """The simulator's odometry noise as an :class:`OdometryGrade`.

    The simulator adds white noise of ``sigma`` (m/s, rad/s) to every odometry sample at
    ``f`` Hz (``semslam/simulation/driver.py``). Integrated over ``t`` seconds it gives
    ``t * f`` independent steps of ``sigma / f`` each: variance ``sigma^2 * t / f``. The
    grade adds ``grade_sigma^2 * t``, so ``grade_sigma = sigma / sqrt(f)`` (m/s * sqrt(s)
    for speed, rad/s * sqrt(s) for the rate, here converted to degrees). The per-drive
    speed scale error (1 %) and gyro bias (1e-4 rad/s + walk) are not white and have no
    place in this convention: they are left out (what that costs is measured below).
    The first frame sees slots, so the initial heading is the frame's own (0 deg floor).
    """
    sim = load_config(None).simulation
    root_f = math.sqrt(sim.drive.odometry_rate)
    noise = sim.odometry_noise
    return OdometryGrade("simulator", noise.speed_sigma / root_f, 0.0,
                         math.degrees(noise.gyro_sigma / root_f))


def correlation_time(x: np.ndarray) -> float:
    """Integrated autocorrelation time of a series, in samples: ``1 + 2 sum rho_k`` over the
    lags up to the first negative autocorrelation (Geyer's initial positive sequence). The
    mean of ``N`` correlated samples has the variance of ``N / tau`` independent ones."""
    d = np.asarray(x, float) - np.mean(x)
    n = len(d)
    if n < 3 or not np.any(d):
        return 1.0
    spectrum = np.fft.rfft(d, 2 * n)
    acf = np.fft.irfft(spectrum * np.conj(spectrum))[:n]
    rho = acf / acf[0]
    negative = np.flatnonzero(rho[1:] < 0)
    last = int(negative[0]) if len(negative) else n - 1
    return float(max(1.0, 1.0 + 2.0 * rho[1 : last + 1].sum()))


def consistency(errors: np.ndarray, covs: np.ndarray, t: np.ndarray, yaw: np.ndarray) -> dict:
    """NEES of position errors (N, 2; m, map frame) against covariances (N, 2, 2; m^2) at
    times t (s); also both split along and across the true heading ``yaw`` (N,; rad)."""
    finite = np.all(np.isfinite(covs.reshape(len(covs), -1)), axis=1)
    e, P, t, yaw = errors[finite], covs[finite], t[finite], yaw[finite]
    u = np.column_stack([np.cos(yaw), np.sin(yaw)])  # along the travel
    v = np.column_stack([-u[:, 1], u[:, 0]])  # across, to the left
    nees = np.einsum("ni,nij,nj->n", e, np.linalg.inv(P), e)
    sigma = np.sqrt(np.linalg.eigvalsh(P)[:, -1])
    n_blocks = len(np.unique(np.floor(t - t[0])))

    def bounds(n: float) -> list[float]:
        return [round(float(chi2.ppf(q, 2 * n) / n), 3) for q in (0.025, 0.975)]

    n_effective = len(nees) / correlation_time(nees)

    return {
        "frames": int(len(e)),
        "frames_unobservable": int((~finite).sum()),
        "nees_mean": round(float(nees.mean()), 2),
        "nees_median": round(float(np.median(nees)), 2),
        "share_within_5.991": round(float((nees <= BOUND_95).mean()), 3),
        "mean_bounds_95_1s_blocks": bounds(n_blocks),
        "mean_bounds_95_frames": bounds(len(e)),
        "mean_bounds_95_effective": bounds(n_effective),
        "blocks_1s": n_blocks,
        "effective_samples": round(float(n_effective), 1),
        "sigma_median_m": round(float(np.median(sigma)), 4),
        "error_median_m": round(float(np.median(np.hypot(*e.T))), 4),
        "sigma_p95_m": round(float(np.percentile(sigma, 95)), 4),
        "error_p95_m": round(float(np.percentile(np.hypot(*e.T), 95)), 4),
        **{f"{name}_rms_{side}_m": round(float(np.sqrt(np.mean(value))), 4)
           for side, w in (("along", u), ("across", v))
           for name, value in (("error", np.einsum("ni,ni->n", e, w) ** 2),
                               ("sigma", np.einsum("ni,nij,nj->n", w, P, w)))},
    }


def odometry_errors(drive_dir: Path) -> dict:
    """The drive's odometry against its truth: wheel-scale error (integrated speed over
    the true path length, minus 1) and the mean gyro bias (integrated yaw rate minus the
    true heading change, over the duration; deg/s)."""
    drive = Drive.open(drive_dir)
    odo = drive.odometry()
    t, poses = drive.groundtruth()
    dt = np.diff(odo.t)
    scale = np.sum(odo.speed[:-1] * dt) / np.hypot(*np.diff(poses[:, :2], axis=0).T).sum() - 1
    turn = np.sum(np.remainder(np.diff(poses[:, 2]) + math.pi, 2 * math.pi) - math.pi)
    bias = (np.sum(odo.yaw_rate[:-1] * dt) - turn) / (t[-1] - t[0])
    return {"scale_error": round(float(scale), 4),
            "gyro_bias_deg_s": round(math.degrees(float(bias)), 4)}


def nees_run(root: Path, seed: int) -> dict:
    """Simulate, localize against the true map, predict along the true route; the NEES."""
    drive = root / f"s{seed}d1"
    run_semslam(["simulate", str(drive), "--preset", "garage", "--seed", str(seed),
                 "--drive", "1", "--no-images"])
    out = root / f"s{seed}.tum"
    # the true map's painted lines are exact: the localizer (and below, its prediction) is
    # told so, as it would be for a surveyed map; its slots say so themselves (zero
    # covariance)
    run_semslam(["localize", str(drive), "--map", str(drive / "world.json"), "-o", str(out),
                 "--observations", "noisy", "--no-progress"], EXACT_LINES)
    truth_t, truth = read_tum(drive / "groundtruth.tum")
    track = read_track_csv(out.with_suffix(".csv"))
    has_pose = np.all(np.isfinite(track.poses), axis=1)
    est, ok = interpolate_poses(track.t[has_pose], track.poses[has_pose], truth_t)
    # the filter's own covariance at the truth times: its frame times are the same
    nearest = np.clip(np.searchsorted(track.t, truth_t), 0, len(track.t) - 1)
    own = track.covariances[nearest][:, :2, :2]
    ok &= np.all(np.isfinite(own.reshape(len(own), -1)), axis=1)
    errors = (est[:, :2] - truth[:, :2])[ok]

    started = time.perf_counter()
    cfg = load_config(None)
    cfg = cfg.model_copy(update={"localization": cfg.localization.model_copy(
        update={"marking_map_sigma": 0.0})})
    world = load_map(drive / "world.json")
    geometry = MapGeometry(world)
    infos, _ = route_information(geometry, truth)  # Hofmann: SensorModel(), ideal filter
    predictions = {g.name: filter_route(infos, truth, truth_t, g)[:, :2, :2]
                   for g in (simulator_grade(), GRADES["automotive"])}
    model = localizer_model(cfg.localization)
    along = predicted_along_route(
        MapGeometry.for_model(world, model), truth, truth_t,
        localizer_grade(cfg.localization, cfg.simulation.drive.odometry_rate),
        simulated_sensors(cfg.simulation.observation_noise), model)
    predictions["localizer"] = along["covariance"][:, :2, :2]
    predictions["filter_own"] = own
    row = {"seed": seed, "frames": len(truth_t), "route_m": round(float(
        np.hypot(*np.diff(truth[:, :2], axis=0).T).sum()), 1)}
    for name, P in predictions.items():
        row[name] = consistency(errors, P[ok], truth_t[ok], truth[ok, 2])
    # the prediction against the localizer's own covariance, frame by frame
    P, Q = predictions["localizer"][ok], own[ok]
    ratio = np.sqrt(np.linalg.eigvalsh(P)[:, -1] / np.linalg.eigvalsh(Q)[:, -1])
    row["localizer_vs_own"] = {
        "sigma_ratio_median": round(float(np.median(ratio)), 3),
        "sigma_ratio_p5": round(float(np.percentile(ratio, 5)), 3),
        "sigma_ratio_p95": round(float(np.percentile(ratio, 95)), 3),
        "trace_ratio_mean": round(float(np.mean(np.trace(P, axis1=1, axis2=2)
                                                 / np.trace(Q, axis1=1, axis2=2))), 3)}
    # by what is in view (the simulator's detectors, as the localizer prediction counts)
    landmarks = (along["slots"] + along["tags"])[ok]
    lines = along["lines"][ok]
    parts = dict(zip(SITUATIONS, (landmarks >= 2, landmarks == 1,
                                  (landmarks == 0) & (lines > 0), (landmarks == 0) & (lines == 0)),
                     strict=True))
    row["by_view"] = {}
    for part_name, part in parts.items():
        if not part.any():
            continue
        cell = {"frames": int(part.sum())}
        for name in ("localizer", "filter_own", "automotive"):
            sub = consistency(errors[part], predictions[name][ok][part], truth_t[ok][part],
                              truth[ok, 2][part])
            cell[name] = {k: sub[k] for k in ("nees_mean", "sigma_median_m", "error_median_m",
                                              "error_rms_along_m", "error_rms_across_m",
                                              "sigma_rms_along_m", "sigma_rms_across_m")}
        row["by_view"][part_name] = cell
    row["odometry"] = odometry_errors(drive)
    blind = parts["nothing"]
    if blind.any():
        yaw = truth[ok, 2][blind]
        along_err = errors[blind, 0] * np.cos(yaw) + errors[blind, 1] * np.sin(yaw)
        row["blind_seconds"] = round(float(blind.sum() * np.median(np.diff(truth_t))), 1)
        row["blind_along_error_max_m"] = round(float(np.abs(along_err).max()), 3)
    row["grade_simulator"] = {k: getattr(simulator_grade(), k) for k in (
        "speed_sigma", "heading_sigma_deg", "rate_sigma_deg")}
    row["predict_s"] = round(time.perf_counter() - started, 1)
    return row


def placement_run(root: Path, seed: int, counts: list[int], draws: int, grade_name: str) -> dict:
    """Greedy vs evenly spread vs random tags on the world's map without its own tags."""
    drive = root / f"s{seed}d1"
    world = load_map(drive / "world.json")
    no_tags = SemanticMap(world.slots, (), world.markings)
    t, poses = read_tum(drive / "groundtruth.tum")
    poses, t = resample_route(poses, t, 1.0)
    grade = GRADES[grade_name]
    infos, _ = route_information(MapGeometry(no_tags), poses)
    cands = candidate_tags(poses, 5.0, 3.0)
    started = time.perf_counter()
    greedy = greedy_placement(infos, poses, t, cands, max(counts), grade)
    greedy_s = time.perf_counter() - started
    rng = np.random.default_rng(0)
    rows = []
    base = greedy[0]
    for k in counts:
        g = greedy[min(k, len(greedy) - 1)]
        e = even_placement(infos, poses, t, cands, k, grade)
        spread = placement_spread([random_placement(infos, poses, t, cands, k, grade, rng)
                                   for _ in range(draws)])
        rows.append({"count": k, "greedy": _summary(g), "even": _summary(e), "random": spread})
    return {"seed": seed, "grade": grade_name, "route_poses": len(poses),
            "candidates": len(cands), "draws": draws, "no_tags": _summary(base),
            "counts": rows, "greedy_s": round(greedy_s, 1)}


def _summary(step) -> dict[str, float]:
    return {k: getattr(step, k) for k in ("worst_m", "p95_m", "worst5_mean_m")}


def markdown(nees: list[dict], placement: list[dict]) -> str:
    lines = ["| seed | covariance | mean NEES | 95 % bounds: 1 s blocks / effective samples | "
             "median NEES | NEES <= 5.991 | sigma median | error median | sigma p95 | "
             "error p95 |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for row in nees:
        for key, label in (("simulator", "predicted, simulator grade"),
                           ("automotive", "predicted, automotive grade"),
                           ("localizer", "**predicted, localizer grade**"),
                           ("filter_own", "filter's own")):
            c = row[key]
            lo, hi = c["mean_bounds_95_1s_blocks"]
            elo, ehi = c["mean_bounds_95_effective"]
            lines.append(f"| {row['seed']} | {label} | {c['nees_mean']} | {lo}-{hi} / "
                         f"{elo}-{ehi} ({c['effective_samples']:.0f}) | "
                         f"{c['nees_median']} | {100 * c['share_within_5.991']:.1f} % | "
                         f"{c['sigma_median_m']:.3f} m | {c['error_median_m']:.3f} m | "
                         f"{c['sigma_p95_m']:.3f} m | {c['error_p95_m']:.3f} m |")
    lines += ["", "The localizer grade's predicted sigma over the filter's own, frame by frame: "
              "median (5th-95th percentile); mean trace ratio:", "",
              "| seed | sigma ratio | trace ratio |", "| --- | --- | --- |"]
    for row in nees:
        r = row["localizer_vs_own"]
        lines.append(f"| {row['seed']} | {r['sigma_ratio_median']} ({r['sigma_ratio_p5']}-"
                     f"{r['sigma_ratio_p95']}) | {r['trace_ratio_mean']} |")
    lines += ["", "By what is in view (slots + tags; painted lines): frames, mean NEES "
              "against the localizer grade / the filter's own covariance / the automotive "
              "grade, sigma median of the localizer grade and of the filter's own, error "
              "median, RMS error along / across the travel against the localizer grade's "
              "(m):", "",
              "| seed | in view | frames | NEES: localizer / own / automotive | sigma: localizer "
              "/ own | error median | along / across RMS: error vs localizer sigma |",
              "| --- | --- | --- | --- | --- | --- | --- |"]
    for row in nees:
        for part, cell in row["by_view"].items():
            loc, own, auto = cell["localizer"], cell["filter_own"], cell["automotive"]
            lines.append(
                f"| {row['seed']} | {part} | {cell['frames']} | {loc['nees_mean']} / "
                f"{own['nees_mean']} / {auto['nees_mean']} | {loc['sigma_median_m']:.4f} / "
                f"{own['sigma_median_m']:.4f} | {loc['error_median_m']:.4f} | "
                f"{loc['error_rms_along_m']:.4f} / {loc['error_rms_across_m']:.4f} vs "
                f"{loc['sigma_rms_along_m']:.4f} / {loc['sigma_rms_across_m']:.4f} |")
        lines.append(f"| {row['seed']} | odometry | | scale error "
                     f"{row['odometry']['scale_error']}, gyro bias "
                     f"{row['odometry']['gyro_bias_deg_s']} deg/s | nothing in view "
                     f"{row.get('blind_seconds', 0)} s | along-track error up to "
                     f"{row.get('blind_along_error_max_m', 0)} m | |")
    if placement:
        keys = ("worst_m", "p95_m", "worst5_mean_m")
        lines += ["", "Filtered sigma on the route, m: worst / 95th percentile / mean of the "
                  "worst 5 %; random: median over the draws (best-worst).", "",
                  "| seed | K | greedy | evenly spread | random worst | random p95 | "
                  "random worst-5 % mean |", "| --- | --- | --- | --- | --- | --- | --- |"]

        def triple(d: dict) -> str:
            return " / ".join(f"{d[k]:.3f}" for k in keys)

        for p in placement:
            lines.append(f"| {p['seed']} | 0 | {triple(p['no_tags'])} | | | | |")
            for r in p["counts"]:
                rand = " | ".join(f"{r['random'][k]['median']:.3f} ({r['random'][k]['best']:.3f}"
                                  f"-{r['random'][k]['worst']:.3f})" for k in keys)
                lines.append(f"| {p['seed']} | {r['count']} | {triple(r['greedy'])} | "
                             f"{triple(r['even'])} | {rand} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[1])
    parser.add_argument("--counts", nargs="+", type=int, default=[3, 5, 10])
    parser.add_argument("--draws", type=int, default=20)
    parser.add_argument("--grade", choices=sorted(GRADES), default="automotive",
                        help="odometry grade of the tag placement comparison")
    parser.add_argument("--no-placement", action="store_true")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    if min(args.counts) < 1 or args.draws < 1:
        parser.error("--counts and --draws must be at least 1")
    nees, placement = [], []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for seed in args.seeds:
            nees.append(nees_run(root, seed))
            print(json.dumps(nees[-1]), flush=True)
            if not args.no_placement:
                placement.append(placement_run(root, seed, sorted(args.counts), args.draws,
                                               args.grade))
                print(json.dumps(placement[-1]), flush=True)
    report(markdown(nees, placement), {"consistency": nees, "placement": placement}, args.json)


if __name__ == "__main__":
    main()
