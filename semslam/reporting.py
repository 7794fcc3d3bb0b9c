"""Terminal output: results as rich tables (the CLI's only printing besides errors)."""

from __future__ import annotations

import json
import math
from typing import Any

from rich.console import Console
from rich.table import Table

from semslam.pipeline.mapping import MapSummary
from semslam.pipeline.simulate import SimulationSummary


def print_simulation_summary(summary: SimulationSummary, console: Console | None = None) -> None:
    """A two-column table of what ``simulate`` wrote."""
    console = console or Console()
    table = Table(title=f"semslam simulate -> {summary.folder}", show_header=False)
    table.add_column(style="bold")
    table.add_column(justify="right")
    rows = [
        ("world", f"{summary.preset}, seed {summary.seed}"),
        ("drive", str(summary.drive_index)),
        ("slots / tags / markings", f"{summary.slots} / {summary.tags} / {summary.markings}"),
        ("driving time", f"{summary.duration_s:.1f} s"),
        ("distance", f"{summary.distance_m:.0f} m"),
        ("frames", str(summary.frames)),
        ("images", "yes" if summary.images else "no"),
        ("took", f"{summary.seconds:.1f} s"),
    ]
    for k, v in rows:
        table.add_row(k, v)
    console.print(table)


def print_metrics(
    title: str, metrics: dict[str, Any], as_json: bool, console: Console | None = None
) -> None:
    """Metrics as JSON (for scripts) or as a table (for people)."""
    if as_json:
        print(json.dumps(metrics, indent=2, allow_nan=False))
        return
    console = console or Console()
    table = Table(title=title, show_header=False)
    table.add_column(style="bold")
    table.add_column(justify="right")
    for key, value in metrics.items():
        if isinstance(value, float):
            value = f"{value:.4g}"
        table.add_row(key, "-" if value is None else str(value))
    console.print(table)


def print_map_summary(summary: MapSummary, console: Console | None = None) -> None:
    """What ``semslam map`` built and how fast."""
    console = console or Console()
    stats = summary.statistics
    table = Table(title=f"semslam map -> {summary.map_path}", show_header=False)
    table.add_column(style="bold")
    table.add_column(justify="right")
    rows = [
        ("drive", f"{summary.drive} ({summary.observations} observations)"),
        ("frames / keyframes", f"{summary.frames} / {stats.get('keyframes', '-')}"),
        ("slots / tags mapped", f"{summary.slots} / {summary.tags}"),
        ("slot observations", str(stats.get("slot_observations", "-"))),
        (
            "accepted / null / pooled",
            f"{stats.get('accepted', '-')} / {stats.get('null', '-')} / {stats.get('pooled', '-')}",
        ),
        ("duplicates merged", str(stats.get("merged", "-"))),
        (
            "odometry scale, gyro bias",
            f"{stats.get('odometry_scale', '-')}, {stats.get('gyro_bias_rad_s', 0.0):.2e} rad/s",
        ),
        ("driving / mapping time", f"{summary.driving_s:.1f} s / {summary.mapping_s:.1f} s"),
        ("faster than driving", f"{stats.get('speedup', '-')}x"),
    ]
    refused = stats.get("tag_conflicts", 0) + stats.get("tag_size_mismatches", 0)
    if refused:  # an ID at two places, or of another size: the sightings left out
        rows.append((
            "tag sightings not used (another place / size under an ID)",
            f"{stats.get('tag_conflicts', 0)} / {stats.get('tag_size_mismatches', 0)}",
        ))
    if stats.get("marginal_fallbacks"):  # gtsam refused their covariance: a rough one instead
        rows.append(("covariances not from the graph", str(stats["marginal_fallbacks"])))
    reason = nothing_mapped_reason(summary)
    if reason:
        rows.append(("nothing mapped", reason))
    for k, v in rows:
        table.add_row(k, v)
    console.print(table)


def nothing_mapped_reason(summary: MapSummary) -> str | None:
    """Why a map holds no slot and no tag, in words, or None when it holds some."""
    if summary.slots or summary.tags:
        return None
    stats = summary.statistics
    if stats.get("keyframes", 0) <= 1:
        return ("the car never moved a keyframe step (mapping.keyframe_distance / "
                "keyframe_angle_deg); slots are confirmed over several keyframes")
    if not stats.get("slot_observations"):
        return "the observations hold no slot or tag"
    return (f"no slot was seen from enough keyframes to be confirmed "
            f"({stats.get('pooled', 0)} sightings left in the pool)")


def print_localize_summary(summary, console: Console | None = None) -> None:
    """What ``semslam localize`` did: frames by status, time to the first pose, speed."""
    console = console or Console()
    table = Table(title=f"semslam localize -> {summary.trajectory}", show_header=False)
    table.add_column(style="bold")
    table.add_column(justify="right")
    first = summary.first_pose_after_s
    rows = [
        ("frames / with a pose", f"{summary.frames} / {summary.frames_with_pose}"),
        ("first pose after", "-" if first is None else f"{first:.1f} s"),
        *(
            (f"frames {status}", str(n))
            for status, n in sorted(summary.status_counts.items())
        ),
        ("association + update, median", f"{summary.update_ms_median:.2f} ms / frame"),
        ("driving / localizing time", f"{summary.driving_s:.1f} s / {summary.elapsed_s:.1f} s"),
        ("track (pose, covariance, status)", str(summary.track)),
    ]
    if summary.odometry_errors is not None:
        (scale, bias), (scale_sigma, bias_sigma) = summary.odometry_errors
        rows.insert(-1, ("wheel-speed scale error, estimated",
                         f"{100 * scale:+.2f} % +- {100 * scale_sigma:.2f} %"))
        rows.insert(-1, ("gyro bias, estimated", f"{math.degrees(bias):+.4f} +- "
                         f"{math.degrees(bias_sigma):.4f} deg/s"))
    for k, v in rows:
        table.add_row(k, v)
    console.print(table)
