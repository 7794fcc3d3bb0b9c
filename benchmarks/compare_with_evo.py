"""semslam's trajectory errors against evo's, on the same two TUM files.

evo (Grupp 2017, ``pip install evo``) is the field's reference for trajectory errors; this
script scores one estimate with both and prints each figure side by side:

- ATE: evo's APE on the translation part (``evo_ape tum TRUTH EST``), without and with
  alignment (evo: Umeyama SE(3) on the positions, which for planar poses at z = 0 is the
  SE(2) fit semslam makes);
- RPE over 1 s: evo's RPE on the translation and rotation parts, every pair ``(i, i + k)``
  (``--all_pairs``, ``k`` frames = 1 s), only where the estimate's frames are evenly
  spaced (evo's RPE steps by frames, semslam's by time: a keyframe trajectory has no
  common ground).

Both sides see every frame (no localizer status, so frames marked lost are scored too,
unlike ``semslam evaluate trajectory TRAJ.tum`` beside its ``TRAJ.csv``). evo pairs frames
by the nearest time stamp within ``max_diff``; semslam interpolates the truth at the
estimate's times; on a simulated drive both have the truth at every frame time, so the
figures should agree to rounding.

Usage::

    PYTHONPATH=. python benchmarks/compare_with_evo.py TRAJ.tum TRUTH.tum [--json]
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from semslam.evaluation.trajectory_metrics import RPE_DELTA_S, evaluate_trajectory  # noqa: E402
from semslam.io.tum import read_tum  # noqa: E402


def semslam_figures(est: Path, truth: Path) -> dict[str, float]:
    t, poses = read_tum(est)
    tt, truth_poses = read_tum(truth)
    plain = evaluate_trajectory(t, poses, tt, truth_poses)
    aligned = evaluate_trajectory(t, poses, tt, truth_poses, align=True)
    return {
        "frames": plain["frames_evaluated"],
        "ate_rmse_m": plain["ate_rmse_m"],
        "ate_mean_m": plain["ate_mean_m"],
        "ate_median_m": plain["ate_median_m"],
        "ate_max_m": plain["ate_max_m"],
        "ate_aligned_rmse_m": aligned["ate_rmse_m"],
        "rpe_pairs": plain["rpe_pairs"],
        "rpe_trans_rmse_m": plain["rpe_trans_rmse_m"],
        "rpe_yaw_rmse_deg": plain["rpe_yaw_rmse_deg"],
    }


def evo_figures(est: Path, truth: Path, max_diff: float) -> dict[str, float]:
    from evo.core import metrics, sync
    from evo.tools import file_interface

    traj_ref = file_interface.read_tum_trajectory_file(str(truth))
    traj_est = file_interface.read_tum_trajectory_file(str(est))
    traj_ref, traj_est = sync.associate_trajectories(traj_ref, traj_est, max_diff=max_diff)

    def ape(ref, est_) -> dict[str, float]:
        m = metrics.APE(metrics.PoseRelation.translation_part)
        m.process_data((ref, est_))
        return m.get_all_statistics()

    plain = ape(traj_ref, traj_est)
    aligned_est = copy.deepcopy(traj_est)
    aligned_est.align(traj_ref, correct_scale=False)
    aligned = ape(traj_ref, aligned_est)
    out = {
        "frames": traj_est.num_poses,
        "ate_rmse_m": plain["rmse"],
        "ate_mean_m": plain["mean"],
        "ate_median_m": plain["median"],
        "ate_max_m": plain["max"],
        "ate_aligned_rmse_m": aligned["rmse"],
    }
    dt = np.diff(traj_est.timestamps)
    if dt.max() > 1.01 * dt.min():
        return out
    step = int(round(RPE_DELTA_S / float(np.median(dt))))
    rpe = {}
    for relation, key in (
        (metrics.PoseRelation.translation_part, "trans"),
        (metrics.PoseRelation.rotation_angle_deg, "yaw"),
    ):
        m = metrics.RPE(relation, delta=step, delta_unit=metrics.Unit.frames, all_pairs=True)
        m.process_data((traj_ref, traj_est))
        rpe[key] = m
    return out | {
        "rpe_pairs": len(rpe["trans"].error),
        "rpe_trans_rmse_m": rpe["trans"].get_statistic(metrics.StatisticsType.rmse),
        "rpe_yaw_rmse_deg": rpe["yaw"].get_statistic(metrics.StatisticsType.rmse),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("trajectory", type=Path, help="the estimate (TUM)")
    parser.add_argument("truth", type=Path, help="the true trajectory (TUM)")
    parser.add_argument(
        "--max-diff", type=float, default=0.01, help="evo's time association, s (default 0.01)"
    )
    parser.add_argument("--json", action="store_true", help="print JSON only")
    args = parser.parse_args(argv)
    ours = semslam_figures(args.trajectory, args.truth)
    theirs = evo_figures(args.trajectory, args.truth, args.max_diff)
    rows = [
        {"figure": k, "semslam": ours[k], "evo": theirs[k], "difference": ours[k] - theirs[k]}
        for k in ours
        if k in theirs
    ]
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print("| figure | semslam | evo | semslam - evo |")
    print("| --- | --- | --- | --- |")
    for r in rows:
        if isinstance(r["semslam"], int):
            print(f"| {r['figure']} | {r['semslam']} | {r['evo']} | {r['difference']} |")
        else:
            print(
                f"| {r['figure']} | {r['semslam']:.6f} | {r['evo']:.6f} | {r['difference']:.1e} |"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
