"""The terrain a scenario names: a DEM file, procedural hills, contour lines or a sample DEM.

:func:`load_terrain` dispatches on the scenario's ``terrain`` block; the grid convention is that
of :mod:`models.terrain`. ``terrain.dem`` is a ``.npy`` array (local metres, row 0 = south,
``cell_size`` required) or any raster GDAL reads with a CRS (:mod:`models.georaster`);
:func:`terrain_frame` gives a georeferenced map's :class:`~models.georef.MapFrame` without
building the DEM. It sits above :mod:`models.terrain` and :mod:`models.contours` (which
builds a :class:`~models.terrain.Terrain` from contour lines), so neither imports the other back.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from models.contours import contours_to_dem, read_contours
from models.errors import InputError, ScenarioError
from models.logs import warn_once
from models.terrain import Terrain, procedural_terrain, sample_terrain

if TYPE_CHECKING:
    from models.georef import MapFrame
    from models.scenario import Scenario, TerrainSpec

__all__ = ["load_terrain", "scenario_terrain", "terrain_frame", "is_raster", "despike", "MAX_ABS_HEIGHT_M"]

log = logging.getLogger(__name__)

#: ground heights beyond this (metres, either sign) are taken for a broken file
MAX_ABS_HEIGHT_M = 1e5


def is_raster(path: Path) -> bool:
    """True when ``terrain.dem`` is read as a georeferenced raster (anything but ``.npy``)."""
    return Path(path).suffix.lower() != ".npy"


def _load_npy(path: Path, cell_size: float, z_scale: float | None = None) -> Terrain:
    try:
        heights = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:  # EOFError: an empty file
        raise InputError(path, f"cannot read DEM as a .npy array: {exc}") from None
    if not isinstance(heights, np.ndarray) or heights.ndim != 2 or min(heights.shape) < 2:
        raise InputError(path, f"DEM must be a 2-D array of at least 2x2 cells, got shape {np.shape(heights)}")
    if not (np.issubdtype(heights.dtype, np.integer) or np.issubdtype(heights.dtype, np.floating)):
        raise InputError(path, f"DEM heights must be real numbers, not {heights.dtype}")
    finite = np.isfinite(heights)
    if not np.all(finite):
        r, c = map(int, np.argwhere(~finite)[0])
        raise InputError(
            path,
            f"DEM heights must be finite numbers (found NaN or inf in {int((~finite).sum())} cells, the first at "
            f"row {r}, col {c}); fill the holes, or give the DEM as a GeoTIFF with a nodata value "
            "(terrain.nodata: fill fills them)",
        )
    scale = 1.0 if z_scale is None else z_scale
    return Terrain(heights=heights.astype(np.float64) * scale, cell_size=cell_size)


def _load_raster(path: Path, spec: TerrainSpec) -> Terrain:
    from models.georaster import raster_height_units, read_raster_dem

    heights, grid = read_raster_dem(path, cell_size=spec.cell_size, nodata=spec.nodata)
    z_scale = spec.z_scale
    if z_scale is None:
        stated, why = raster_height_units(path)
        if stated is not None:
            z_scale = stated
            if stated != 1.0:
                log.info("%s: heights converted to metres (x %g): %s", path, stated, why)
        else:
            z_scale = 1.0
            if why:
                warn_once(
                    log,
                    "%s: heights taken as metres, but %s: set terrain.z_scale (0.3048 for feet, "
                    "0.3048006096 for US survey feet) if they are not",
                    path,
                    why,
                )
    if z_scale != 1.0:
        heights = heights * z_scale
    return Terrain(heights=heights, cell_size=grid.cell_size, frame=grid.frame)


#: a DEM cell further than this from the median of its eight neighbours (and than
#: SPIKE_STEPS times the DEM's 99th-percentile neighbour step) is a spike or a pit
SPIKE_MIN_M = 50.0
SPIKE_STEPS = 5.0


def despike(heights: np.ndarray, *, path: Path, policy: str, cell_size: float) -> np.ndarray:
    """``heights`` (rows, cols) metres, row 0 = south, with single-cell spikes and pits
    ``"fill"``-ed by the median of their eight neighbours (a warning says how many and
    where), ``"keep"``-ed, or ``"refuse"``-d (an :class:`InputError` naming the file)."""
    if policy == "keep" or min(heights.shape) < 3:
        return heights
    from scipy.ndimage import median_filter

    ring = np.ones((3, 3), bool)
    ring[1, 1] = False
    median = median_filter(heights, footprint=ring, mode="nearest")
    off = heights - median
    steps = np.concatenate([np.abs(np.diff(heights, axis=0)).ravel(), np.abs(np.diff(heights, axis=1)).ravel()])
    limit = max(SPIKE_MIN_M, SPIKE_STEPS * float(np.percentile(steps, 99)))
    bad = np.abs(off) > limit
    n = int(bad.sum())
    if n == 0:
        return heights
    r, c = map(int, np.unravel_index(int(np.argmax(np.abs(off) * bad)), heights.shape))
    what = (
        f"{n} cell(s) stand out from their neighbours by more than {limit:.0f} m, the worst by "
        f"{off[r, c]:+.0f} m at x {c * cell_size:g}, y {r * cell_size:g} (local metres)"
    )
    if policy == "refuse":
        raise InputError(path, f"{what}: spikes or pits; set terrain.spikes: fill or keep")
    warn_once(log, "%s: %s: taken for spikes or pits, filled with their neighbours' median", path, what)
    return np.where(bad, median, heights)


def _cell(spec: TerrainSpec) -> float:
    """``cell_size``, which the spec requires for every source but a raster DEM."""
    if spec.cell_size is None:  # pragma: no cover - the spec validator forbids it
        raise ScenarioError(None, "terrain.cell_size", "is required")
    return spec.cell_size


def _resolve(p: Path, base_dir: Path) -> Path:
    return p if p.is_absolute() else Path(base_dir) / p


def terrain_frame(spec: TerrainSpec, *, base_dir: Path) -> MapFrame | None:
    """The :class:`~models.georef.MapFrame` of a georeferenced map without building the DEM, else None.

    A raster's frame comes from its metadata; a contour file's from its CRS and its lines' extent.
    """
    if spec.dem is not None and is_raster(spec.dem):
        from models.georaster import raster_frame

        return raster_frame(_resolve(spec.dem, base_dir), cell_size=spec.cell_size).frame
    if spec.contours is not None:
        return read_contours(_resolve(spec.contours, base_dir), attribute=spec.elevation_attribute)[1]
    return None


def load_terrain(spec: TerrainSpec, *, base_dir: Path, seed: int) -> Terrain:
    """Build the terrain a scenario names (``dem``, ``procedural``, ``contours`` or ``sample``).

    ``dem`` is a ``.npy`` array (local metres, row 0 = south, ``cell_size`` required) or any
    raster GDAL reads with a CRS (see :mod:`models.georaster`).

    Relative paths resolve against ``base_dir``; ``seed`` seeds a procedural terrain without
    its own seed. Raises :class:`InputError` for an unreadable DEM or contour file.
    """

    def resolve(p: Path) -> Path:
        return _resolve(p, base_dir)

    if spec.dem is not None:
        path = resolve(spec.dem)
        if is_raster(path):
            terrain = _load_raster(path, spec)
        else:
            terrain = _load_npy(path, _cell(spec), spec.z_scale)
        clean = despike(terrain.heights, path=path, policy=spec.spikes, cell_size=terrain.cell_size)
        if clean is not terrain.heights:
            from dataclasses import replace

            terrain = replace(terrain, heights=clean)
    elif spec.procedural is not None:
        p = spec.procedural
        terrain = procedural_terrain(
            size=p.size, relief=p.relief, cell_size=_cell(spec), rng=seed if p.seed is None else p.seed
        )
    elif spec.contours is not None:
        from dataclasses import replace

        path = resolve(spec.contours)
        lines, frame = read_contours(path, attribute=spec.elevation_attribute, z_scale=spec.z_scale or 1.0)
        try:
            terrain = replace(contours_to_dem(lines, cell_size=_cell(spec)), frame=frame)
        except ValueError as exc:
            raise InputError(path, str(exc)) from None
    elif spec.sample is not None:
        terrain = sample_terrain(spec.sample, cell_size=_cell(spec))
    else:  # pragma: no cover - the spec validator forbids it
        raise ScenarioError(None, "terrain", "needs exactly one source")
    log.info("terrain %s x %s cells, %.0f..%.0f m", *terrain.shape, terrain.heights.min(), terrain.heights.max())
    return terrain


def scenario_terrain(scenario: Scenario) -> Terrain:
    """:func:`load_terrain` of a scenario, its errors naming the scenario file and the field as
    well as the data file (``x.yaml: terrain.dem: x.npy: DEM must be ...``): the one message the
    pre-run check and an agent meeting the file during a run both give."""
    spec = scenario.terrain
    field = "terrain." + next(k for k in ("dem", "contours", "procedural", "sample") if getattr(spec, k) is not None)
    try:
        terrain = load_terrain(spec, base_dir=scenario.base_dir, seed=scenario.seed)
    except InputError as err:
        raise ScenarioError(scenario.path, field, str(err)) from None
    except (ValueError, OSError) as err:
        raise ScenarioError(scenario.path, field, f"cannot build the terrain: {err}") from None
    low, high = float(np.min(terrain.heights)), float(np.max(terrain.heights))
    if max(abs(low), abs(high)) > MAX_ABS_HEIGHT_M:
        raise ScenarioError(
            scenario.path, field, f"heights {low:g}..{high:g} m are beyond ±{MAX_ABS_HEIGHT_M:g} m: not a terrain"
        )
    return terrain
