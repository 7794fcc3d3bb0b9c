"""The command summaries: what they say."""

from io import StringIO
from pathlib import Path

from rich.console import Console

from semslam.pipeline.mapping import MapSummary
from semslam.reporting import nothing_mapped_reason, print_map_summary


def _summary(statistics: dict, slots: int = 3, tags: int = 1) -> MapSummary:
    return MapSummary(Path("m.json"), "d", "noisy", 10, 1.0, 0.1, slots, tags, statistics)


def _printed(statistics: dict, slots: int = 3, tags: int = 1) -> str:
    out = StringIO()
    summary = _summary(statistics, slots, tags)
    print_map_summary(summary, Console(file=out, width=120))
    return out.getvalue()


def test_the_map_summary_says_when_covariances_did_not_come_from_the_graph():
    assert "covariances not from the graph" not in _printed({"marginal_fallbacks": 0})
    text = _printed({"marginal_fallbacks": 1792})
    assert "covariances not from the graph" in text and "1792" in text


def test_an_empty_map_says_why_it_is_empty():
    assert nothing_mapped_reason(_summary({"keyframes": 40})) is None
    assert nothing_mapped_reason(_summary({"keyframes": 40}, slots=0, tags=2)) is None
    standing = _summary({"keyframes": 1, "slot_observations": 9}, slots=0, tags=0)
    assert "never moved" in nothing_mapped_reason(standing)
    blind = _summary({"keyframes": 40, "slot_observations": 0}, slots=0, tags=0)
    assert "no slot or tag" in nothing_mapped_reason(blind)
    unconfirmed = _summary({"keyframes": 40, "slot_observations": 3, "pooled": 3}, 0, 0)
    assert "3 sightings left in the pool" in nothing_mapped_reason(unconfirmed)
    assert "nothing mapped" in _printed({"keyframes": 1}, slots=0, tags=0)
    assert "nothing mapped" not in _printed({"keyframes": 40})
