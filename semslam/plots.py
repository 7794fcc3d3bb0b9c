"""Pictures a person would rather look at than read (matplotlib, PNG bytes; no file I/O).

- :func:`map_figure`: slots with their IDs, tags, painted lines and 3-sigma corner
  ellipses (optionally over the true map).
- :func:`trajectory_figure`: the estimated trajectory over the truth, coloured by error.
- :func:`error_figure`: position error and 3-sigma bound over time, with the status.
- :func:`audit_figure`: what became of the slot observations (accepted, reassigned,
  null hypothesis, pooled), overall and per slot.
- :func:`accuracy_figure`, :func:`tag_plan_figure`: predicted accuracy (grid and route)
  and proposed tags with accuracy against their number.
"""

from __future__ import annotations

import io
import math
from collections import Counter
from collections.abc import Sequence

import numpy as np

from semslam.geometry import FloatArray
from semslam.types import SemanticMap

STATUS_COLOURS = {
    "tracking": "#2ca02c",
    "coasting": "#ffbf00",
    "relocalized": "#1f77b4",
    "initializing": "#9467bd",
    "lost": "#d62728",
}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _png(fig) -> bytes:
    plt = _plt()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _ellipse(mean: FloatArray, cov: FloatArray, k: float = 3.0, n: int = 40) -> FloatArray:
    w, v = np.linalg.eigh(np.asarray(cov, float))
    a = np.linspace(0.0, 2 * math.pi, n)
    circle = np.stack([np.cos(a), np.sin(a)], axis=1) * k * np.sqrt(np.maximum(w, 0.0))
    return np.asarray(mean, float) + circle @ v.T


def _outline(
    ax, semantic_map: SemanticMap, slots: str, lines: str, tags: str | None, width: float
) -> None:
    """The map's slots and painted lines as thin outlines, its tags as squares (if a
    colour is given). One collection per kind: a plot call per slot cost seconds on a
    garage of thousands."""
    _polylines(ax, [np.vstack([s.corners, s.corners[:1]]) for s in semantic_map.slots],
               color=slots, lw=width)
    _polylines(ax, [np.array([m.a, m.b]) for m in semantic_map.markings], color=lines, lw=width)
    if tags is not None and semantic_map.tags:
        xy = np.array([t.mTt[:2] for t in semantic_map.tags])
        ax.plot(xy[:, 0], xy[:, 1], "s", color=tags, ms=5, ls="none")


def _polylines(ax, paths: Sequence[FloatArray], **style) -> None:
    """Draw ``paths`` (each (n, 2)) as one line collection and widen the axes' limits to
    them, as a plot call per path would."""
    if not paths:
        return
    from matplotlib.collections import LineCollection

    ax.add_collection(LineCollection([np.asarray(p, float) for p in paths], **style))
    ax.autoscale_view()


def map_figure(
    semantic_map: SemanticMap, truth: SemanticMap | None = None, title: str = "map"
) -> bytes:
    """Slots (blue, with labels), tags (red), lines (grey), 3-sigma corner ellipses (x10,
    orange) and, if given, the true slots underneath (light green)."""
    plt = _plt()
    pts = [s.corners for s in semantic_map.slots] + [np.array([[0.0, 0.0]])]
    span = np.ptp(np.concatenate(pts), axis=0)
    aspect = (span[1] + 10) / max(span[0] + 10, 1.0)
    fig, ax = plt.subplots(figsize=(14, max(4.0, 14 * aspect)), dpi=100)
    if truth is not None:
        _polylines(ax, [np.vstack([s.corners, s.corners[:1]]) for s in truth.slots],
                   color="#a6dba0", lw=2.5, zorder=1)
    _polylines(ax, [np.array([m.a, m.b]) for m in semantic_map.markings], color="0.55", lw=0.8,
               zorder=2)
    _polylines(ax, [np.vstack([s.corners, s.corners[:1]]) for s in semantic_map.slots],
               color="#1f4e9c", lw=0.9, zorder=3)
    _polylines(  # 3 sigma, drawn x10
        ax,
        [_ellipse(corner, np.asarray(cov) * 100.0) for s in semantic_map.slots
         for corner, cov in zip(s.corners, s.corner_covariances, strict=True)],
        color="#ff7f0e", lw=0.6, zorder=4,
    )
    for s in semantic_map.slots:
        if s.label:
            centre = s.corners.mean(axis=0)
            ax.text(
                centre[0],
                centre[1],
                s.label,
                fontsize=6,
                ha="center",
                va="center",
                color="#1f4e9c",
                alpha=0.4 + 0.6 * s.label_confidence,
                zorder=5,
            )
    for t in semantic_map.tags:
        x, y, yaw = t.mTt
        ax.plot(x, y, "s", color="#d62728", ms=6, zorder=6)
        ax.annotate(
            "",
            (x + 1.5 * math.cos(yaw), y + 1.5 * math.sin(yaw)),
            (x, y),
            arrowprops={"arrowstyle": "->", "color": "#d62728"},
            zorder=6,
        )
        ax.text(x + 0.6, y + 0.6, str(t.tag_id), fontsize=7, color="#d62728", zorder=6)
    ax.set_aspect("equal")
    ax.set_xlabel("x, m")
    ax.set_ylabel("y, m")
    ax.set_title(
        f"{title}: {len(semantic_map.slots)} slots, {len(semantic_map.tags)} tags, "
        f"{len(semantic_map.markings)} lines (corner ellipses: 3 sigma, drawn x10"
        + ("; green: truth)" if truth is not None else ")")
    )
    return _png(fig)


def trajectory_figure(
    estimate: FloatArray,
    truth: FloatArray,
    error: FloatArray,
    semantic_map: SemanticMap | None = None,
    title: str = "trajectory",
) -> bytes:
    """The estimated positions (N, 2+) coloured by position error (m), over the true ones
    (N, 2+, grey) and the map's slots."""
    plt = _plt()
    from matplotlib.collections import LineCollection

    estimate, truth = np.asarray(estimate, float), np.asarray(truth, float)
    span = np.ptp(truth[:, :2], axis=0)
    fig, ax = plt.subplots(figsize=(14, max(4.0, 14 * (span[1] + 10) / (span[0] + 10))), dpi=100)
    if semantic_map is not None:
        _outline(
            ax,
            SemanticMap(slots=semantic_map.slots),
            slots="0.8",
            lines="0.8",
            tags=None,
            width=0.6,
        )
    ax.plot(truth[:, 0], truth[:, 1], color="0.4", lw=3.0, alpha=0.4, label="truth")
    seg = np.stack([estimate[:-1, :2], estimate[1:, :2]], axis=1)
    hi = max(float(np.percentile(error, 99)), 0.05)
    lc = LineCollection(seg, cmap="plasma", norm=plt.Normalize(0.0, hi), linewidths=1.8)
    lc.set_array(np.asarray(error, float)[1:])
    ax.add_collection(lc)
    fig.colorbar(lc, ax=ax, fraction=0.025, label="position error, m")
    ax.set_aspect("equal")
    ax.legend(loc="upper right")
    ax.set_xlabel("x, m")
    ax.set_ylabel("y, m")
    ax.set_title(title)
    return _png(fig)


def error_figure(
    t: FloatArray,
    error: FloatArray,
    sigma: FloatArray,
    status: Sequence[str],
    title: str = "position error over time",
) -> bytes:
    """Position error (m) and the filter's 3-sigma bound over time, the status as a
    coloured band underneath."""
    plt = _plt()
    t, error, sigma = (np.asarray(v, float) for v in (t, error, sigma))
    fig, (ax, band) = plt.subplots(
        2, 1, figsize=(14, 4.5), dpi=100, sharex=True, gridspec_kw={"height_ratios": [5, 1]}
    )
    ax.plot(t, error, color="#1f77b4", lw=1.0, label="position error")
    ax.plot(t, 3 * sigma, color="#ff7f0e", lw=0.8, ls="--", label="3 sigma (reported)")
    ax.set_ylabel("m")
    ax.set_ylim(0, max(float(np.percentile(error, 99.5)) * 1.3, 0.05))
    ax.legend(loc="upper right")
    ax.grid(alpha=0.3)
    ax.set_title(title)
    codes = {name: k for k, name in enumerate(STATUS_COLOURS)}
    from matplotlib.colors import ListedColormap

    band.imshow(
        np.array([[codes.get(s, 0) for s in status]]),
        aspect="auto",
        cmap=ListedColormap(list(STATUS_COLOURS.values())),
        vmin=-0.5,
        vmax=len(STATUS_COLOURS) - 0.5,
        extent=(t[0], t[-1], 0, 1),
    )
    band.set_yticks([])
    band.set_xlabel("time, s")
    counts = Counter(status)
    band.set_title(
        "  ".join(f"{k}: {counts.get(k, 0)}" for k in STATUS_COLOURS), fontsize=8, loc="left"
    )
    return _png(fig)


def audit_figure(
    audit_rows: Sequence[dict], per_slot: Sequence[dict], title: str = "association audit"
) -> bytes:
    """The fate of every slot observation: totals over the drive (the rows of
    ``MAP.audit.jsonl``) and per mapped slot (``MAP.audit.json``'s ``slots``, sorted by
    observations): accepted, went to another slot, left to the null hypothesis."""
    plt = _plt()
    statuses = ("accepted", "reassigned", "null", "pooled")
    colours = ("#2ca02c", "#1f77b4", "#d62728", "#bbbbbb")
    totals = Counter(r.get("status") for r in audit_rows)
    fig, (ax, bx) = plt.subplots(
        1, 2, figsize=(14, 4), dpi=100, gridspec_kw={"width_ratios": [1, 4]}
    )
    ax.bar(range(len(statuses)), [totals.get(s, 0) for s in statuses], color=colours)
    ax.set_xticks(range(len(statuses)), statuses, fontsize=8)
    ax.set_title("all slot observations")
    for k, s in enumerate(statuses):
        ax.text(k, totals.get(s, 0), str(totals.get(s, 0)), ha="center", va="bottom", fontsize=8)
    parts = (("accepted", "#2ca02c"), ("went_to_other_slot", "#1f77b4"), ("null", "#d62728"))
    counts = np.array([[len(s.get(k, ())) for k, _ in parts] for s in per_slot], float)
    counts = counts.reshape(-1, len(parts))
    order = np.argsort(-counts.sum(axis=1), kind="stable")
    bottom = np.zeros(len(order))
    for k, (name, colour) in enumerate(parts):
        h = counts[order, k]
        bx.bar(
            np.arange(len(order)),
            h,
            bottom=bottom,
            color=colour,
            width=1.0,
            label=name.replace("_", " "),
        )
        bottom += h
    bx.set_xlabel("mapped slot (by number of observations)")
    bx.set_ylabel("observations")
    bx.legend(loc="upper right")
    bx.set_title(title)
    return _png(fig)


def accuracy_figure(
    semantic_map: SemanticMap,
    xs: FloatArray,
    ys: FloatArray,
    grid: FloatArray,
    route_xy: FloatArray | None,
    route_sigma: FloatArray | None,
    threshold: float,
) -> bytes:
    """Predicted accuracy: the grid's single-frame sigma (H, W over ``xs``, ``ys``) as a
    heat map under the map, and the route (N, 2) coloured by its filtered sigma (m)."""
    plt = _plt()
    from matplotlib.collections import LineCollection

    width = max(xs[-1] - xs[0], 1.0)
    height = max(ys[-1] - ys[0], 1.0)
    fig, ax = plt.subplots(figsize=(12, max(3.0, 12 * height / width) + 1), dpi=110)
    shown = np.where(np.isfinite(grid), grid, np.nan)
    image = ax.imshow(
        shown,
        origin="lower",
        extent=(xs[0], xs[-1], ys[0], ys[-1]),
        cmap="viridis_r",
        vmin=0.0,
        vmax=max(
            float(np.nanpercentile(shown, 95)) if np.isfinite(shown).any() else threshold, 1e-3
        ),
        alpha=0.8,
    )
    fig.colorbar(
        image,
        ax=ax,
        fraction=0.04,
        pad=0.08,
        orientation="horizontal",
        label="single-frame sigma, m (worst heading)",
    )
    _outline(ax, semantic_map, slots="white", lines="0.85", tags="red", width=0.6)
    if route_xy is not None and len(route_xy) > 1:
        segments = np.stack([route_xy[:-1], route_xy[1:]], axis=1)
        sig = np.minimum(np.where(np.isfinite(route_sigma), route_sigma, 10.0), 10.0)[1:]
        lc = LineCollection(segments, cmap="RdYlGn_r", norm=plt.Normalize(0.0, 2 * threshold))
        lc.set_array(sig)
        lc.set_linewidth(2.5)
        ax.add_collection(lc)
        fig.colorbar(lc, ax=ax, fraction=0.025, label="filtered sigma on the route, m")
    ax.set_aspect("equal")
    ax.set_xlabel("x, m")
    ax.set_ylabel("y, m")
    ax.set_title("predicted positioning accuracy (red squares: tags)")
    return _png(fig)


def tag_plan_figure(
    semantic_map: SemanticMap,
    poses: FloatArray,
    steps: Sequence,
    even: Sequence,
    random: Sequence[dict] | None = None,
    coverage: Sequence[float] | None = None,
) -> bytes:
    """Proposed tags (numbered, in order) along the route, and the worst / 95th-percentile
    sigma against the number of tags, greedy and evenly spread
    (:class:`~semslam.analysis.tag_placement.PlacementStep` lists) and, if given, random
    (``{"count": K, "worst_m": {"median", "best", "worst"}}`` per K: median and range) and
    the relocalization coverage of each greedy step (share of the route, right axis)."""
    plt = _plt()

    fig, (ax, bx) = plt.subplots(
        1, 2, figsize=(15, 5.5), dpi=100, gridspec_kw={"width_ratios": [2.6, 1]}
    )
    _outline(ax, semantic_map, slots="0.6", lines="0.75", tags="0.3", width=0.5)
    ax.plot(poses[:, 0], poses[:, 1], color="tab:blue", lw=1.0)
    for s in steps[1:]:
        x, y, yaw = s.tag
        ax.plot(x, y, "s", color="red", ms=7)
        ax.annotate(
            "",
            (x + 2.0 * math.cos(yaw), y + 2.0 * math.sin(yaw)),
            (x, y),
            arrowprops={"arrowstyle": "->", "color": "red"},
        )
        ax.text(x + 0.8, y + 0.8, str(s.count), color="red", fontsize=9, weight="bold")
    ax.set_aspect("equal")
    ax.set_title("proposed tags (red, in order; grey: the map's)")
    ks = [s.count for s in steps]
    bx.plot(ks, [s.worst_m for s in steps], "o-", label="greedy: worst")
    bx.plot(ks, [s.p95_m for s in steps], "o--", label="greedy: 95th percentile")
    bx.plot([e.count for e in even], [e.worst_m for e in even], "s-", label="evenly spread: worst")
    if random:
        rk = [r["count"] for r in random]
        line = bx.plot(rk, [r["worst_m"]["median"] for r in random], "^-",
                       label="random: worst (median, range)")
        bx.fill_between(rk, [r["worst_m"]["best"] for r in random],
                        [r["worst_m"]["worst"] for r in random], color=line[0].get_color(),
                        alpha=0.15, lw=0)
    bx.axhline(0.2, color="0.5", lw=0.8, ls=":")
    bx.set_xlabel("tags added")
    bx.set_ylabel("filtered position sigma on the route, m")
    bx.legend()
    bx.grid(alpha=0.3)
    if coverage is not None:
        cx = bx.twinx()
        cx.plot(ks, [100.0 * c for c in coverage], "d:", color="tab:purple")
        cx.set_ylabel("route poses relocalizable from (purple), %", color="tab:purple")
    return _png(fig)


__all__ = [
    "accuracy_figure",
    "audit_figure",
    "error_figure",
    "map_figure",
    "tag_plan_figure",
    "trajectory_figure",
]
