"""The command summaries: what they say."""

from io import StringIO
from pathlib import Path

from rich.console import Console

from semslam.pipeline.mapping import MapSummary
from semslam.reporting import print_map_summary


def _printed(statistics: dict) -> str:
    out = StringIO()
    summary = MapSummary(Path("m.json"), "d", "noisy", 10, 1.0, 0.1, 3, 1, statistics)
    print_map_summary(summary, Console(file=out, width=120))
    return out.getvalue()


def test_the_map_summary_says_when_covariances_did_not_come_from_the_graph():
    assert "covariances not from the graph" not in _printed({"marginal_fallbacks": 0})
    text = _printed({"marginal_fallbacks": 1792})
    assert "covariances not from the graph" in text and "1792" in text
