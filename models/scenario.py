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
"""

from __future__ import annotations

import logging
import math
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
    "TrackingSpec",
    "ExpectSpec",
    "Scenario",
    "load_scenario",
    "scenario_from_dict",
    "SAMPLE_DEMS",
]

log = logging.getLogger(__name__)

#: names accepted by ``terrain.sample``
SAMPLE_DEMS: tuple[str, ...] = ("jacksboro",)


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


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
    relief: float = Field(gt=0)
    seed: int | None = None


class TerrainSpec(_Spec):
    """``cell_size`` plus exactly one source: ``dem``, ``procedural``, ``contours`` or ``sample``."""

    cell_size: float = Field(gt=0)
    dem: Path | None = None
    procedural: ProceduralSpec | None = None
    contours: Path | None = None
    sample: Literal["jacksboro"] | None = None

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
        return self


class LandmarkSpec(_Spec):
    """A box landmark: footprint centre (x, y), width along local x, depth along local y."""

    id: str = Field(min_length=1)
    kind: str = Field(min_length=1)
    x: float
    y: float
    width: float = Field(gt=0)
    depth: float = Field(gt=0)
    height: float = Field(gt=0)
    yaw_deg: float = 0.0


class CameraSpec(_Spec):
    """Pinhole camera: ``{width: 160, height: 120, fov_y_deg: 45, eye_height: 2.0, near: 1, far: 5000}``."""

    width: int = Field(ge=8, le=4096)
    height: int = Field(ge=8, le=4096)
    fov_y_deg: float = Field(gt=0, lt=180)
    eye_height: float = Field(ge=0)
    pitch_deg: float = Field(default=0.0, gt=-90, lt=90)
    near: float = Field(gt=0)
    far: float = Field(gt=0)

    @field_validator("far")
    @classmethod
    def _beyond_near(cls, value: float, info: ValidationInfo) -> float:
        near = info.data.get("near")
        if near is not None and value <= near:
            raise ValueError(f"must be > near ({near:g})")
        return value


class TruthSpec(_Spec):
    """True pose of a camera frame (for evaluation only)."""

    x: float
    y: float
    heading_deg: float


class FrameSpec(_Spec):
    """A camera image taken during the mission; ``image`` must exist. ``time``: seconds (any
    origin), increasing along ``sensor.frames``, which are in time order."""

    image: Path
    truth: TruthSpec | None = None
    time: float | None = Field(default=None, allow_inf_nan=False)

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

    interval_s: float = Field(default=2.0, gt=0)
    speed_mps: tuple[float, float] = (8.0, 20.0)
    speed_change: float = Field(default=0.2, ge=0, le=1)
    p_stop: float = Field(default=0.05, ge=0, lt=1)
    stop_frames: int = Field(default=3, ge=1)
    lateral_m: float = Field(default=1.5, ge=0)
    heading_deg: float = Field(default=3.0, ge=0)
    start: float = Field(default=0.0, ge=0, lt=1)
    kidnap_at: int | None = Field(default=None, ge=1)
    kidnap_to: float | None = Field(default=None, ge=0, lt=1)
    frames: int | None = Field(default=None, ge=1)

    @field_validator("speed_mps")
    @classmethod
    def _speeds(cls, value: tuple[float, float]) -> tuple[float, float]:
        if not 0 <= value[0] <= value[1] or value[1] <= 0:
            raise ValueError("must be [min, max] with 0 <= min <= max and max > 0")
        return value


class SimulateSpec(_Spec):
    """Simulated camera frames near the route points (see the end-to-end issue), or along a
    ``drive`` (then ``per_point``, ``stride``, ``jitter_*`` and ``advance`` do not apply)."""

    per_point: int = Field(default=1, ge=1)
    stride: int = Field(default=1, ge=1)  # frames at every stride-th route point only
    jitter_m: float = Field(default=1.5, ge=0)
    jitter_deg: float = Field(default=3.0, ge=0)
    advance: float = Field(default=0.15, ge=0, lt=1)
    lighting: float = Field(default=0.3, ge=0)
    haze: float = Field(default=0.2, ge=0)
    gain: float = Field(default=0.2, ge=0)
    gamma: float = Field(default=0.2, ge=0)
    noise: float = Field(default=4.0, ge=0)
    blur: float = Field(default=0.7, ge=0)
    texture: float = Field(default=0.3, ge=0)
    seed: int | None = Field(default=None, ge=0)
    drive: DriveSpec | None = None


class SensorSpec(_Spec):
    """Exactly one of ``frames`` (real images) or ``simulate``."""

    frames: list[FrameSpec] | None = Field(default=None, min_length=1)
    simulate: SimulateSpec | None = None

    @model_validator(mode="after")
    def _exactly_one(self) -> SensorSpec:
        if (self.frames is None) == (self.simulate is None):
            raise ValueError("needs exactly one of frames, simulate")
        if self.frames:
            given = [f.time for f in self.frames]
            if any(t is not None for t in given):
                times = [t for t in given if t is not None]
                if len(times) != len(given):
                    raise ValueError("frames: give a time for every frame or for none")
                for i, (a, b) in enumerate(zip(times, times[1:]), start=1):
                    if b <= a:
                        raise ValueError(f"frames[{i}].time: must be > the previous frame's ({a:g}): "
                                         "frames are in time order")
        return self


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
    degree of pitch moves the horizon about 2.7 rows and one degree of heading about 2.0
    columns); ``key`` the K-GEN method of :mod:`models.memory_keys`.

    The defaults were chosen on the tuning split of the evaluation set (``bench/evalset``,
    ``bench/ranking_sweep.py``; BENCHMARKS.md, "Associative ranking defaults"): one viewframe
    per bank (superposing two lost 3-6 points of ranking top-1 there), rows +-8 (pitch errors of
    up to 2 degrees plus eye-height and terrain differences; +-2 lost 8 points), columns +-16
    (about 8 degrees of heading). Example::

        memory: {size: 128, blur_sigma: 1.0, bank_size: 1, shard_size: 512, max_shift: [8, 16]}
    """

    size: int = 128
    edge: Literal["sobel", "scharr", "laplacian", "canny", "none"] = "sobel"
    blur_sigma: float = Field(default=1.0, gt=0)
    whiten: bool = True
    bank_size: int = Field(default=1, ge=1)
    shard_size: int = Field(default=512, ge=1)
    max_shift: tuple[int, int] = (8, 16)
    key: Literal["phase", "quantized"] = "phase"

    @field_validator("max_shift")
    @classmethod
    def _shift_range(cls, value: tuple[int, int]) -> tuple[int, int]:
        if not all(0 <= v <= 16 for v in value):
            raise ValueError("must be two integers in 0..16")
        return value

    @field_validator("size")
    @classmethod
    def _power_of_two(cls, value: int) -> int:
        if not 16 <= value <= 1024 or value & (value - 1):
            raise ValueError("must be a power of two in 16..1024")
        return value


class SchedulerSpec(_Spec):
    """Scene-analysis scheduler and landmark detector settings (the rule is documented in
    :mod:`knowledge_sources.scene_analysis`).

    ``candidates`` best viewframes of the ranking are verified; the best is accepted at posterior
    ``accept``; ``reliability`` is the detectors' assumed reliability, ``beta`` the sharpness of
    the ranking weights; a landmark is asked about only where it covers at least ``min_pixels``
    pixels of the viewframe; a detector answers *present* from ``detector_threshold`` and *absent*
    below ``absent_threshold``; an unanswered query times out after ``query_timeout_s``. The
    defaults were chosen on simulated frames of the bundled scenarios with other seeds than theirs
    (BENCHMARKS.md). Example::

        scheduler: {candidates: 8, accept: 0.6, min_pixels: 60, detector_threshold: 0.65}
    """

    candidates: int = Field(default=8, ge=1)
    accept: float = Field(default=0.6, gt=0, le=1)
    reliability: float = Field(default=0.8, gt=0.5, lt=1)
    beta: float = Field(default=3.0, gt=0)
    min_pixels: int = Field(default=60, ge=1)
    detector_threshold: float = Field(default=0.65, ge=0, le=1)
    absent_threshold: float = Field(default=0.15, ge=0, le=1)
    query_timeout_s: float = Field(default=10.0, gt=0)
    strategy: Literal["associative", "prior"] = "associative"

    @model_validator(mode="after")
    def _thresholds(self) -> SchedulerSpec:
        if self.absent_threshold > self.detector_threshold:
            raise ValueError(f"absent_threshold must be <= detector_threshold ({self.detector_threshold})")
        return self


class TrackingSpec(_Spec):
    """Tracking along the route (:mod:`models.tracking`): a grid filter over arc length.

    Example: ``tracking: {enabled: true, smoothing: false, cell_m: 2.0}``.

    Grid: ``cell_m`` metres of route per cell; the grid runs on past the last route point by
    ``tail`` of the last leg. Motion per frame: forward by up to ``cruise_points`` mean route
    spacings (or ``max_speed_mps`` * dt when frames carry a ``time`` and that is more), with
    probability ``p_skip`` by up to ``max_skip_points`` spacings (dropped frames), a stop with
    probability ``p_stop``, a reversal of up to ``reverse_m`` with probability ``p_reverse``; a
    jump anywhere on the route with probability ``p_kidnap`` (relocalization). Observation: the
    ranking's variances as a likelihood, ``log(eps_f + exp(gain - z / temperature))`` with ``z`` the
    variance above the best in robust spreads, the floor ``eps_f = eps + margin_scale / margin``
    higher when the ranking's margin is low, each route point's term spread along the route by a
    Gaussian of ``spread`` mean route spacings (the ranking's own along-route error);
    ``temperature``, ``gain``, ``eps``, ``margin_scale`` and ``spread`` were fitted on
    tuning drives (bench/tracking_calibrate.py, BENCHMARKS.md). ``reliability``: assumed landmark
    detector reliability for the scene analysis's answers. State: ``tracking`` from a confidence
    (posterior mass on the chosen route point) of ``enter`` on, ``lost`` below ``exit``.
    ``smoothing``: offline forward-backward over the whole drive (frames from files).
    """

    enabled: bool = True
    smoothing: bool = False
    cell_m: float = Field(default=2.0, gt=0)
    tail: float = Field(default=0.5, ge=0)
    max_speed_mps: float = Field(default=30.0, gt=0)
    cruise_points: float = Field(default=2.0, gt=0)
    max_skip_points: float = Field(default=6.0, gt=0)
    p_skip: float = Field(default=0.15, ge=0, le=1)
    p_stop: float = Field(default=0.1, ge=0, lt=1)
    p_reverse: float = Field(default=0.02, ge=0, lt=1)
    reverse_m: float = Field(default=10.0, ge=0)
    p_kidnap: float = Field(default=0.02, ge=0, lt=1)
    temperature: float = Field(default=1.11, gt=0)
    gain: float = 0.0
    eps: float = Field(default=1e-4, ge=0, le=1)
    margin_scale: float = Field(default=0.0, ge=0)
    spread: float = Field(default=0.45, ge=0)
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
    mean_queries_max: float | None = Field(default=None, gt=0)
    mean_error_m_max: float | None = Field(default=None, gt=0)
    fewer_queries_than_prior: bool = False
    processes: bool = False


class Scenario(_Spec):
    """A validated scenario. Build it with :func:`load_scenario` or :func:`scenario_from_dict`."""

    name: str = Field(min_length=1)
    seed: int = 0
    terrain: TerrainSpec
    landmarks: list[LandmarkSpec] = Field(default_factory=list)
    route: list[tuple[float, float]] = Field(min_length=2)
    camera: CameraSpec
    sensor: SensorSpec | None = None
    memory: MemorySpec = MemorySpec()
    scheduler: SchedulerSpec = SchedulerSpec()
    tracking: TrackingSpec = TrackingSpec()
    expect: ExpectSpec | None = None

    _path: Path | None = PrivateAttr(default=None)

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
        for i, (a, b) in enumerate(zip(value, value[1:]), start=1):
            if not all(math.isfinite(v) for v in (*a, *b)):
                raise ValueError(f"point {i} is not finite")
            if math.hypot(b[0] - a[0], b[1] - a[1]) < 1e-6:
                raise ValueError(f"points {i - 1} and {i} coincide")
        return value

    @property
    def path(self) -> Path | None:
        """The scenario file, or None for a scenario built from a dict without a path."""
        return self._path

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


def _to_scenario_error(exc: ValidationError, path: Path | None) -> ScenarioError:
    errors = exc.errors()
    # union members (e.g. route tuple) report the deepest location first; keep the first error
    err = errors[0]
    more = f" (and {len(errors) - 1} more error{'s' if len(errors) > 2 else ''})" if len(errors) > 1 else ""
    return ScenarioError(path, _field_path(tuple(err["loc"])) or None, _message(err) + more)


def scenario_from_dict(data: dict, *, path: Path | None = None) -> Scenario:
    """Validate ``data`` (the parsed YAML) into a :class:`Scenario`.

    ``path`` is the file it came from: relative paths resolve against its folder and errors
    name it. Raises :class:`ScenarioError` naming the field path on the first problem.
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
    return scenario


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
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise ScenarioError(path, None, f"invalid YAML{where}: {problem}") from None
    log.debug("loaded scenario %s", path)
    return scenario_from_dict(data, path=path)
