"""Terminal output: results as rich tables (the CLI's only printing besides errors)."""

from __future__ import annotations

from rich.console import Console
from rich.table import Table

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
