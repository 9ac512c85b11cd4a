"""``overview.png``: the map shaded, with the route, viewframe positions and landmark footprints."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import LightSource  # noqa: E402

from models.camera import Pose  # noqa: E402
from models.landmarks import Landmark  # noqa: E402
from models.terrain import Terrain  # noqa: E402

__all__ = ["draw_overview"]


def draw_overview(
    terrain: Terrain,
    landmarks: Sequence[Landmark],
    route: Sequence[tuple[float, float]],
    poses: Sequence[Pose],
    out: str | Path,
    *,
    title: str = "",
    dpi: int = 110,
) -> Path:
    """Write a hillshaded map (x east, y north, metres) with the route, each viewframe's position
    and heading, and the landmark footprints labelled by id. Returns the path written."""
    out = Path(out)
    x0, x1, y0, y1 = terrain.extent
    half = terrain.cell_size / 2
    fig, ax = plt.subplots(figsize=(7, 7 * (y1 - y0 + 1) / (x1 - x0 + 1) + 0.6))
    try:
        ls = LightSource(azdeg=315, altdeg=45)
        rgb = ls.shade(terrain.heights[::-1], cmap=plt.get_cmap("gist_earth"), blend_mode="soft",
                       vert_exag=2.0, dx=terrain.cell_size, dy=terrain.cell_size)
        ax.imshow(rgb, extent=(x0 - half, x1 + half, y0 - half, y1 + half), origin="upper")
        r = np.asarray(route, dtype=np.float64)
        ax.plot(r[:, 0], r[:, 1], "-", color="white", lw=2.2)
        ax.plot(r[:, 0], r[:, 1], "-", color="black", lw=1.0, label="route")
        if poses:
            px = np.array([p.x for p in poses])
            py = np.array([p.y for p in poses])
            h = np.radians([p.heading_deg for p in poses])
            ax.scatter(px, py, s=12, c="yellow", edgecolors="black", linewidths=0.5, zorder=3, label="viewframes")
            span = max(x1 - x0, y1 - y0) * 0.025
            ax.quiver(px, py, np.cos(h) * span, np.sin(h) * span, angles="xy", scale_units="xy", scale=1,
                      color="yellow", width=0.003, zorder=3)
            for i, p in enumerate(poses[:: max(1, len(poses) // 10)]):
                ax.annotate(str(i * max(1, len(poses) // 10)), (p.x, p.y), fontsize=6, color="white",
                            xytext=(3, 3), textcoords="offset points")
        for lm in landmarks:
            c = np.vstack([lm.corners(), lm.corners()[:1]])
            ax.fill(c[:, 0], c[:, 1], color="red", alpha=0.9, zorder=4)
            ax.annotate(lm.id, (lm.x, lm.y), fontsize=7, color="red", xytext=(4, -8), textcoords="offset points",
                        zorder=5)
        ax.set_xlim(x0 - half, x1 + half)
        ax.set_ylim(y0 - half, y1 + half)
        ax.set_xlabel("x (m, east)")
        ax.set_ylabel("y (m, north)")
        ax.set_title(title)
        ax.legend(loc="upper right", fontsize=7)
        fig.tight_layout()
        fig.savefig(out, dpi=dpi)
    finally:
        plt.close(fig)
    return out
