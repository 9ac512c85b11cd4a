"""``overview.png``: the map shaded, with the route, viewframe positions and landmark footprints."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import LightSource  # noqa: E402

from models.camera_emulator import Pose  # noqa: E402
from models.landmarks import Landmark  # noqa: E402
from models.terrain import Terrain  # noqa: E402

__all__ = ["plot_map", "draw_overview"]


def plot_map(
    ax,
    terrain: Terrain,
    landmarks: Sequence[Landmark],
    route: Sequence[tuple[float, float]],
    poses: Sequence[Pose] = (),
    *,
    label_every: int | None = None,
) -> None:
    """Draw on matplotlib axes ``ax``: the hillshaded map in world metres (x east, y north),
    the route, each viewframe's position and heading (``poses``), and the landmark footprints
    labelled by id. ``label_every``: number every n-th viewframe (default: about ten labels)."""
    x0, x1, y0, y1 = terrain.extent
    half = terrain.cell_size / 2
    ls = LightSource(azdeg=315, altdeg=45)
    # row 0 of the DEM is the south: flip it for imshow's top-down rows
    rgb = ls.shade(
        terrain.heights[::-1],
        cmap=plt.get_cmap("gist_earth"),
        blend_mode="soft",
        vert_exag=2.0,
        dx=terrain.cell_size,
        dy=terrain.cell_size,
    )
    ax.imshow(rgb, extent=(x0 - half, x1 + half, y0 - half, y1 + half), origin="upper")
    r = np.asarray(route, dtype=np.float64)
    ax.plot(r[:, 0], r[:, 1], "-", color="white", lw=2.2)
    ax.plot(r[:, 0], r[:, 1], "-", color="black", lw=1.0, label="route")
    if len(poses):
        px = np.array([p.x for p in poses])
        py = np.array([p.y for p in poses])
        h = np.radians([p.heading_deg for p in poses])
        ax.scatter(px, py, s=12, c="yellow", edgecolors="black", linewidths=0.5, zorder=3, label="viewframes")
        span = max(np.ptp(r[:, 0]), np.ptp(r[:, 1]), 10 * terrain.cell_size) * 0.03
        ax.quiver(
            px,
            py,
            np.cos(h) * span,
            np.sin(h) * span,
            angles="xy",
            scale_units="xy",
            scale=1,
            color="yellow",
            width=0.003,
            zorder=3,
        )
        step = label_every or max(1, len(poses) // 10)
        for i in range(0, len(poses), step):
            ax.annotate(str(i), (px[i], py[i]), fontsize=6, color="white", xytext=(3, 3), textcoords="offset points")
    for lm in landmarks:
        c = np.vstack([lm.corners(), lm.corners()[:1]])
        ax.fill(c[:, 0], c[:, 1], color="red", alpha=0.9, zorder=4)
        ax.annotate(lm.id, (lm.x, lm.y), fontsize=7, color="red", xytext=(4, -8), textcoords="offset points", zorder=5)
    ax.set_xlim(x0 - half, x1 + half)
    ax.set_ylim(y0 - half, y1 + half)
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")


def draw_overview(
    terrain: Terrain,
    landmarks: Sequence[Landmark],
    route: Sequence[tuple[float, float]],
    poses: Sequence[Pose],
    out: str | Path,
    *,
    title: str = "",
    dpi: int = 110,
    zoom: bool = True,
) -> Path:
    """Write ``overview.png``: the whole map (left) and, with ``zoom``, the route's surroundings
    (right), each drawn by :func:`plot_map`. Returns the path written."""
    out = Path(out)
    fig, axes = plt.subplots(1, 2 if zoom else 1, figsize=(13 if zoom else 7, 6.5), squeeze=False)
    try:
        plot_map(axes[0, 0], terrain, landmarks, route, poses)
        axes[0, 0].set_title(f"{title} - map" if title else "map")
        if zoom:
            plot_map(axes[0, 1], terrain, landmarks, route, poses)
            pts = np.vstack([np.asarray(route, dtype=np.float64)] + [[lm.x, lm.y] for lm in landmarks])
            lo, hi = pts.min(0), pts.max(0)
            pad = max(0.15 * (hi - lo).max(), 5 * terrain.cell_size)
            cx, cy = (lo + hi) / 2
            half = (hi - lo).max() / 2 + pad
            axes[0, 1].set_xlim(cx - half, cx + half)
            axes[0, 1].set_ylim(cy - half, cy + half)
            axes[0, 1].set_title("route and landmarks")
        axes[0, 0].legend(loc="upper right", fontsize=7)
        fig.tight_layout()
        fig.savefig(out, dpi=dpi)
    finally:
        plt.close(fig)
    return out
