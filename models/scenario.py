"""Scenario files: the map, the landmarks, the mission route, the camera and the sensor input.

A scenario is a YAML file validated fully on load; every error names the file, the field path
and what is wrong (``scenarios/x.yaml: landmarks[3].height: must be > 0``). Relative paths
(DEM, contours, camera frames) resolve against the scenario file's folder. Example::

    name: hills
    seed: 7
    terrain: {cell_size: 10.0, procedural: {size: 256, relief: 120.0, seed: 3}}
    landmarks:
      - {id: H1, kind: house, x: 812.0, y: 450.5, width: 20, depth: 12, height: 8, yaw_deg: 30}
    route: [[100, 100], [250, 140], [400, 210]]
    camera: {width: 160, height: 120, fov_y_deg: 45, eye_height: 2.0, near: 1.0, far: 5000.0}
    sensor: {simulate: {per_point: 1}}

World coordinates are metres, x east, y north, z up; see :mod:`models.terrain` for the DEM
grid convention and :mod:`models.camera_emulator` for the pinhole convention.

**Every default is defined here, once.** The optional blocks (``memory``, ``scheduler``,
``sensor.simulate``) are the settings of the associative memory and preprocessing, of the
scene-analysis scheduler and the landmark detectors, and of the simulated camera; the classes and
functions that use them (:mod:`models.preprocess`, :mod:`models.associative`,
:mod:`models.memory_keys`, :mod:`models.detectors`, :mod:`knowledge_sources.scene_analysis`, the
agents) take their default values from these specs (``MemorySpec().blur_sigma`` ...) and write
none of their own. Why each default was chosen is in BENCHMARKS.md ("Choosing the memory and
scheduler defaults").

On a georeferenced map (``terrain.dem`` a GeoTIFF or other GDAL raster, or contour lines with a
CRS) the route, landmark and truth coordinates are in the map's CRS, or in the CRS named by the
top-level ``crs:`` (``EPSG:4326``: [lon, lat] degrees); they are converted to local metres on
load (:class:`~models.georef.MapFrame`, in :attr:`Scenario.map_frame`), so every model and agent
sees local metres::

    terrain: {dem: data/dem.tif}        # cell size and CRS from the GeoTIFF
    crs: EPSG:4326
    route: [[-84.301, 36.402], [-84.300, 36.403]]

Positions are converted; directions (``landmarks[].yaw_deg``, ``truth.heading_deg``) are taken
as they are, counterclockwise from the working CRS's grid east: within a map's extent that
differs from true east by the grid convergence (zero on a transverse Mercator's central
meridian, up to a few degrees at a UTM zone's edge).
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_core import ErrorDetails

from models.errors import ScenarioError

__all__ = [
    "ProceduralSpec",
    "TerrainSpec",
    "LandmarkSpec",
    "CameraSpec",
    "TruthSpec",
    "FrameSpec",
    "DriveSpec",
    "SimulateSpec",
    "SensorSpec",
    "MemorySpec",
    "SchedulerSpec",
    "SkylineSpec",
    "RenderSpec",
    "RefineSpec",
    "VerifySpec",
    "TrackingSpec",
    "ExpectSpec",
    "Scenario",
    "load_scenario",
    "scenario_from_dict",
    "SAMPLE_DEMS",
    "validation_problem",
]

log = logging.getLogger(__name__)

#: names accepted by ``terrain.sample``
SAMPLE_DEMS: tuple[str, ...] = ("jacksboro",)


#: bounds shared by several fields: world coordinates and lengths (metres), seeds
MAX_COORD_M = 1e7
MAX_SIZE_M = 1e4
MAX_SEED = 2**32 - 1
#: at most this many viewframes per leg of the route (``render.views_per_leg``)
MAX_VIEWS_PER_LEG = 9
#: ``render.views_per_leg`` by default: this many on routes of fewer than DENSE_ROUTE_POINTS points,
#: one per point on longer ones (chosen on the evaluation set's tuning split, BENCHMARKS.md)
DENSE_VIEWS_PER_LEG = 3
DENSE_ROUTE_POINTS = 1000
#: at most this many route points and camera frames in one scenario
MAX_ROUTE_POINTS = 1_000_000
#: the memory's shift search reaches at most this many memory pixels (its lags are circular: a
#: window of half the memory size or more covers every lag)
MAX_SHIFT = 64
#: the most roll angles the memory's match searches (MemorySpec.roll_search_deg): each is one more ranking
MAX_ROLL_SEARCH = 9
#: the rolls (degrees) the camera image is matched turned by, in the memory's ranking and the
#: verification alike (MemorySpec.roll_search_deg, VerifySpec.roll_search_deg)
ROLL_SEARCH_DEG: tuple[float, ...] = (-3.0, -1.5, 0.0, 1.5, 3.0)
MAX_FRAMES = 1_000_000
MAX_TIME_S = 1e11  # frame times: seconds from any origin (epoch seconds fit)
MAX_SPEED_MPS = 1000.0
#: the scheduler's clip of one answer's log-likelihood ratio, and the detector calibration's
#: coefficients (the defaults are single digits): larger ones only overflow the posterior
MAX_LLR = 20.0
MAX_CALIBRATION = 1e3
#: smallest camera image on file accepted, pixels per side (the camera's own lower bound)
MIN_IMAGE_PX = 8


class _Spec(BaseModel):
    # no inf/NaN anywhere: every float is finite (pydantic's finite_number error)
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def _resolve_path(value: Path, info: ValidationInfo, *, must_exist: bool = True) -> Path:
    """Resolve ``value`` against the scenario folder given in the validation context."""
    base = (info.context or {}).get("base_dir")
    path = Path(value).expanduser()
    if not path.is_absolute():
        path = ((Path(base) if base is not None else Path.cwd()) / path).absolute()
    if must_exist and not path.is_file():
        raise ValueError(f"file not found: {path}")
    return path


class ProceduralSpec(_Spec):
    """Procedural hills: ``{size: 256, relief: 120.0, seed: 3}`` (seed None -> scenario seed)."""

    size: int = Field(ge=8, le=4096)
    relief: float = Field(gt=0, le=MAX_SIZE_M)
    seed: int | None = Field(default=None, ge=0, le=MAX_SEED)


class TerrainSpec(_Spec):
    """Exactly one source, ``dem``, ``procedural``, ``contours`` or ``sample``, and ``cell_size``.

    ``cell_size`` (metres) is required but for a raster ``dem`` (a GeoTIFF or any GDAL raster),
    whose own cells are used unless ``cell_size`` asks for others (it is then resampled, see
    :mod:`models.georaster`). ``nodata`` says what a raster's nodata cells become: ``fill``
    (nearest valid height, with a warning) or ``refuse`` (an error); a raster that names no
    nodata value has its cells of -9999, -99999, -32767, -32768 or beyond ±1e30 taken as nodata.

    Heights are metres: ``z_scale`` is the metres per height unit of a ``dem`` or ``contours``
    file (0.3048 for heights in feet, 0.3048006096 for US survey feet); by default a raster
    whose band names its unit (``ft``, ``US survey foot``, ``m``) is converted by it, and
    anything else is taken as metres (with a warning when the map's CRS is in feet).

    ``spikes`` says what a ``dem``'s single-cell spikes and pits become (cells further from
    the median of their eight neighbours than 50 m and than 5 times the DEM's 99th-percentile
    neighbour step: a broken cell, not a cliff): ``fill`` (that median, with a warning naming
    how many and where), ``keep`` or ``refuse`` (an error).

    ``elevation_attribute`` names the contour files' height attribute; by default the first of
    ``elevation``, ``elev``, ``ele``, ``height``, ``z``, ``contour``, ``level``, ``alt``,
    ``altitude`` the file has (in any case), else the lines' own z coordinates (3-D lines).
    """

    cell_size: float | None = Field(default=None, gt=0, le=MAX_SIZE_M)
    dem: Path | None = None
    procedural: ProceduralSpec | None = None
    contours: Path | None = None
    sample: Literal["jacksboro"] | None = None
    nodata: Literal["fill", "refuse"] = "fill"
    z_scale: float | None = Field(default=None, gt=0, le=1000)
    spikes: Literal["fill", "keep", "refuse"] = "fill"
    elevation_attribute: str | None = Field(default=None, min_length=1)

    @field_validator("dem", "contours")
    @classmethod
    def _file(cls, value: Path | None, info: ValidationInfo) -> Path | None:
        return None if value is None else _resolve_path(value, info)

    @model_validator(mode="after")
    def _exactly_one(self) -> TerrainSpec:
        given = [k for k in ("dem", "procedural", "contours", "sample") if getattr(self, k) is not None]
        if len(given) != 1:
            got = ", ".join(given) if given else "none"
            raise ValueError(f"needs exactly one of dem, procedural, contours, sample (got {got})")
        raster = self.dem is not None and self.dem.suffix.lower() != ".npy"
        if self.cell_size is None and not raster:
            raise ValueError("cell_size is required (metres per DEM cell) but for a georeferenced raster dem")
        return self


class LandmarkSpec(_Spec):
    """A box landmark: footprint centre (x, y), width along local x, depth along local y."""

    id: str = Field(min_length=1, max_length=64)
    kind: str = Field(min_length=1, max_length=64)
    x: float = Field(ge=-MAX_COORD_M, le=MAX_COORD_M)
    y: float = Field(ge=-MAX_COORD_M, le=MAX_COORD_M)
    width: float = Field(gt=0, le=MAX_SIZE_M)
    depth: float = Field(gt=0, le=MAX_SIZE_M)
    height: float = Field(gt=0, le=MAX_SIZE_M)
    yaw_deg: float = Field(default=0.0, ge=-360, le=360)


class CameraSpec(_Spec):
    """Pinhole camera: ``{width: 160, height: 120, fov_y_deg: 45, eye_height: 2.0, near: 1, far: 5000}``."""

    width: int = Field(ge=8, le=4096)
    height: int = Field(ge=8, le=4096)
    fov_y_deg: float = Field(gt=0, lt=180)
    eye_height: float = Field(ge=0, le=MAX_SIZE_M)
    pitch_deg: float = Field(default=0.0, gt=-90, lt=90)
    near: float = Field(gt=0, le=MAX_SIZE_M)
    far: float = Field(gt=0, le=MAX_COORD_M)

    @field_validator("far")
    @classmethod
    def _beyond_near(cls, value: float, info: ValidationInfo) -> float:
        near = info.data.get("near")
        if near is not None and value <= near:
            raise ValueError(f"must be > near ({near:g})")
        return value


class TruthSpec(_Spec):
    """True pose of a camera frame (for evaluation only)."""

    x: float = Field(ge=-MAX_COORD_M, le=MAX_COORD_M)
    y: float = Field(ge=-MAX_COORD_M, le=MAX_COORD_M)
    heading_deg: float = Field(ge=-360, le=360)


class FrameSpec(_Spec):
    """A camera image taken during the mission; ``image`` must exist. ``time``: seconds (any
    origin), increasing along ``sensor.frames``, which are in time order."""

    image: Path
    truth: TruthSpec | None = None
    time: float | None = Field(default=None, ge=-MAX_TIME_S, le=MAX_TIME_S)

    @field_validator("image")
    @classmethod
    def _file(cls, value: Path, info: ValidationInfo) -> Path:
        return _resolve_path(value, info)


class DriveSpec(_Spec):
    """A simulated drive: frames in time order along the route (see :func:`models.sensor.drive_poses`).

    Example: ``drive: {interval_s: 2.0, speed_mps: [8, 20], p_stop: 0.05, kidnap_at: 12}``.

    Every ``interval_s`` seconds one frame; the speed wanders in ``speed_mps`` (a random walk,
    ``speed_change`` of the range per frame); with probability ``p_stop`` a frame starts a stop
    of 1 to ``stop_frames`` frames. The camera is off the route by Gaussian ``lateral_m``
    (perpendicular) and off its direction by ``heading_deg``, both slowly varying. With
    ``kidnap_at``, that frame jumps to arc fraction ``kidnap_to`` of the route (default: drawn at
    least a quarter of the route away). The drive ends at the last route point or after
    ``frames`` frames.
    """

    interval_s: float = Field(default=2.0, gt=0, le=3600)
    speed_mps: tuple[float, float] = (8.0, 20.0)
    speed_change: float = Field(default=0.2, ge=0, le=1)
    p_stop: float = Field(default=0.05, ge=0, lt=1)
    stop_frames: int = Field(default=3, ge=1, le=MAX_FRAMES)
    lateral_m: float = Field(default=1.5, ge=0, le=1000)
    heading_deg: float = Field(default=3.0, ge=0, le=180)
    start: float = Field(default=0.0, ge=0, lt=1)
    kidnap_at: int | None = Field(default=None, ge=1, le=MAX_FRAMES)
    kidnap_to: float | None = Field(default=None, ge=0, lt=1)
    frames: int | None = Field(default=None, ge=1, le=MAX_FRAMES)

    @field_validator("speed_mps")
    @classmethod
    def _speeds(cls, value: tuple[float, float]) -> tuple[float, float]:
        if not 0 <= value[0] <= value[1] <= MAX_SPEED_MPS or value[1] <= 0:
            raise ValueError(f"must be [min, max] with 0 <= min <= max <= {MAX_SPEED_MPS:g} and max > 0")
        return value


class SimulateSpec(_Spec):
    """Simulated camera frames near the route points (see the end-to-end issue), or along a
    ``drive`` (then ``per_point``, ``stride``, ``jitter_*`` and ``advance`` do not apply)."""

    per_point: int = Field(default=1, ge=1, le=1000)
    stride: int = Field(default=1, ge=1, le=MAX_ROUTE_POINTS)  # frames at every stride-th route point only
    jitter_m: float = Field(default=1.5, ge=0, le=1000)
    jitter_deg: float = Field(default=3.0, ge=0, le=180)
    advance: float = Field(default=0.15, ge=0, lt=1)
    lighting: float = Field(default=0.3, ge=0, le=1)  # light intensity 1 ± lighting: must stay >= 0
    haze: float = Field(default=0.2, ge=0, le=1)  # a blend fraction
    gain: float = Field(default=0.2, ge=0, le=1)  # gain 1 ± gain
    gamma: float = Field(default=0.2, ge=0, le=5)
    noise: float = Field(default=4.0, ge=0, le=255)  # gray levels
    blur: float = Field(default=0.7, ge=0, le=50)  # pixels
    texture: float = Field(default=0.3, ge=0, le=4)
    seed: int | None = Field(default=None, ge=0, le=MAX_SEED)
    drive: DriveSpec | None = None


class SensorSpec(_Spec):
    """Exactly one of ``frames`` (real images) or ``simulate``.

    ``fov_y_deg`` and ``fov_x_deg`` are the vertical and horizontal fields of view of the images
    in ``frames`` (default: the scenario camera's ``fov_y_deg``, the same lens, with square
    pixels: give one of them, or both for non-square pixels). Images of any size and aspect
    ratio are mapped onto the scenario camera's field of view (:func:`models.sensor.fit_to_camera`):
    scaled by the ratio of the focal lengths, cropped where they see more than the camera and
    padded (border pixels replicated) where they see less; an image that sees less than half of
    the camera's width or height is refused. Without either field an image whose aspect ratio
    differs from the camera's is taken to have the camera's vertical field of view, with a
    warning.
    """

    frames: list[FrameSpec] | None = Field(default=None, min_length=1, max_length=MAX_FRAMES)
    simulate: SimulateSpec | None = None
    fov_y_deg: float | None = Field(default=None, gt=0, lt=180)
    fov_x_deg: float | None = Field(default=None, gt=0, lt=180)

    @model_validator(mode="after")
    def _exactly_one(self) -> SensorSpec:
        if (self.frames is None) == (self.simulate is None):
            raise ValueError("needs exactly one of frames, simulate")
        if self.frames is None and (self.fov_y_deg is not None or self.fov_x_deg is not None):
            raise ValueError("fov_y_deg and fov_x_deg describe the images of sensor.frames: give frames")
        if self.frames:
            given = [f.time for f in self.frames]
            if any(t is not None for t in given):
                times = [t for t in given if t is not None]
                if len(times) != len(given):
                    raise ValueError("frames: give a time for every frame or for none")
                for i, (a, b) in enumerate(zip(times, times[1:]), start=1):
                    if b <= a:
                        raise ValueError(
                            f"frames[{i}].time: must be > the previous frame's ({a:g}): frames are in time order"
                        )
        return self


def _roll_angles(value: tuple[float, ...]) -> tuple[float, ...]:
    """A roll search's angles (MemorySpec's and VerifySpec's ``roll_search_deg``), checked."""
    if not 1 <= len(value) <= MAX_ROLL_SEARCH or not all(math.isfinite(v) and abs(v) <= 45 for v in value):
        raise ValueError(f"must be 1 to {MAX_ROLL_SEARCH} angles in degrees within [-45, 45]")
    if len(set(value)) != len(value):
        raise ValueError("must not repeat an angle")
    return value


class MemorySpec(_Spec):
    """Associative memory and preprocessing settings.

    ``size`` is the side N of the memory patterns; ``edge``, ``blur_sigma`` (memory pixels) and
    ``whiten`` the edge operator, gaussian blur and spectral whitening of
    :func:`models.preprocess.preprocess`; ``bank_size`` viewframes share one holographic memory
    (a *bank*: consecutive route views are alike, so their crosstalk is structured and a bank
    holds few of them); ``shard_size`` viewframes go to one associative indexer agent (a
    *shard*), which holds them in as many banks as needed; ``max_shift`` is the (rows, cols)
    window in memory pixels over which the recall is matched against each prototype, absorbing
    pose errors (at N=128 with the 160x120 camera of 45 degrees vertical field of view, one
    degree of pitch moves the horizon about 2.7 rows and one degree of heading about 2.2
    columns; the default (8, 24) absorbs about 3 degrees of pitch and 11 of heading: the camera's
    heading error plus the bend between the leg a camera just before route point k drives on
    and the leg viewframe k looks along; chosen on the evaluation set's tuning split,
    BENCHMARKS.md, "Associative ranking defaults"); ``key`` the K-GEN method of
    :mod:`models.memory_keys`.

    The track's neighbourhood (:func:`models.index.track_window`): on routes of at least
    ``window_route_points`` points (null: never), while the tracker is tracking, the indexers
    rank for frame t only the route points where the track of frame t - 1 predicts frame t
    (the interval holding all but 1e-3 of its ``prior_next`` without the kidnap part, the
    track's ``window_next``), widened by ``window_margin``
    points on each side, when that track is there as the frame is ranked (an indexer never
    waits for it); every ``window_full_every``-th frame, and whenever the track is lost or not
    there, they rank every viewframe, so that a track that went wrong (a vehicle moved elsewhere) meets
    the evidence against it. Short routes always rank everything: there the full ranking is
    cheap, and a window can only lose evidence.

    The coarse stage: a frame ranked in full (no track window) is first compared, in each shard,
    with every viewframe of the shard by the memory's own low-passed similarity on the few
    spectral bins the blur leaves, over a coarse grid of shifts (:class:`models.coarse.MemoryCoarse`),
    and only the shard's ``coarse_candidates`` best are ranked in full (null: every viewframe);
    the shard's ranking holds those, as a window's ranking holds the window's viewframes. A
    shard of no more viewframes (the evaluation set's routes of 32), and a track window's frames,
    are ranked in full. 32 is the fewest whose candidates held the full ranking's first for 99.5 %
    of the frames of the evaluation set's tuning split with its four routes pooled in one index
    (``bench/coarse.py --memory tuning``; BENCHMARKS.md, "Associative coarse stage").

    The defaults were chosen on the tuning split of the evaluation set (``bench/evalset``,
    ``bench/ranking_sweep.py``; BENCHMARKS.md, "Associative ranking defaults"): one viewframe
    per bank (superposing two lost 3-6 points of ranking top-1 there), rows +-8 (pitch errors of
    up to 2 degrees plus eye-height and terrain differences; +-2 lost 8 points), columns +-16
    (about 8 degrees of heading). ``roll_search_deg``: the camera image is matched turned by
    each of these rolls (degrees, counter-clockwise as seen in the image, about its centre:
    :func:`models.derotate.rolled`), and each viewframe keeps its best (smallest) error variance
    of them: no shift undoes a roll, which tilts every edge (3 degrees move a 128-pattern's side
    columns by about 3 rows against its centre, beyond the 1-pixel blur). Each angle costs one
    more preprocessing and ranking of the frame; ``[0]`` is the plain match. The default
    (-3, -1.5, 0, 1.5, 3), the larger pose-error profile's roll bound in steps of about the blur's
    tolerance, was chosen on the tuning split with bench/tracking.py's extra tuning drives (640
    frames, ``bench/pose_ablation.py --extra --rolls``): fused ranking top-1 0.589 -> 0.636 (top-5
    0.928 -> 0.958) under the larger pose errors, 0.702 -> 0.705 (0.959 -> 0.972) under the
    standard ones (BENCHMARKS.md, "Larger pose errors, component by component").
    ``roll_shortlist`` (default null: every viewframe ranked) is how many viewframes, the plain
    match's best, the turned images are ranked among (the others keep the plain match's
    variance), for large maps where the search's cost matters: on the 640 tuning frames 32 halve
    the memory's time a frame (84 -> 42 ms) and lose part of the gain (fused top-1 0.705 -> 0.691
    standard, 0.636 -> 0.625 larger errors; BENCHMARKS.md, "The roll search's shortlist").
    ``weight`` is
    the associative ranking's weight in the fusion
    of ranking sources, in nats per robust z-score of its error variances
    (:mod:`knowledge_sources.fusion`), calibrated with the skyline's on the tuning split
    (``bench/fusion_sweep.py --fit``). Example::

        memory: {size: 128, blur_sigma: 1.0, bank_size: 1, shard_size: 512, max_shift: [8, 24]}
    """

    size: int = 128
    edge: Literal["sobel", "scharr", "laplacian", "canny", "none"] = "sobel"
    blur_sigma: float = Field(default=1.0, gt=0, le=64)
    whiten: bool = True
    bank_size: int = Field(default=1, ge=1, le=4096)
    shard_size: int = Field(default=512, ge=1, le=MAX_ROUTE_POINTS)
    max_shift: tuple[int, int] = (8, 24)
    key: Literal["phase", "quantized"] = "phase"
    weight: float = Field(default=0.64, ge=0, le=1e3)
    window_route_points: int | None = Field(default=2000, ge=1, le=MAX_ROUTE_POINTS)
    window_margin: int = Field(default=16, ge=0, le=MAX_ROUTE_POINTS)
    window_full_every: int = Field(default=10, ge=1, le=1_000_000)
    coarse_candidates: int | None = Field(default=32, ge=1, le=MAX_ROUTE_POINTS)
    roll_search_deg: tuple[float, ...] = ROLL_SEARCH_DEG
    roll_shortlist: int | None = Field(default=None, ge=1, le=MAX_ROUTE_POINTS)

    @field_validator("roll_search_deg")
    @classmethod
    def _rolls(cls, value: tuple[float, ...]) -> tuple[float, ...]:
        return _roll_angles(value)

    @field_validator("max_shift")
    @classmethod
    def _shift_range(cls, value: tuple[int, int]) -> tuple[int, int]:
        if not all(0 <= v <= MAX_SHIFT for v in value):
            raise ValueError(f"must be two integers in 0..{MAX_SHIFT}")
        return value

    @field_validator("size")
    @classmethod
    def _power_of_two(cls, value: int) -> int:
        if not 16 <= value <= 1024 or value & (value - 1):
            raise ValueError("must be a power of two in 16..1024")
        return value


#: the detectors' calibration, one for every kind ("any", models.detectors.ANY_KIND; a kind or
#: detector family, models.detectors.KIND_FAMILY, may have its own), fitted by
#: bench/tuning/calibrate_detectors.py on the evaluation set's tuning split (one calibration did
#: better than one per family or kind with a tuning case left out: BENCHMARKS.md); the weights are
#: the features' (:data:`CALIBRATION_FEATURES`)
DETECTOR_CALIBRATION: dict[str, tuple[float, ...]] = {
    "any": (-8.2229, 1.1922, 3.623, 6.5304, 0.3359, 3.4658),
}

#: the evidence a detector calibration weighs, in order (models.detectors.LR_FEATURES): a
#: calibration is ``[bias, w_statistic, w_orientation, w_vertical, w_contrast, w_context]``
CALIBRATION_FEATURES: tuple[str, ...] = ("statistic", "orientation", "vertical", "contrast", "context")


class SchedulerSpec(_Spec):
    """Scene-analysis scheduler and landmark detector settings (the rule is documented in
    :mod:`knowledge_sources.scene_analysis`).

    ``candidates`` best viewframes of the ranking are verified; the best is accepted at posterior
    ``accept``; ``reliability`` is the detectors' assumed reliability, ``beta`` the sharpness of
    the ranking weights; a landmark is asked about only where it covers at least ``min_pixels``
    pixels of the viewframe; a detector answers *present* from ``detector_threshold`` and *absent*
    below ``absent_threshold``; an unanswered query times out after ``query_timeout_s``; with
    tracking, a frame whose previous frame's track is not posted within ``track_timeout_s`` (or
    whose tracker is dead) is analysed blind. The
    defaults were chosen on simulated frames of the bundled scenarios with other seeds than theirs
    (BENCHMARKS.md). Example::

        scheduler: {candidates: 8, accept: 0.6, min_pixels: 60, detector_threshold: 0.65}
    """

    candidates: int = Field(default=8, ge=1, le=MAX_ROUTE_POINTS)
    accept: float = Field(default=0.6, gt=0, le=1)
    reliability: float = Field(default=0.8, gt=0.5, lt=1)
    beta: float = Field(default=3.0, gt=0, le=100)
    min_pixels: int = Field(default=60, ge=1, le=4096 * 4096)
    detector_threshold: float = Field(default=0.65, ge=0, le=1)
    absent_threshold: float = Field(default=0.15, ge=0, le=1)
    # a question unanswered this long is given up (its detector is taken as dead for it)
    query_timeout_s: float = Field(default=10.0, ge=0.01, le=3600)
    # tracking: frame t waits this long after frame t - 1's position for the track of t - 1, then
    # (or at once when the tracker is dead) it is analysed blind (the tracker answers in milliseconds)
    track_timeout_s: float = Field(default=5.0, ge=0.01, le=3600)
    strategy: Literal["associative", "prior"] = "associative"
    #: how detector answers enter the posterior: "hard" (an absent landmark discards its
    #: viewframes, the seed paper's) or "soft" (the answer's likelihood ratio enters it)
    backtracking: Literal["hard", "soft"] = "soft"
    #: question order: "information" (expected information gain) or "probability" (P(L|A))
    questions: Literal["information", "probability"] = "information"
    #: soft: a candidate whose posterior falls below this is discarded
    floor: float = Field(default=1e-3, ge=0, lt=1)
    #: soft: no single answer moves a candidate's log-odds by more than this (natural log; 20 is
    #: a likelihood ratio of about 5e8, beyond which one answer would decide alone)
    max_llr: float = Field(default=3.0, gt=0, le=MAX_LLR)
    #: soft: how likely a camera frame taken near a viewframe shows a landmark that the viewframe
    #: does not show but a neighbouring viewframe along the route does (one neighbour's share: the
    #: viewframe's own visibility blurred along the route by (a, 1 - 2a, a), so a landmark shown by
    #: this viewframe alone counts 1 - 2a); 0: the symbolic descriptions' visible sets exactly, the
    #: rule before session 15 (knowledge_sources.scene_analysis, "Visibility near a viewframe")
    neighbour_visibility: float = Field(default=0.0, ge=0, le=0.5)
    #: soft: answers say where the landmark was found, and that place enters the posterior of every
    #: candidate showing it by how well it fits where the candidate puts it (position evidence,
    #: knowledge_sources.scene_analysis); false (default): presence only. Off because on the
    #: evaluation set's tuning split, through the whole pipeline, it did not pay (BENCHMARKS.md)
    position_evidence: bool = False
    #: the position evidence's Student-t scales: (elevation degrees, azimuth degrees, log of the
    #: size ratio), the robust spread (1.4826 x median |residual|) of the detectors' found place
    #: about the true viewframe's prediction on the evaluation set's tuning split
    #: (bench/tuning/calibrate_position.py; BENCHMARKS.md)
    position_spread: tuple[float, float, float] = (1.6, 1.6, 0.21)
    #: its degrees of freedom (3: heavy tails, a wrong match is not a Gaussian outlier)
    position_dof: float = Field(default=3.0, gt=0, le=1e3)
    #: the most one answer's position evidence lowers a candidate's log-likelihood (natural log)
    max_position_llr: float = Field(default=3.0, gt=0, le=MAX_LLR)
    #: pose errors, (pitch, heading) degrees, the detectors' likelihood ratio must tolerate
    align_deg: tuple[float, float] = (2.0, 5.0)
    #: template scales the detectors' likelihood ratio searches (a position error along the route
    #: makes a near landmark larger or smaller than its viewframe shows it): 0.7 to 1.43 in steps of
    #: about 10%, so that a scaled template's thin edges stay within 2 px on a 40-px landmark
    #: (steps of 20% did a little worse with a tuning case left out; BENCHMARKS.md)
    detector_scales: tuple[float, ...] = Field(
        default=(0.7, 0.76, 0.83, 0.91, 1.0, 1.1, 1.2, 1.31, 1.43), min_length=1, max_length=16
    )
    #: detector calibration, {landmark kind, detector family or "any": [bias, w_statistic, w_orientation,
    #: w_vertical, w_contrast, w_context]}:
    #: the log-likelihood ratio is bias + w . features (models.detectors.Calibration); fitted
    #: by bench/tuning/calibrate_detectors.py on tuning seeds
    calibration: dict[str, tuple[float, ...]] = Field(default_factory=lambda: dict(DETECTOR_CALIBRATION), max_length=64)

    @field_validator("calibration")
    @classmethod
    def _calibration(cls, value: dict[str, tuple[float, ...]]) -> dict[str, tuple[float, ...]]:
        for kind, numbers in value.items():
            if not 1 <= len(kind) <= 64:
                raise ValueError(f"{kind!r}: a landmark kind or detector family of 1 to 64 characters")
            if len(numbers) != len(CALIBRATION_FEATURES) + 1:
                raise ValueError(
                    f"{kind}: a calibration is {len(CALIBRATION_FEATURES) + 1} numbers, [bias, "
                    + ", ".join(f"w_{f}" for f in CALIBRATION_FEATURES)
                    + f"], not {len(numbers)} (the four of before session 9 weigh other evidence: "
                    "refit with bench/tuning/calibrate_detectors.py, or leave the default)"
                )
            if not all(abs(v) <= MAX_CALIBRATION for v in numbers):
                raise ValueError(f"{kind}: every number must be within ±{MAX_CALIBRATION:g}")
        return value

    @field_validator("detector_scales")
    @classmethod
    def _scales(cls, value: tuple[float, ...]) -> tuple[float, ...]:
        if not all(0.25 <= v <= 4 for v in value):
            raise ValueError("every scale must be within [0.25, 4]")
        return value

    @field_validator("position_spread")
    @classmethod
    def _position_spread(cls, value: tuple[float, float, float]) -> tuple[float, float, float]:
        if not all(0 < v <= 90 for v in value):
            raise ValueError("must be three values in (0, 90]: (elevation_deg, azimuth_deg, log_size)")
        return value

    @field_validator("align_deg")
    @classmethod
    def _align(cls, value: tuple[float, float]) -> tuple[float, float]:
        if not all(0 <= v < 45 for v in value):
            raise ValueError("must be two angles in [0, 45) degrees: (pitch, heading)")
        return value

    @model_validator(mode="after")
    def _thresholds(self) -> SchedulerSpec:
        if self.absent_threshold > self.detector_threshold:
            raise ValueError(f"absent_threshold must be <= detector_threshold ({self.detector_threshold})")
        return self


class SkylineSpec(_Spec):
    """The skyline ranking source (:mod:`models.skyline`, :mod:`knowledge_sources.skyline`):
    ``{enabled: true, step_deg: 0.5, max_heading_deg: 12, max_pitch_deg: 4, truncate_deg: 2,
    max_roll_deg: 3, roll_candidates: 64, coarse_candidates: 200, weight: 3.8}``.
    ``max_roll_deg`` bounds the tilt of the camera's profile against a viewframe's that the
    matching fits (the camera's roll;
    :func:`models.skyline.match_skylines`), chosen on the evaluation set's tuning split;
    ``roll_candidates`` (null: all) is how many viewframes, the best of a roll-free first pass,
    the roll is fitted for (the roll fit is most of a match's cost; BENCHMARKS.md, "Scale").
    ``coarse_candidates`` (null: none, every viewframe ranked is matched in full) is how many
    viewframes, the best of a coarse first comparison with every one (:mod:`models.skyline_coarse`),
    the full match ranks; the others are left out of the ranking, as outside a track window.
    200 was chosen on the evaluation set's tuning split padded to 10,000 references, where the
    full ranking's first was always among the coarse first 86 (``bench/skyline_coarse.py``;
    BENCHMARKS.md, "Skyline coarse stage").
    ``weight`` is the skyline's weight in the fusion of ranking sources, in nats per degree of
    matching error (:mod:`knowledge_sources.fusion`; the memory's is ``memory.weight``),
    calibrated with the memory's on the tuning split (``bench/fusion_sweep.py --fit``;
    BENCHMARKS.md).
    """

    enabled: bool = True
    step_deg: float = Field(default=0.5, gt=0, le=5)
    max_heading_deg: float = Field(default=12.0, ge=0, le=90)
    max_pitch_deg: float = Field(default=4.0, ge=0, le=30)
    truncate_deg: float = Field(default=2.0, gt=0, le=90)
    max_roll_deg: float = Field(default=3.0, ge=0, lt=45)
    roll_candidates: int | None = Field(default=64, ge=1, le=MAX_ROUTE_POINTS)
    coarse_candidates: int | None = Field(default=200, ge=1, le=MAX_ROUTE_POINTS)
    weight: float = Field(default=3.8, ge=0, le=1e3)

    def match_options(self) -> dict[str, float | int | None]:
        """The keywords of :func:`models.skyline.match_skylines` (and of the skyline agent) these settings give."""
        return {
            "step_deg": self.step_deg,
            "max_heading_deg": self.max_heading_deg,
            "max_pitch_deg": self.max_pitch_deg,
            "truncate_deg": self.truncate_deg,
            "max_roll_deg": self.max_roll_deg,
            "roll_candidates": self.roll_candidates,
        }


class RenderSpec(_Spec):
    """How the map's viewframes are rendered (:mod:`models.viewframes`) and posted: ``{workers: null,
    viewframes_per_worker: 250, inline: false}``. ``workers`` processes, each with its own offscreen
    renderer, render shares of the route (the viewframes are the same as rendered in one process);
    null: one worker per ``viewframes_per_worker`` route points, at most the machine's CPU count
    (a worker costs a few seconds to start, so short routes render in the calling process);
    1: in the calling process. ``inline``: false (default) posts each ``viewframe`` message
    without its pixels when the viewframes are in a viewframe cache entry, naming the entry, and
    the agents read the pixels from it (every agent's host must see the cache folder at the same
    path); true: the pixels travel in the messages (agents on hosts without a shared folder).
    Without a cache the pixels are always inline.

    ``views_per_leg``: viewframes per leg of the route: 1 renders one at each route point (the
    seed paper's), ``F`` also ``F - 1`` between each route point and the next, evenly along the
    leg, looking along it (:func:`models.viewframes.view_route`). The answer is still a route
    point (the one nearest the chosen viewframe) and its position the chosen viewframe's: a camera
    between route points looks along the leg it drives on, as viewframe ``k`` looks at ``k + 1``, so
    with one viewframe per point it matches the point behind it best even when it is nearer the
    one ahead; viewframes between the points resolve that (BENCHMARKS.md). Costs ``F`` times the
    rendering, memory and ranking of one per point. Null (default): :data:`DENSE_VIEWS_PER_LEG` on
    routes of fewer than :data:`DENSE_ROUTE_POINTS` points, 1 on longer ones (where the track
    window, not the single frame, bounds the search and the cost is what matters); read it as
    :meth:`views` (or :attr:`Scenario.views_per_leg`).
    """

    workers: int | None = Field(default=None, ge=1, le=256)
    viewframes_per_worker: int = Field(default=250, ge=1, le=MAX_ROUTE_POINTS)
    inline: bool = False
    views_per_leg: int | None = Field(default=None, ge=1, le=MAX_VIEWS_PER_LEG)

    def views(self, points: int) -> int:
        """Viewframes per leg on a route of ``points`` route points (see the class docstring)."""
        if self.views_per_leg is not None:
            return self.views_per_leg
        return DENSE_VIEWS_PER_LEG if points < DENSE_ROUTE_POINTS else 1

    def worker_count(self, viewframes: int) -> int:
        """The number of worker processes for a route of ``viewframes`` points (1: none)."""
        if self.workers is not None:
            return min(self.workers, max(1, viewframes))
        cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        return max(1, min(cpus, viewframes // self.viewframes_per_worker))


class RefineSpec(_Spec):
    """Pose refinement after the decision (:mod:`models.refine`, :mod:`knowledge_sources.refiner`):
    ``{enabled: true, along_m: 20, across_m: 8, levels: 2, grid: 5, edge_weight: 2}``: positions
    within ``along_m`` along and ``across_m`` across the chosen route point's heading are
    searched, ``levels`` times on a ``grid`` x ``grid`` pattern that shrinks each time; a view's
    score is its skyline error plus ``edge_weight`` times one minus its edge correlation.
    ``position: false`` (default) refines heading and pitch only: on the evaluation set's tuning
    split the position search made the median error worse than the route point's (BENCHMARKS.md).
    ``max_roll_deg`` (default 0) is the skyline match's roll bound in the refiner's scores (the
    ranker's is ``skyline.max_roll_deg``): fitting the roll there flattened the score across
    positions, and the position search missed a known offset it finds without
    (tests/models/test_refine.py). ``recheck: true`` scores the heading and pitch found at the
    chosen viewframe again in a view rendered at them (the first view is the viewframe's own,
    read from the viewframe cache when it has it); the default, false, keeps the first match's
    heading, pitch and score: one render less a frame (at 10,000 viewframes, half the refiner's
    CPU), and on the evaluation set's tuning split (200 frames, tracking on) the same top-1 and
    position errors, single-frame heading error mean 2.08 -> 2.04 deg, median 1.11 -> 1.12 deg,
    90th percentile 3.92 -> 3.88 deg (BENCHMARKS.md). ``memory_heading: true`` (default): where
    the skyline's match at the chosen viewframe is worse than half a degree (the skyline trust's
    full-trust bound, :data:`models.skyline.TRUST_DEG`: a horizon found wrongly, e.g. under clouds),
    the heading and pitch come from the memory's shift search against the viewframe instead
    (:func:`models.refine.refine_pose`'s ``pattern``). Through the pipeline on the evaluation
    set's tuning split the single-frame heading error went from 1.05 / 2.13 / 4.04 degrees
    (median / mean / 90th percentile) to 1.01 / 1.77 / 3.89 (larger pose errors 1.74 / 3.44 /
    8.59 -> 1.70 / 3.04 / 6.81), and on five tuning-seeded cases whose camera frames the
    evaluation set's rasteriser made (clouds, other frame sizes) each case's median from 1.6-6.6
    to 0.4-1.2 degrees, where the route's own heading is off by 1.8-3.9 (BENCHMARKS.md, "The
    heading where the skyline fails")."""

    enabled: bool = True
    position: bool = False
    recheck: bool = False
    memory_heading: bool = True
    along_m: float = Field(default=20.0, ge=0, le=MAX_SIZE_M)
    across_m: float = Field(default=8.0, ge=0, le=MAX_SIZE_M)
    levels: int = Field(default=2, ge=1, le=8)
    grid: int = Field(default=5, ge=3, le=11)
    edge_weight: float = Field(default=2.0, ge=0, le=1e3)
    max_roll_deg: float = Field(default=0.0, ge=0, lt=45)


class VerifySpec(_Spec):
    """Render-and-compare verification of the fused ranking's first candidates before the scene
    analysis (:mod:`models.verify`, :mod:`knowledge_sources.verifier`), opt-in: ``{enabled: true,
    candidates: 5, margin: 1.0, weight: 23.3, timeout_s: 10}``. When the fused ranking's second
    route point is within ``margin`` (its fused score, nats) of the first, the scheduler asks the
    verifier about the fused ranking's first ``candidates`` viewframes: each is rendered at its
    place turned as the camera was, by two alignments (the memory's shift search over its
    ``max_shift`` and the rolls of ``roll_search_deg``, and the skyline's heading, pitch and roll
    up to ``max_roll_deg``), and the camera image's correlation ``c`` with the better-matching
    view is the memory's (the whitened, blurred edge patterns of
    :meth:`models.index.ViewframeIndex.pattern`, best over +-2 rows and columns and the camera
    image turned by the alignment's roll and 0.75 degrees either side). Each candidate's fused
    score gains ``weight * (max_j c_j - c_k)`` nats, and the ranking is sorted again before the
    scene analysis starts; the tracker observes the frame re-scored the same way. ``when``:
    "blind" (default) verifies only frames analysed without a track prior (no tracker, the first
    frame, the track lost), "always" every frame whose first two are within ``margin``.

    ``weight`` is calibrated, not tuned for top-1: the conditional logit of the truth's route
    point among the first 5 viewframes of 1,280 tuning frames (the evaluation set's tuning split
    and bench/tracking.py's extra tuning drives, 640 frames each under the standard and the larger
    pose errors; ``bench/rerank.py --extra``) gives ``0.630 F - 14.71 c``, i.e. 23.3 nats of F per
    unit of correlation. There, at these defaults, top-1 of the fused ranking rose 0.705 -> 0.759
    (standard pose errors; 52 of the 189 wrong frames fixed, 17 of the 451 right ones broken) and
    0.636 -> 0.675 (larger; 55 of 233 fixed, 30 of 407 broken); 8 candidates gained about half a
    point more, 3 (the first version's count, then route points) one to two points less; a margin
    of 2 nats, or none, changed at most three frames. Through the pipeline on the tuning split:
    single-frame top-1 0.735 -> 0.795 (standard), 0.640 -> 0.660 (larger), tracked 0.795 -> 0.820
    and 0.700 -> 0.725. **Off by default**: held out, measured once afterwards, it lost: single
    frame 0.806 -> 0.785 (standard; 12 fixed, 18 of 232 right frames broken, terraced mesas 0.768
    -> 0.696) and 0.681 -> 0.698 (larger), tracked 0.840 -> 0.826 and 0.736 -> 0.712, and
    ``bench/tracking.py``'s tracked top-1 86.4 -> 82.9 % (BENCHMARKS.md, "Render and compare,
    turned as the camera was"): on terrain whose fused ranking is already right four times in
    five, the correlations break more frames than they fix. Decided again on a split made for
    it (``confirm``, by a rule written before it ran): single frame +2.4 points, but tracked top-1
    (a mission's answer) 0.807 -> 0.799 pooled, so it stays off; with ``when: blind`` on a second
    such split (``confirm2``) single frame +0.7 points, under the +1.0 its rule asked: off. A
    verification that does not come within ``timeout_s`` leaves the ranking as it is (the frame's
    record says so)."""

    enabled: bool = False
    candidates: int = Field(default=5, ge=2, le=20)
    margin: float = Field(default=1.0, ge=0, le=1e3)
    weight: float = Field(default=23.3, ge=0, le=1e3)
    timeout_s: float = Field(default=10.0, gt=0, le=3600)
    when: Literal["blind", "always"] = "blind"
    roll_search_deg: tuple[float, ...] = ROLL_SEARCH_DEG
    max_roll_deg: float = Field(default=3.0, ge=0, lt=45)

    @field_validator("roll_search_deg")
    @classmethod
    def _rolls(cls, value: tuple[float, ...]) -> tuple[float, ...]:
        return _roll_angles(value)


class TrackingSpec(_Spec):
    """Tracking along the route (:mod:`models.tracking`): a grid filter over arc length.

    Example: ``tracking: {enabled: true, smoothing: false, cell_m: 2.0}``.

    Grid: ``cell_m`` metres of route per cell; the grid runs on past the last route point by
    ``tail`` of the last leg. Motion per frame: forward by up to ``cruise_points`` mean route
    spacings (or ``max_speed_mps`` * dt when frames carry a ``time`` and that is more), with
    probability ``p_skip`` by up to ``max_skip_points`` spacings (dropped frames), a stop with
    probability ``p_stop``, a reversal of up to ``reverse_m`` with probability ``p_reverse``; a
    jump anywhere on the route with probability ``p_kidnap`` (relocalization). Speed state: the
    step's speed class (a part of that kernel) is kept from the previous step with probability
    ``speed_persistence`` (then moved to a neighbouring class with probability ``speed_walk``),
    else drawn afresh from the kernel; 0 is the kernel alone. Observation: the
    frame's ranking (every ranking source the scheduler uses, fused by its rule:
    :mod:`knowledge_sources.fusion`) as a likelihood, ``log(eps_f + exp(gain - z / temperature))``
    with ``z`` the fused score above the best: with ``scores: nats`` the calibrated fusion's
    negative log posterior as it is (nats), with ``robust`` standardised per frame by its robust
    spread (the tracker before the calibrated fusion), the floor ``eps_f = eps + margin_scale / margin``
    higher when the ranking's margin is low, each route point's term spread along the route by a
    Gaussian of ``spread`` mean route spacings (the ranking's own along-route error);
    the parameters were measured on the fused ranking of the evaluation set's tuning split
    (maximum likelihood, then the tracked top-1 over a grid; ``gain`` fixed; ``spread`` and
    ``speed_persistence`` refitted with three viewframes a leg on the tuning drives;
    bench/tracking_calibrate.py, BENCHMARKS.md). ``evidence``: where a ranking's evidence stands
    along the route with viewframes between the route points: ``views``, each viewframe's at its
    own arc length (the default), or ``points``, its viewframes' total lumped at the route point
    (the tracker before session 10, which threw away where along a leg the ranking puts the
    camera). ``outlier`` > 0: the likelihood is the mixture ``(1 - outlier) D(s) + outlier / length``
    of the frame's density over arc length ``D`` (the evidence weights ``exp(-z / temperature)``
    normalised, each spread by its Gaussian) and a uniform one (a frame whose ranking says nothing
    about where the camera is: ``eps`` is then unused); 0 is the floor ``eps_f`` above, as before.
    ``temperature`` 0.67, ``spread`` 0.2, ``outlier`` 0.03 and ``evidence: views`` were chosen
    together on the TUNING drives only (session 10, issue 9; BENCHMARKS.md "Session 10: the
    tracker's observation, sharper and where its views stand"): the fused posterior taken at
    temperature 1 is under-confident (its route points of probability 0.3-0.5 are right 46-64 % of
    the time, those of 0.01-0.03 only 0.1-0.3 %), its maximum-likelihood sharpening with a uniform
    outlier part is temperature 0.33-0.38 with an outlier weight of 1 % (over-confident for
    tracking: consecutive frames' errors are correlated), and the tracked top-1 of every tuning
    source is on a plateau at temperature 0.5-0.67, outlier 0.01-0.03, spread 0.2 (route
    spacings) with the evidence at the viewframes; of it 0.67, the softer end, because at 0.5 a
    stop with every third ranking confidently wrong (tests/models/test_tracking.py) drifts onto
    the wrong point. ``reliability``: assumed landmark
    detector reliability for the scene analysis's answers. State: ``tracking`` from a confidence
    (posterior mass on the chosen route point) of ``enter`` on, ``lost`` below ``exit``.
    ``smoothing``: offline forward-backward over the whole drive (frames from files), with the
    plain kernel (``smoother: plain``) or over the joint (speed class, cell) state of the speed
    state (``speed``; :func:`models.tracking.smooth`). ``plain`` is the default because on the
    TUNING drives the joint smoother was right less often (pooled 75.2 against 76.4 %, session
    10, helper trackgap; on synthetic drives whose speed persists it is the better one).
    ``max_skip_points`` 5 and ``p_skip`` 0.3 (were 6 and 0.15; session 10, trackgap): the
    one-step maximum likelihood of the kernel at the true moves of the tuning drives (evaluation
    set tuning split and its extra tuning drives, 484 moves; bench/tracking_calibrate.py's
    simulated drives, 284) is at a skip bound of 5 spacings, flat in ``p_skip`` over 0.15-0.3
    (within 0.012 nats a move); of that range the tracked top-1 of the tuning sources is best at
    0.3 (pooled 74.7 against 73.8 %, kidnaps and sweeps no worse; BENCHMARKS.md "Session 10:
    gaps, the route's end and the smoother"). ``p_skip`` 0.5 (session 11, issue 9; BENCHMARKS.md
    "Session 11: the drives against their frames"): on the held-out drives the single frame is
    strong (83 %) and the track was right less often than its frames; on the TUNING drives the
    one kind of frame on which the track lost to the frame was the gap (2.5-5 spacings since the
    frame before: 150 frames, the frame right 66 %, the track 53 %; it stays behind or lands
    short, since it moves from a belief that lags, not from the true place the one-step fit
    starts from), and on drives whose frames are strong that loss outweighs what the track gains
    elsewhere (synthetic drives of the tuning moves with strong rankings, tests/models/test_tracking.py:
    the track at 0.3 right on 89.4 % of the frames against the frames' own 93.3 %, at 0.5 on 93.5 %).
    A heavier skip part follows them: on the tuning sources (the evaluation set's tuning split, its
    extra tuning drives and 16 more, standard and larger errors, the simulated drives; 1,848 frames
    after the warm-up) gaps 53 -> 62 %, the drives on which the single frame is right 70 % or more
    77.8 -> 80.2 % (single 76.2 %), pooled 73.7 -> 74.3 %, within the warm-up the same, sweeps -2
    frames; 0.45-0.6 is the plateau, 0.7 lower. (Held out, measured once after the choice: the
    drives' top-1 the same, 76.2 % against the frames' 83.3 %, on each drive.)
    """

    enabled: bool = True
    smoothing: bool = False
    smoother: Literal["plain", "speed"] = "plain"
    cell_m: float = Field(default=2.0, gt=0, le=MAX_SIZE_M)
    tail: float = Field(default=0.5, ge=0, le=100)
    max_speed_mps: float = Field(default=30.0, gt=0, le=MAX_SPEED_MPS)
    cruise_points: float = Field(default=2.0, gt=0, le=MAX_ROUTE_POINTS)
    max_skip_points: float = Field(default=5.0, gt=0, le=MAX_ROUTE_POINTS)
    p_skip: float = Field(default=0.5, ge=0, le=1)
    p_stop: float = Field(default=0.1, ge=0, lt=1)
    p_reverse: float = Field(default=0.02, ge=0, lt=1)
    reverse_m: float = Field(default=10.0, ge=0, le=MAX_COORD_M)
    p_kidnap: float = Field(default=0.02, ge=0, lt=1)
    speed_persistence: float = Field(default=0.3, ge=0, lt=1)
    speed_walk: float = Field(default=0.25, ge=0, le=1)
    temperature: float = Field(default=0.67, gt=0, le=1000)
    gain: float = Field(default=0.0, ge=-100, le=100)
    eps: float = Field(default=1e-4, ge=0, le=1)
    margin_scale: float = Field(default=0.0, ge=0, le=1000)
    spread: float = Field(default=0.2, ge=0, le=1000)
    outlier: float = Field(default=0.03, ge=0, lt=1)
    evidence: Literal["views", "points"] = "views"
    scores: Literal["nats", "robust"] = "nats"
    reliability: float = Field(default=0.8, gt=0.5, lt=1)
    enter: float = Field(default=0.5, gt=0, le=1)
    exit: float = Field(default=0.25, ge=0, le=1)

    @model_validator(mode="after")
    def _hysteresis(self) -> TrackingSpec:
        if self.exit > self.enter:
            raise ValueError(f"exit must be <= enter ({self.enter})")
        if self.p_stop + self.p_reverse >= 1:
            raise ValueError("p_stop + p_reverse must be < 1")
        return self


class ExpectSpec(_Spec):
    """Expected outcome of running the scenario (checked by the pytest plugin). ``top1_min`` and
    ``mean_error_m_max`` judge the final answer (the track when tracking is on);
    ``top1_frame_only_min`` the single-frame decisions beside it."""

    strategy: Literal["associative", "prior"] | None = None
    top1_min: float | None = Field(default=None, ge=0, le=1)
    top1_frame_only_min: float | None = Field(default=None, ge=0, le=1)
    mean_queries_max: float | None = Field(default=None, gt=0, le=1e6)
    mean_error_m_max: float | None = Field(default=None, gt=0, le=MAX_COORD_M)
    fewer_queries_than_prior: bool = False
    processes: bool = False


class Scenario(_Spec):
    """A validated scenario. Build it with :func:`load_scenario` or :func:`scenario_from_dict`."""

    name: str = Field(min_length=1, max_length=200)
    seed: int = Field(default=0, ge=0, le=MAX_SEED)
    crs: str | None = Field(default=None, min_length=1, max_length=1000)
    terrain: TerrainSpec
    landmarks: list[LandmarkSpec] = Field(default_factory=list)
    route: list[tuple[float, float]] = Field(min_length=2, max_length=MAX_ROUTE_POINTS)
    camera: CameraSpec
    sensor: SensorSpec | None = None
    memory: MemorySpec = MemorySpec()
    scheduler: SchedulerSpec = SchedulerSpec()
    skyline: SkylineSpec = SkylineSpec()
    render: RenderSpec = RenderSpec()
    refine: RefineSpec = RefineSpec()
    verify: VerifySpec = VerifySpec()
    tracking: TrackingSpec = TrackingSpec()
    expect: ExpectSpec | None = None

    _path: Path | None = PrivateAttr(default=None)
    _frame: Any = PrivateAttr(default=None)

    @property
    def views_per_leg(self) -> int:
        """Viewframes per leg of this scenario's route (:meth:`RenderSpec.views`)."""
        return self.render.views(len(self.route))

    @field_validator("crs")
    @classmethod
    def _known_crs(cls, value: str | None) -> str | None:
        if value is not None:
            from models.georef import parse_crs

            parse_crs(value)
        return value

    @field_validator("landmarks")
    @classmethod
    def _unique_ids(cls, value: list[LandmarkSpec]) -> list[LandmarkSpec]:
        seen: set[str] = set()
        for lm in value:
            if lm.id in seen:
                raise ValueError(f"duplicate landmark id {lm.id!r}")
            seen.add(lm.id)
        return value

    @field_validator("route")
    @classmethod
    def _distinct(cls, value: list[tuple[float, float]]) -> list[tuple[float, float]]:
        for i, point in enumerate(value):
            if not all(math.isfinite(v) and abs(v) <= MAX_COORD_M for v in point):
                raise ValueError(f"point {i} must be finite, within ±{MAX_COORD_M:g} m")
        for i, (a, b) in enumerate(zip(value, value[1:]), start=1):
            if math.hypot(b[0] - a[0], b[1] - a[1]) < 1e-6:
                raise ValueError(f"points {i - 1} and {i} coincide")
        return value

    @property
    def path(self) -> Path | None:
        """The scenario file, or None for a scenario built from a dict without a path."""
        return self._path

    @property
    def map_frame(self):
        """The :class:`~models.georef.MapFrame` of a georeferenced map, else None (local metres)."""
        return self._frame

    @property
    def base_dir(self) -> Path:
        """Folder relative paths resolve against: the scenario file's folder (else the cwd)."""
        return self._path.parent if self._path is not None else Path.cwd()


_MESSAGES = {
    "greater_than": "must be > {gt}",
    "greater_than_equal": "must be >= {ge}",
    "less_than": "must be < {lt}",
    "less_than_equal": "must be <= {le}",
    "missing": "is required",
    "extra_forbidden": "unknown field",
    "too_short": "needs at least {min_length} items",
    "too_long": "allows at most {max_length} items",
    "string_too_short": "must not be empty",
    "string_too_long": "must be at most {max_length} characters",
    "int_parsing": "must be an integer",
    "int_from_float": "must be an integer",
    "int_type": "must be an integer",
    "float_parsing": "must be a number",
    "float_type": "must be a number",
    "finite_number": "must be a finite number",
    "string_type": "must be a string",
    "bool_parsing": "must be true or false",
    "bool_type": "must be true or false",
    "list_type": "must be a list",
    "tuple_type": "must be a list of two numbers",
    "model_type": "must be a mapping",
    "model_attributes_type": "must be a mapping",
    "dict_type": "must be a mapping",
    "literal_error": "must be one of {expected}",
    "path_type": "must be a path",
}


def _field_path(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else str(part)
    return out


def _message(err: ErrorDetails) -> str:
    kind = err["type"]
    if kind == "value_error":
        msg = str(err.get("ctx", {}).get("error", err["msg"]))
        return msg
    template = _MESSAGES.get(kind)
    if template is None:
        return err["msg"]
    ctx = {k: (f"{v:g}" if isinstance(v, float) else v) for k, v in err.get("ctx", {}).items()}
    try:
        return template.format(**ctx)
    except (KeyError, IndexError):
        return err["msg"]


def validation_problem(exc: ValidationError) -> tuple[str | None, str]:
    """``(field path, message)`` of a pydantic error, worded as this module's scenario errors
    (``landmarks[3].height``, ``must be > 0 (and 2 more errors)``); for other user files too."""
    errors = exc.errors()
    # union members (e.g. route tuple) report the deepest location first; keep the first error
    err = errors[0]
    more = f" (and {len(errors) - 1} more error{'s' if len(errors) > 2 else ''})" if len(errors) > 1 else ""
    return _field_path(tuple(err["loc"])) or None, _message(err) + more


def _model_at(loc: tuple[Any, ...]) -> type[BaseModel] | None:
    """The spec class whose fields are at ``loc`` (a field path into :class:`Scenario`), or None."""
    import typing

    cls: type[BaseModel] = Scenario
    for part in loc:
        if isinstance(part, int):
            continue
        field = cls.model_fields.get(str(part))
        if field is None:
            return None
        todo, found = [field.annotation], None
        while todo and found is None:
            t = todo.pop()
            if isinstance(t, type) and issubclass(t, BaseModel):
                found = t
            else:
                todo.extend(typing.get_args(t))
        if found is None:
            return None
        cls = found
    return cls


def _did_you_mean(err: ErrorDetails) -> str:
    """`` (did you mean cell_size?)`` for a misspelt field, else ``""``."""
    import difflib

    loc = tuple(err["loc"])
    if err["type"] != "extra_forbidden" or not loc or not isinstance(loc[-1], str):
        return ""
    model = _model_at(loc[:-1])
    if model is None:
        return ""
    close = difflib.get_close_matches(loc[-1], list(model.model_fields), n=2, cutoff=0.6)
    if not close:
        return f" (known: {', '.join(model.model_fields)})"
    return f" (did you mean {' or '.join(close)}?)"


def _to_scenario_error(exc: ValidationError, path: Path | None) -> ScenarioError:
    """One error listing every problem, one line each naming the file and field; the first
    problem's field is ``.field`` and ``.problems`` holds all (field, message) pairs."""
    problems: list[tuple[str | None, str]] = []
    seen: set[str | None] = set()
    for err in exc.errors():
        field = _field_path(tuple(err["loc"])) or None
        if field in seen:  # members of a union report one mistake several times
            continue
        seen.add(field)
        problems.append((field, _message(err) + _did_you_mean(err)))
    first_field, first = problems[0]
    rest = "".join("\n" + ": ".join(str(p) for p in (path, f, m) if p) for f, m in problems[1:])
    error = ScenarioError(path, first_field, first + rest)
    error.problems = problems  # type: ignore[attr-defined]
    return error


def scenario_from_dict(data: dict, *, path: Path | None = None) -> Scenario:
    """Validate ``data`` (the parsed YAML) into a :class:`Scenario`.

    ``path`` is the file it came from: relative paths resolve against its folder and errors
    name it. Raises :class:`ScenarioError` listing every problem, one line each with its field
    path, a misspelt field with the names it may have meant.
    """
    path = None if path is None else Path(path)
    if not isinstance(data, dict):
        raise ScenarioError(path, None, f"must be a mapping at the top level, not {type(data).__name__}")
    if "path" in data:
        raise ScenarioError(path, "path", "unknown field")
    base_dir = path.parent if path is not None else Path.cwd()
    try:
        scenario = Scenario.model_validate(data, context={"base_dir": base_dir})
    except ValidationError as exc:
        raise _to_scenario_error(exc, path) from None
    scenario._path = path
    return _georeferenced(scenario, path)


def _georeferenced(scenario: Scenario, path: Path | None) -> Scenario:
    """The scenario with its coordinates in local metres and its map frame, for a georeferenced map."""
    from models.errors import InputError
    from models.terrain_sources import terrain_frame

    try:
        frame = terrain_frame(scenario.terrain, base_dir=scenario.base_dir)
    except InputError as exc:  # name the scenario field as well as the file
        field = "terrain.dem" if scenario.terrain.dem is not None else "terrain.contours"
        raise ScenarioError(path, field, str(exc)) from None
    if frame is None:
        if scenario.crs is not None:
            raise ScenarioError(
                path,
                "crs",
                "needs a georeferenced map: terrain.dem a GeoTIFF (or other GDAL "
                "raster) with a CRS, or contour lines with a CRS",
            )
        return scenario
    src = scenario.crs or frame.crs
    label = scenario.crs or frame.name

    def convert(fields: list[str], pts: list[tuple[float, float]]) -> list[tuple[float, float]]:
        x, y = frame.to_local([p[0] for p in pts], [p[1] for p in pts], crs=src)
        for field, p, a, b in zip(fields, pts, x.tolist(), y.tolist()):
            if not (math.isfinite(a) and math.isfinite(b)):
                raise ScenarioError(path, field, f"({p[0]:g}, {p[1]:g}) cannot be converted from {label}")
        return [(float(a), float(b)) for a, b in zip(x.tolist(), y.tolist())]

    route = list(scenario.route)
    update: dict[str, Any] = {"route": convert([f"route[{i}]" for i in range(len(route))], route)}
    if scenario.landmarks:
        xy = convert(
            [f"landmarks[{i}]" for i in range(len(scenario.landmarks))], [(lm.x, lm.y) for lm in scenario.landmarks]
        )
        update["landmarks"] = [lm.model_copy(update={"x": x, "y": y}) for lm, (x, y) in zip(scenario.landmarks, xy)]
    sensor = scenario.sensor
    if sensor is not None and sensor.frames:
        frames = list(sensor.frames)
        truths = {i: f.truth for i, f in enumerate(frames) if f.truth is not None}
        if truths:
            xy = convert([f"sensor.frames[{i}].truth" for i in truths], [(t.x, t.y) for t in truths.values()])
            for (i, t), (x, y) in zip(truths.items(), xy):
                frames[i] = frames[i].model_copy(update={"truth": t.model_copy(update={"x": x, "y": y})})
            update["sensor"] = sensor.model_copy(update={"frames": frames})
    out = scenario.model_copy(update=update)
    out._path, out._frame = scenario._path, frame
    log.debug("scenario %s: coordinates in %s converted to local metres (origin %s)", path, label, frame.origin)
    return out


_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario YAML file; raises :class:`ScenarioError`."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ScenarioError(path, None, "file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(path, None, f"cannot read: {exc}") from None
    try:
        # libyaml's parser where PyYAML has it (the same data and error marks, about 4x faster:
        # a generated route of 10,000 points is a 350 KB file, read by several agents of a run)
        data = yaml.load(text, Loader=_YAML_LOADER)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise ScenarioError(path, None, f"invalid YAML{where}: {problem}") from None
    log.debug("loaded scenario %s", path)
    return scenario_from_dict(data, path=path)
