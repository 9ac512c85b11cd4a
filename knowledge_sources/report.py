"""Plots of results files: what a person would rather look at than read.

Pure functions from results (and the scenario they came from) to figures, separate from the
command that writes them (:mod:`knowledge_sources.commands.report`):

* :func:`plot_positions`: the map with true and estimated positions, joined, coloured by right/wrong;
* :func:`plot_frame`: a camera frame beside the chosen viewframe, with both preprocessed edge images;
* :func:`plot_rankings`: each frame's five best error variances, relative to the best;
* :func:`plot_queries`: detector questions per frame, one series per results file (strategy);
* :func:`plot_track`: the map with the track (the tracker's estimates, joined in time order)
  against the true path, the single-frame estimates faint beside it;
* :func:`plot_belief`: the tracker's belief over the route points against time (frames), the
  true route point and the track on top, lost frames marked.

World coordinates are ``(x, y)`` metres, x east, y north; images are shown row 0 at the top.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

__all__ = ["plot_positions", "plot_frame", "plot_rankings", "plot_queries", "plot_track", "plot_belief"]


def plot_positions(results: dict[str, Any], *, terrain, landmarks, route, poses) -> Figure:
    """The map with each frame's true position (x) joined to its estimate (o), a legend and
    the elevation colour bar."""
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    from models.overview import plot_map

    fig, ax = plt.subplots(figsize=(9, 7))
    plot_map(ax, terrain, landmarks, route, poses)
    h = terrain.heights
    bar = ScalarMappable(norm=Normalize(float(h.min()), float(h.max())), cmap=plt.get_cmap("gist_earth"))
    fig.colorbar(bar, ax=ax, shrink=0.8, label="elevation (m, hillshaded on the map)")
    handles = [
        Line2D([], [], color="black", lw=1.0, label="route"),
        Line2D([], [], marker="o", ls="", mfc="yellow", mec="black", label="viewframes (route points)"),
        Patch(color="red", label="landmarks"),
        Line2D([], [], marker="x", ls="", color="black", label="true position"),
        Line2D([], [], marker="o", ls="-", mfc="none", color="tab:green", label="estimate, right"),
        Line2D([], [], marker="o", ls="-", mfc="none", color="tab:red", label="estimate, wrong"),
    ]
    ax.legend(handles=handles, loc="upper left", fontsize=7, framealpha=0.85)
    for f in results["frames"]:
        if f["truth"] is None:
            continue
        tx, ty = f["truth"][:2]
        ax.plot(tx, ty, "x", color="black", ms=6, zorder=5)
        if f["position"] is not None:
            ex, ey = f["position"]
            color = "tab:green" if f["correct"] else "tab:red"
            ax.plot([tx, ex], [ty, ey], "-", color=color, lw=1, zorder=5)
            ax.plot(ex, ey, "o", mfc="none", color=color, ms=7, zorder=6)
    pts = np.asarray(route, dtype=float)
    margin = max(150.0, 0.15 * float(np.ptp(pts, axis=0).max()))
    ax.set_xlim(pts[:, 0].min() - margin, pts[:, 0].max() + margin)
    ax.set_ylim(pts[:, 1].min() - margin, pts[:, 1].max() + margin)
    s = results["summary"]
    top1 = "n/a" if s["top1"] is None else f"{s['top1']:.0%}"
    ax.set_title(f"{results['scenario']} ({results['strategy']}): true x, estimate o; top-1 {top1}")
    fig.tight_layout()
    return fig


def plot_frame(
    frame: dict[str, Any],
    camera_image: np.ndarray,
    viewframe_image: np.ndarray | None,
    *,
    pattern: Callable[[np.ndarray], np.ndarray],
) -> Figure:
    """A camera frame beside the chosen viewframe, and both edge images as the memory sees them
    (``pattern``: the index's preprocessing, :meth:`models.index.ViewframeIndex.pattern`)."""

    fig, axes = plt.subplots(2, 2, figsize=(8, 6.4))
    panels: list[tuple[np.ndarray | None, str]] = [(camera_image, f"camera frame {frame['frame']}")]
    chosen = frame["viewframe"]
    panels.append((viewframe_image, f"viewframe {chosen}" if chosen is not None else "not localized"))
    for ax, (img, title) in zip(axes[0], panels):
        if img is not None:
            ax.imshow(img)
        ax.set_title(title)
    for ax, (img, title) in zip(axes[1], panels):
        if img is not None:
            ax.imshow(pattern(img), cmap="gray")
        ax.set_title("edges: " + title)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    truth = frame["truth_viewframe"]
    verdict = "" if frame["correct"] is None else (" — right" if frame["correct"] else f" — wrong (truth {truth})")
    fig.suptitle(
        f"frame {frame['frame']}: viewframe {chosen}, confidence {frame['confidence']:.2f}, "
        f"{frame['queries']} queries, {frame['backtracks']} backtracks{verdict}",
        fontsize=10,
    )
    fig.tight_layout()
    return fig


def plot_rankings(results: dict[str, Any]) -> Figure:
    """Each frame's five best error variances divided by the best: a sharp ranking stands high."""
    fig, ax = plt.subplots(figsize=(9, 4))
    for f in results["frames"]:
        if not f["ranking"]:
            continue
        v = np.array([r[1] for r in f["ranking"]], dtype=float)
        rel = v / v[0] if v[0] > 0 else v
        color = {True: "tab:green", False: "tab:red", None: "tab:gray"}[f["correct"]]
        ax.plot(np.full(len(rel) - 1, f["frame"]), rel[1:], ".", color=color, alpha=0.7)
    ax.axhline(1.0, color="black", lw=0.8)
    ax.set_xlabel("frame")
    ax.set_ylabel("variance / best variance (ranks 2-5)")
    ax.set_title("associative ranking margin (green: frame localized right)")
    fig.tight_layout()
    return fig


def plot_queries(runs: Sequence[dict[str, Any]]) -> Figure:
    """Detector questions per frame, one bar series per results file."""
    fig, ax = plt.subplots(figsize=(9, 4))
    width = 0.8 / max(1, len(runs))
    for i, res in enumerate(runs):
        frames = [f["frame"] for f in res["frames"]]
        q = [f["queries"] for f in res["frames"]]
        label = f"{res['strategy']} (mean {res['summary']['mean_queries']:.2f})"
        ax.bar(np.asarray(frames) + i * width, q, width=width, label=label)
    ax.set_xlabel("frame")
    ax.set_ylabel("detector queries")
    ax.legend()
    ax.set_title("queries per frame")
    fig.tight_layout()
    return fig


def plot_track(results: dict[str, Any], *, terrain, landmarks, route, poses) -> Figure:
    """The map with the true path (black), the track (blue, joined in frame order; open circles
    where the tracker was lost) and the single-frame estimates (grey dots)."""
    from models.overview import plot_map

    fig, ax = plt.subplots(figsize=(8, 7))
    plot_map(ax, terrain, landmarks, route, poses)
    frames = [f for f in results["frames"] if f["position"] is not None]
    truth = np.array([f["truth"][:2] for f in results["frames"] if f["truth"] is not None], dtype=float)
    if truth.size:
        ax.plot(truth[:, 0], truth[:, 1], "-", color="black", lw=1.2, label="true path", zorder=5)
    single = np.array(
        [
            f["frame_only"]["position"]
            for f in results["frames"]
            if (f.get("frame_only") or {}).get("position") is not None
        ],
        dtype=float,
    )
    if single.size:
        ax.plot(single[:, 0], single[:, 1], ".", color="0.45", ms=5, label="single frame", zorder=6)
    if frames:
        xy = np.array([f["position"] for f in frames], dtype=float)
        ax.plot(xy[:, 0], xy[:, 1], "-", color="tab:blue", lw=1.5, label="track", zorder=7)
        lost = np.array([f.get("state") == "lost" for f in frames])
        ax.plot(xy[~lost, 0], xy[~lost, 1], "o", color="tab:blue", ms=4, zorder=8)
        if lost.any():
            ax.plot(xy[lost, 0], xy[lost, 1], "o", mfc="none", color="tab:orange", ms=7, label="lost", zorder=8)
    pts = np.asarray(route, dtype=float)
    margin = max(150.0, 0.15 * float(np.ptp(pts, axis=0).max()))
    ax.set_xlim(pts[:, 0].min() - margin, pts[:, 0].max() + margin)
    ax.set_ylim(pts[:, 1].min() - margin, pts[:, 1].max() + margin)
    ax.legend(loc="best", fontsize=8)
    s = results["summary"]
    top1 = "n/a" if s["top1"] is None else f"{s['top1']:.0%}"
    single_top1 = "n/a" if s.get("top1_frame_only") is None else f"{s['top1_frame_only']:.0%}"
    ax.set_title(f"{results['scenario']}: track top-1 {top1}, single frame {single_top1}")
    fig.tight_layout()
    return fig


def plot_belief(results: dict[str, Any]) -> Figure:
    """Belief over the route points (rows: frames, in time order; darker: more probable), with the
    true route point (white line) and the tracked one (red dots); lost frames marked on the left."""
    frames = results["frames"]
    rows = [f.get("belief") for f in frames]
    width = max((len(r) for r in rows if r), default=0)
    fig, ax = plt.subplots(figsize=(9, 5))
    if width == 0:
        ax.text(
            0.5,
            0.5,
            "no track in these results (run without --no-track)",
            ha="center",
            va="center",
            transform=ax.transAxes,
        )
        ax.set_axis_off()
        return fig
    belief = np.array([r if r else [np.nan] * width for r in rows], dtype=float)
    ax.imshow(
        belief,
        aspect="auto",
        cmap="Greys",
        interpolation="nearest",
        vmin=0.0,
        vmax=max(0.2, np.nanmax(belief)),
        extent=(-0.5, width - 0.5, len(frames) - 0.5, -0.5),
    )
    t = np.arange(len(frames))
    truth = [f["truth_viewframe"] for f in frames]
    if any(v is not None for v in truth):
        ax.plot([np.nan if v is None else v for v in truth], t, "-", color="tab:cyan", lw=1.5, label="true route point")
    chosen = [np.nan if f["viewframe"] is None else f["viewframe"] for f in frames]
    ax.plot(chosen, t, ".", color="tab:red", ms=5, label="track")
    lost = [i for i, f in enumerate(frames) if f.get("state") == "lost"]
    if lost:
        ax.plot(np.full(len(lost), -0.5), lost, ">", color="tab:orange", ms=6, label="lost", clip_on=False)
    ax.set_xlabel("route point")
    ax.set_ylabel("frame (time runs down)")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title("tracker belief over the route")
    fig.tight_layout()
    return fig
