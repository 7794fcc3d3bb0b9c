"""Localization benchmark (issue 4): accuracy, consistency, auto-init, kidnap, speed.

Simulates a `garage` world twice (drive 0 to map, drive 1 to localize), maps drive 0 with
`semslam map`, then localizes drive 1 with `semslam localize` in both update modes and with
markings only, scores each with `semslam evaluate trajectory`, and runs the relocalization
trials through the library (100 random starts with `--init auto`; kidnaps of 10 m).

    python benchmarks/bench_localization.py [--seeds 1 2 3] [--starts 100] [--kidnaps 20]
        [--observability-only] [--plan-tags K] [--trials-only]

``--plan-tags K``: first plan up to K tags for relocalization on drive 0's route through the
bare world (`semslam plan-tags --objective relocalization`; ``--plan-routes 0 1``: on both
drives' routes; either way only tags drive 0 sees, `--mapping-route`, since drive 0 is the
one mapped), then simulate both drives with them (`semslam simulate --tags`): what the
garage would give with the tags semslam proposes.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import run_semslam

KEYS = ["ate_rmse_m", "ate_p95_m", "yaw_rmse_deg", "parallel_mean_m", "orthogonal_mean_m",
        "nees_mean", "frames", "frames_lost"]


run = run_semslam


def localize_and_score(drive: Path, map_path: Path, out: Path, env: dict[str, str]) -> dict:
    started = time.perf_counter()
    run(["localize", str(drive), "--map", str(map_path), "-o", str(out), "--observations",
         "noisy", "--no-progress"], env)
    elapsed = time.perf_counter() - started
    metrics = json.loads(run(["evaluate", "trajectory", str(out), "--truth",
                              str(drive / "groundtruth.tum"), "--map", str(map_path), "--json"]))
    return {**{k: metrics.get(k) for k in KEYS}, "wall_s": round(elapsed, 1)}


def _truth_at(truth_t, truth_poses, t):
    i = int(np.clip(np.searchsorted(truth_t, t), 1, len(truth_t) - 1))
    a = (t - truth_t[i - 1]) / (truth_t[i] - truth_t[i - 1])
    p = truth_poses[i - 1] + a * (truth_poses[i] - truth_poses[i - 1])
    p[2] = truth_poses[i - 1][2] + a * math.remainder(truth_poses[i][2] - truth_poses[i - 1][2],
                                                      2 * math.pi)
    return p


def _error(pose, truth):
    return float(np.hypot(*(pose[:2] - truth[:2]))), abs(math.degrees(
        math.remainder(pose[2] - truth[2], 2 * math.pi)))


def relocalization_trials(drive_dir: Path, map_path: Path, starts: int, kidnaps: int,
                          seed: int) -> dict:
    """Random starts with no pose (time to the first pose, ``auto_init_within_2s``, and to
    the first within 0.5 m and 5 deg of the truth, ``auto_init_right_within_2s``; a first
    pose outside those is counted in ``auto_init_wrong``) and 10 m kidnaps (time until the
    error is below 0.5 m again).

    Besides the rates over all trials, the rates over the *observable* ones: trials in
    which the exact sensor sees at least one slot or tag within the time allowed (2 s for
    a start, 3 s after a kidnap). Stretches of the simulated route see nothing at all
    (the perimeter lane behind the tag walls); no method can find a pose there."""
    from semslam.config import load_config
    from semslam.io import Drive, load_map
    from semslam.localization.localizer import Localizer

    cfg = load_config(None).localization
    drive = Drive.open(drive_dir)
    odo = drive.odometry()
    frames = drive.observations("noisy")
    exact = drive.observations("exact")
    truth_t, truth_poses = drive.groundtruth()

    def observable(first: int, seconds: float) -> bool:
        return _sees(exact, first, seconds, lines=False)

    semantic_map = load_map(map_path)
    rng = np.random.default_rng(seed)
    found_s, right_s, wrong, start_seen = [], [], 0, []
    for start in _random_starts(rng, len(frames), starts):
        start_seen.append(observable(int(start), 2.0))
        keep = odo.t >= frames[start].t - 1e-9
        loc = Localizer(semantic_map, cfg, odo.t[keep], odo.speed[keep], odo.yaw_rate[keep])
        took = right = None
        for frame in frames[start : start + 100]:
            est = loc.step(frame)
            if np.all(np.isfinite(est.pose)):
                e_pos, e_yaw = _error(est.pose, _truth_at(truth_t, truth_poses, frame.t))
                off = e_pos > 0.5 or e_yaw > 5
                if took is None:
                    took = frame.t - frames[start].t
                    wrong += off
                if not off:
                    right = frame.t - frames[start].t
                    break
            if took is not None and frame.t - frames[start].t > 2.0:
                break
        found_s.append(took)
        right_s.append(right)
    recover_s, kidnap_seen = [], []
    for k in rng.integers(200, len(frames) - 100, kidnaps):
        kidnap_seen.append(observable(int(k), 3.0))
        loc = Localizer(semantic_map, cfg, odo.t, odo.speed, odo.yaw_rate, drive.start_pose)
        for frame in frames[: k]:
            loc.step(frame)
        direction = rng.uniform(0, 2 * math.pi)
        loc.filter.x[:2] += 10.0 * np.array([math.cos(direction), math.sin(direction)])
        took = None
        for frame in frames[k : k + 100]:
            est = loc.step(frame)
            e_pos, _ = _error(est.pose, _truth_at(truth_t, truth_poses, frame.t))
            if e_pos < 0.5 and est.status in ("tracking", "relocalized"):
                took = frame.t - frames[k].t
                break
        recover_s.append(took)
    found = [s for s in found_s if s is not None]
    recovered = [s for s in recover_s if s is not None]

    def rate(times: list, seen: list, limit: float) -> float | None:
        ok = [t is not None and t <= limit for t, v in zip(times, seen, strict=True) if v]
        return round(sum(ok) / len(ok), 3) if ok else None

    return {
        "auto_init_starts": starts,
        "auto_init_within_2s": sum(s <= 2.0 for s in found) / max(starts, 1),
        "auto_init_right_within_2s": sum(s is not None and s <= 2.0 for s in right_s)
        / max(starts, 1),
        "auto_init_observable_starts": sum(start_seen),
        "auto_init_within_2s_observable": rate(found_s, start_seen, 2.0),
        "auto_init_median_s": float(np.median(found)) if found else None,
        "auto_init_wrong": wrong,
        "kidnaps": kidnaps,
        "kidnap_recovered_within_3s": sum(s <= 3.0 for s in recovered) / max(kidnaps, 1),
        "kidnaps_observable": sum(kidnap_seen),
        "kidnap_recovered_within_3s_observable": rate(recover_s, kidnap_seen, 3.0),
        "kidnap_recovery_median_s": float(np.median(recovered)) if recovered else None,
        "kidnap_recovery_max_s": float(np.max(recovered)) if recovered else None,
    }


def _random_starts(rng: np.random.Generator, frames: int, starts: int) -> np.ndarray:
    """The trials' start frames (the first draws of the trials' generator)."""
    return rng.integers(0, frames - 100, starts)


def _sees(exact: list, first: int, seconds: float, lines: bool) -> bool:
    """Does the exact sensor report a slot or tag (or, with ``lines``, a painted line) in
    the ``seconds`` from frame ``first`` on?"""
    t0 = exact[first].t
    for f in exact[first:]:
        if f.t - t0 > seconds:
            return False
        if f.slots or f.tags or (lines and f.markings):
            return True
    return False


def start_observability(drive_dir: Path, starts: int, seed: int) -> dict:
    """Of the relocalization trials' random starts (the same draws), how many see a slot or
    tag within 2 s, how many only painted lines, how many nothing at all: the share of
    starts any method could localize from within 2 s is at most 1 - nothing / starts."""
    from semslam.io import Drive

    exact = Drive.open(drive_dir).observations("exact")
    rng = np.random.default_rng(seed)
    first = [int(k) for k in _random_starts(rng, len(exact), starts)]
    landmarks = sum(_sees(exact, k, 2.0, lines=False) for k in first)
    anything = sum(_sees(exact, k, 2.0, lines=True) for k in first)
    return {"starts": starts, "slot_or_tag_within_2s": landmarks,
            "only_lines_within_2s": anything - landmarks, "nothing_within_2s": starts - anything}


def plan_relocalization_tags(root: Path, seed: int, count: int, within: float = 2.0,
                             routes: tuple[int, ...] = (0,)) -> dict:
    """Up to ``count`` tags planned for relocalization (a slot or tag within ``within`` s) on
    the routes of drives ``routes`` through the bare `garage` world ``seed`` (several routes
    joined end to end, 1,000 s apart), each seen by drive 0, the one mapped: the plan's JSON
    (its file under ``root``)."""
    from semslam.io import read_tum, write_tum

    times, poses = [], []
    for k in sorted(set(routes) | {0}):
        run(["simulate", str(root / f"s{seed}bare{k}"), "--preset", "garage", "--seed", str(seed),
             "--drive", str(k), "--no-images"])
    for k in routes:
        bare = root / f"s{seed}bare{k}"
        t, p = read_tum(bare / "groundtruth.tum")
        times.append(t + (times[-1][-1] + 1000.0 if times else 0.0))
        poses.append(p)
    route = root / f"s{seed}routes.tum"
    write_tum(route, np.concatenate(times), np.concatenate(poses))
    out = root / f"s{seed}plan"
    run(["plan-tags", str(bare / "world.json"), "--route", str(route),
         "-o", str(out), "--count", str(count), "--objective", "relocalization",
         "--within", str(within), "--random-trials", "1",
         "--mapping-route", str(root / f"s{seed}bare0" / "groundtruth.tum")])
    return json.loads((out / "tag_plan.json").read_text()) | {"file": str(out / "tag_plan.json")}


def simulate_and_map(root: Path, seed: int, tags: str | None = None) -> tuple[Path, Path]:
    """Drives 0 and 1 of the `garage` world ``seed`` simulated under ``root`` (no images;
    with the tags of the plan file ``tags`` added), drive 0 mapped with noisy observations:
    drive 1's folder and the map's path."""
    d0, d1 = root / f"s{seed}d0", root / f"s{seed}d1"
    extra = [] if tags is None else ["--tags", tags]
    run(["simulate", str(d0), "--preset", "garage", "--seed", str(seed), "--no-images", *extra])
    run(["simulate", str(d1), "--preset", "garage", "--seed", str(seed), "--drive", "1",
         "--no-images", *extra])
    map_path = root / f"s{seed}.map.json"
    run(["map", str(d0), "-o", str(map_path), "--observations", "noisy", "--no-progress"])
    return d1, map_path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[1])
    parser.add_argument("--starts", type=int, default=100)
    parser.add_argument("--kidnaps", type=int, default=20)
    parser.add_argument("--observability-only", action="store_true",
                        help="only count what the random starts can see (no map, no filter)")
    parser.add_argument("--plan-tags", type=int, default=0, metavar="K",
                        help="add up to K tags planned for relocalization to the world")
    parser.add_argument("--plan-within", type=float, default=2.0, metavar="S",
                        help="the plan's time to see a slot or tag, s (default 2)")
    parser.add_argument("--plan-routes", type=int, nargs="+", default=[0], metavar="DRIVE",
                        help="the drives whose routes the plan covers (default: 0, the one "
                        "mapped)")
    parser.add_argument("--trials-only", action="store_true",
                        help="skip the localization runs; only the relocalization trials")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for seed in args.seeds:
            tags = None
            if args.plan_tags:
                plan = plan_relocalization_tags(root, seed, args.plan_tags, args.plan_within,
                                                tuple(args.plan_routes))
                tags = plan["file"]
                print(json.dumps({"seed": seed, "planned_tags": len(plan["proposed_tags"]),
                                  "candidates_unmapped": plan["candidates_unmapped"],
                                  "coverage": [s["relocalization_coverage"]
                                               for s in plan["greedy"]]}), flush=True)
            if args.observability_only:
                d1 = root / f"s{seed}d1"
                run(["simulate", str(d1), "--preset", "garage", "--seed", str(seed), "--drive",
                     "1", "--no-images", *([] if tags is None else ["--tags", tags])])
                rows.append({"seed": seed, **start_observability(d1, args.starts, seed)})
                print(json.dumps(rows[-1]), flush=True)
                continue
            d1, map_path = simulate_and_map(root, seed, tags)
            variants = {
                "ekf (default)": {},
                "sigma points (Houben)": {"SEMSLAM_LOCALIZATION__UPDATE": "sigma"},
                "markings only": {"SEMSLAM_LOCALIZATION__USE_SLOTS": "false",
                                  "SEMSLAM_LOCALIZATION__USE_TAGS": "false"},
            }
            for name, env in ({} if args.trials_only else variants).items():
                out = root / f"s{seed}-{len(rows)}.tum"
                row = {"seed": seed, "variant": name,
                       **localize_and_score(d1, map_path, out, env)}
                track = out.with_suffix(".csv")
                row["update_ms_median"] = _median_update_ms(d1, map_path, env)
                del track
                rows.append(row)
                print(json.dumps(row), flush=True)
            if args.starts or args.kidnaps:
                trials = relocalization_trials(d1, map_path, args.starts, args.kidnaps, seed)
                print(json.dumps({"seed": seed, **trials}), flush=True)
                rows.append({"seed": seed, "variant": "relocalization", **trials})
    print(json.dumps(rows, indent=1))


def _median_update_ms(drive_dir: Path, map_path: Path, env: dict[str, str]) -> float:
    """Median per-frame association + update time (ms), measured in this process."""
    from semslam.config import load_config
    from semslam.io import Drive, load_map
    from semslam.localization.localizer import Localizer

    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        cfg = load_config(None).localization
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    drive = Drive.open(drive_dir)
    odo = drive.odometry()
    loc = Localizer(load_map(map_path), cfg, odo.t, odo.speed, odo.yaw_rate, drive.start_pose)
    times = [loc.step(f).update_ms for f in drive.observations("noisy")]
    return round(float(np.median(times)), 3)


if __name__ == "__main__":
    main()
