"""Plots of results files: what a person would rather look at than read.

Pure functions from results (and the scenario they came from) to figures, separate from the
command that writes them (:mod:`knowledge_sources.commands.report`):

* :func:`plot_positions`: the map with true and estimated positions, joined, coloured by right/wrong;
* :func:`plot_frame`: a camera frame beside the chosen viewframe, with both preprocessed edge images;
* :func:`plot_rankings`: each frame's five best error variances, relative to the best;
* :func:`plot_queries`: detector questions per frame, one series per results file (strategy).

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

__all__ = ["plot_positions", "plot_frame", "plot_rankings", "plot_queries"]


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


def plot_frame(frame: dict[str, Any], camera_image: np.ndarray, viewframe_image: np.ndarray | None, *,
               pattern: Callable[[np.ndarray], np.ndarray]) -> Figure:
    """A camera frame beside the chosen viewframe, and both edge images as the memory sees them
    (``pattern``: the index's preprocessing, :meth:`models.index.ViewframeIndex.pattern`)."""

    fig, axes = plt.subplots(2, 2, figsize=(8, 6.4))
    panels = [(camera_image, f"camera frame {frame['frame']}")]
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
    fig.suptitle(f"frame {frame['frame']}: viewframe {chosen}, confidence {frame['confidence']:.2f}, "
                 f"{frame['queries']} queries, {frame['backtracks']} backtracks{verdict}", fontsize=10)
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
