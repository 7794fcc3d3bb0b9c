"""Where the mapper's iSAM2 time goes on a long drive: every update's time, and at every
relinearisation check how many variables move and the step of a few watched poses.

Maps a simulated drive (noisy observations) with the default configuration (changed by
``SEMSLAM_MAPPING__...`` variables) and prints the checks that moved more than ``--show``
variables, then a summary per 500 keyframes (updates, total and median update time, of it
the time spent linearising the factors in Python, median and largest number of variables
iSAM2 re-eliminated, median nonzeros of the Bayes tree). A step that changes sign from one
check to the next at the same pose is Gauss-Newton swinging, not new information.

``--cliques-at K ...`` prints iSAM2's Bayes-tree statistics (``printStats``: average and
largest conditional and separator, in variables) after the update at or past keyframe K.
``--null-sides`` counts at every check the factors with a null-hypothesis loss (one-candidate
slot sightings, painted-line detections) that sit on their null side at iSAM2's
linearisation point but on the measurement's at its current estimate, and the other way
(slow: every such factor is evaluated twice per check, inside the timed updates).
``--step-costs`` prints, at every check that moves more than ``--show`` variables, the error of
the factors in iSAM2 at its linearisation point, after the whole step (iSAM2's estimate), with
only the variables relinearised moved (the new linearisation point), and after half and a
quarter of the whole step (slow: the whole graph evaluated five times per such check).

    PYTHONPATH=. python benchmarks/profile_relinearisation.py DRIVE [--watch 1000 2000 3000]
        [--cliques-at 2500 4000 5300] [--null-sides] [--step-costs]
"""

from __future__ import annotations

import argparse
import time

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

from semslam.config import load_config
from semslam.io import Drive
from semslam.mapping.mapper import Mapper
from semslam.mapping.maxmix import is_null_chosen


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("drive")
    parser.add_argument("--watch", type=int, nargs="+", default=[1000, 2000, 3000])
    parser.add_argument("--show", type=int, default=300, help="checks moving more than this")
    parser.add_argument("--cliques-at", type=int, nargs="*", default=[])
    parser.add_argument("--null-sides", action="store_true")
    parser.add_argument("--step-costs", action="store_true",
                        help="at checks moving more than --show variables, the graph's error "
                        "at the linearisation point and after the step, whole and halved")
    args = parser.parse_args()
    cliques_at = sorted(args.cliques_at)
    drive = Drive.open(args.drive)
    odometry = drive.odometry()
    mapper = Mapper(load_config(None).mapping, drive.start_pose, odometry.t, odometry.speed,
                    odometry.yaw_rate)
    graph = mapper.graph
    updates: list[tuple[int, float, int]] = []  # (keyframes, seconds, re-eliminated)
    linearising: list[float] = []  # seconds of each update spent in Graph._linearized
    nonzeros: list[int] = []  # of the Bayes tree after each update
    checks: list[dict] = []
    timed_update, predicted = graph.update, graph._relinearized_by_isam2
    timed_linearized = graph._linearized
    spent = [0.0]

    def linearized(index: int):
        start = time.perf_counter()
        factor = timed_linearized(index)
        spent[0] += time.perf_counter() - start
        return factor

    def update() -> None:
        spent[0] = 0.0
        start = time.perf_counter()
        timed_update()
        keyframes = len(mapper.keyframe_times)
        updates.append((keyframes, time.perf_counter() - start,
                        graph.last_result.getVariablesReeliminated()))
        linearising.append(spent[0])
        nonzeros.append(graph.isam.treeNnz())
        while cliques_at and keyframes >= cliques_at[0]:
            print(f"--- Bayes tree after the update at keyframe {keyframes}, "
                  f"{graph._theta.size()} variables", flush=True)
            graph.isam.printStats()
            cliques_at.pop(0)

    def relinearised() -> list[int]:
        delta = graph.isam.getDelta()
        steps = {k: np.round(delta.at(X(k)), 3).tolist() for k in args.watch
                 if delta.exists(X(k))}
        sides = null_sides() if args.null_sides else None
        before = gtsam.Values(graph._theta) if args.step_costs else None
        moved = predicted()
        costs = step_costs(before, delta) if before is not None and len(moved) > args.show else None
        checks.append({"keyframes": len(mapper.keyframe_times), "moved": len(moved),
                       "variables": graph._theta.size(), "steps": steps, "sides": sides,
                       "costs": costs})
        return moved

    def step_costs(before: gtsam.Values, delta: gtsam.VectorValues) -> list[float]:
        """The error of the factors in iSAM2 at the linearisation point, after the whole
        step, after the step of the variables relinearised only, and after half and a
        quarter of the whole step."""
        factors = gtsam.NonlinearFactorGraph()
        for i in range(graph._in_isam):
            factors.add(graph.factors.at(i))
        return [factors.error(before), factors.error(before.retract(delta)),
                factors.error(graph._theta), factors.error(before.retract(delta.scale(0.5))),
                factors.error(before.retract(delta.scale(0.25)))]

    def null_sides() -> tuple[int, int, int]:
        """(factors with a null-hypothesis loss, null at the linearisation point but not at
        the estimate, the other way round)."""
        estimate = graph.isam.calculateEstimate()
        total = stuck = freed = 0
        for i in range(graph._in_isam):
            factor = graph.factors.at(i)
            if not isinstance(factor.noiseModel(), gtsam.noiseModel.Robust):
                continue
            total += 1
            at_point = is_null_chosen(factor, graph._theta, mapper.null)
            at_estimate = is_null_chosen(factor, estimate, mapper.null)
            stuck += at_point and not at_estimate
            freed += at_estimate and not at_point
        return total, stuck, freed

    graph.update, graph._relinearized_by_isam2 = update, relinearised
    graph._linearized = linearized
    start = time.perf_counter()
    for frame in drive.observations("noisy"):
        mapper.add_frame(frame)
    print(f"incremental pass {time.perf_counter() - start:.1f} s, "
          f"{len(updates)} updates {sum(t for _, t, _ in updates):.1f} s")
    took = {k: t for k, t, _ in updates}
    for c in checks:
        if c["moved"] > args.show:
            print(f"keyframe {c['keyframes']}: {c['moved']} of {c['variables']} moved, "
                  f"{took.get(c['keyframes'], 0.0):.2f} s; steps {c['steps']}")
            if c["costs"]:
                print("    error at the point / whole step / relinearised only / half / quarter: "
                      + " / ".join(f"{e:.1f}" for e in c["costs"]))
    if args.null_sides:
        print("| check at keyframe | null-hypothesis factors | null at the linearisation point "
              "only | null at the estimate only |")
        print("|---|---|---|---|")
        for c in checks:
            print(f"| {c['keyframes']} | {c['sides'][0]} | {c['sides'][1]} | {c['sides'][2]} |")
    kf = np.array([k for k, _, _ in updates])
    dt = np.array([t for _, t, _ in updates])
    redone = np.array([n for _, _, n in updates])
    lin, nnz = np.array(linearising), np.array(nonzeros)
    print(f"of the updates' {dt.sum():.1f} s, {lin.sum():.1f} s linearising in Python")
    print("| keyframes | updates | seconds | of it linearising s | median ms | "
          "re-eliminated: median / largest | tree nonzeros, median |")
    print("|---|---|---|---|---|---|---|")
    for lo in range(0, int(kf.max()) + 1, 500):
        sel = (kf >= lo) & (kf < lo + 500)
        if sel.any():
            print(f"| {lo}-{lo + 499} | {sel.sum()} | {dt[sel].sum():.1f} | {lin[sel].sum():.1f} | "
                  f"{1e3 * np.median(dt[sel]):.0f} | {np.median(redone[sel]):.0f} / "
                  f"{redone[sel].max()} | {np.median(nnz[sel]):.0f} |")


if __name__ == "__main__":
    main()
