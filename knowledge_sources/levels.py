"""The blackboard levels of mapinterp: one typed message class per level, and the ids of its hypotheses.

Each level is one frozen, slotted dataclass deriving from :class:`Message`. Its ``level``
class attribute names the level, its docstring's first line says what one hypothesis stands for,
its fields (with their ``doc``) are the body, and :meth:`Message.to_body` /
:meth:`Message.from_body` convert to and from the plain dict that travels in a hypothesis
(msgpack through :mod:`blackboard.codec`). Construction validates every field against its type
hint (``int``, ``float``, ``str``, ``bool``, ``list``, ``dict``, ``numpy.ndarray`` with an
optional ``dtype``/``ndim``, each optionally ``| None``); a bad body raises
:class:`MessageError` naming the level, the field and the hypothesis. Numpy arrays are passed
through untouched: a message adds no copy to the one the codec makes when it decodes.

The id of every hypothesis is built by a function here (:func:`frame_id`, :func:`viewframe_id`,
...) and :meth:`Message.id` returns it; :func:`post` posts a message under its id.

Adding a level is adding one class::

    @dataclass(frozen=True, slots=True)
    class Odometry(Message):
        \"\"\"The vehicle's odometry at one camera frame.\"\"\"

        level: ClassVar[str] = "odometry"
        posted_by: ClassVar[str] = "odometer"
        id_pattern: ClassVar[str] = "od-<frame:06d>"
        frame: int = field(metadata={"doc": "camera frame number"})
        distance_m: float = field(metadata={"doc": "metres driven since the previous frame"})

        def id(self) -> str:
            return odometry_id(self.frame)


    def odometry_id(frame: int) -> str:
        return f"od-{frame:06d}"

The class registers itself (:data:`MESSAGES`), the level name constant is ``Odometry.level``, and
the levels table below (and in README.md, checked by ``tests/knowledge_sources/test_levels.py``)
is generated from the classes: run ``python -m knowledge_sources.levels`` to print it.

"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Self

import numpy as np

from blackboard.errors import BlackboardError

if TYPE_CHECKING:
    from blackboard.hypothesis import Hypothesis
    from blackboard.knowledge_source import Board
    from models import viewframes as models_viewframes
    from models.associative import Ranking as MemoryRanking
    from models.viewframe_cache import Pixels

__all__ = [
    "ANSWER",
    "Answer",
    "INDEX",
    "Index",
    "MAP",
    "MESSAGES",
    "Map",
    "Message",
    "MessageError",
    "POSITION",
    "POSE",
    "PixelsRef",
    "Pose",
    "Position",
    "QUERY",
    "Query",
    "RANKING",
    "Ranking",
    "SCENARIO",
    "SENSOR_FRAME",
    "Scenario",
    "SensorFrame",
    "TRACK",
    "TRACK_QUERY",
    "TRUTH",
    "Track",
    "TrackQuery",
    "Truth",
    "VERIFICATION",
    "VERIFY_QUERY",
    "Verification",
    "VerifyQuery",
    "VIEWFRAME",
    "Viewframe",
    "answer_id",
    "frame_id",
    "index_id",
    "levels_table",
    "map_id",
    "message_class",
    "pose_id",
    "position_id",
    "post",
    "query_id",
    "ranking_id",
    "scenario_id",
    "track_id",
    "track_query_id",
    "truth_id",
    "verification_id",
    "verify_query_id",
    "viewframe_id",
]


class MessageError(BlackboardError):
    """A hypothesis body does not fit its level's message class.

    Attributes: ``level``, ``field`` (None for the body as a whole), ``hypothesis_id`` (None when
    not known, e.g. while an agent builds a message).
    """

    def __init__(self, level: str, field: str | None, problem: str, *, hypothesis_id: str | None = None) -> None:
        self.level = level
        self.field = field
        self.problem = problem
        self.hypothesis_id = hypothesis_id
        where = f"level {level}" + (f" hypothesis {hypothesis_id}" if hypothesis_id else "")
        super().__init__(f"{where}: {field + ': ' if field else ''}{problem}")


#: level name -> message class, in the order the classes are defined (the pipeline's order)
MESSAGES: dict[str, type[Message]] = {}

_Check = Callable[[Any], Any]


class Message:
    """Base of the level messages (see the module docstring). Subclasses are frozen slotted dataclasses."""

    __slots__ = ()
    #: the level's name (a key chunk)
    level: ClassVar[str]
    #: who posts it, for the levels table
    posted_by: ClassVar[str]
    #: the shape of its hypothesis ids, for the levels table (the id function builds them)
    id_pattern: ClassVar[str]
    #: (field name, check) pairs, built from the type hints on first use
    _checks: ClassVar[tuple[tuple[str, _Check], ...] | None] = None
    _required: ClassVar[frozenset[str]] = frozenset()
    _names: ClassVar[frozenset[str]] = frozenset()
    _order: ClassVar[tuple[str, ...]] = ()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        level = cls.__dict__.get("level")
        if level is None:
            return
        missing = [name for name in ("posted_by", "id_pattern") if name not in cls.__dict__]
        if missing or cls.id is Message.id:
            raise TypeError(
                f"message class {cls.__qualname__} of level {level!r} must define "
                + ", ".join([*missing, *(["id()"] if cls.id is Message.id else [])])
            )
        # dataclass(slots=True) creates the class a second time: replace, do not refuse
        known = MESSAGES.get(level)
        if known is not None and (known.__name__, known.__module__) != (cls.__name__, cls.__module__):
            raise TypeError(f"level {level!r} already has message class {known.__qualname__}")
        MESSAGES[level] = cls

    def __post_init__(self) -> None:
        cls = type(self)
        checks = cls.__dict__.get("_checks") or _build_checks(cls)
        for name, check in checks:
            value = getattr(self, name)
            try:
                new = check(value)
            except (TypeError, ValueError) as err:
                raise MessageError(cls.level, name, str(err)) from None
            if new is not value:
                object.__setattr__(self, name, new)

    def id(self) -> str:
        """The id of the hypothesis carrying this message."""
        raise NotImplementedError(f"{type(self).__name__} has no id function")

    def to_body(self) -> dict[str, Any]:
        """The hypothesis body: every field by name (arrays not copied)."""
        cls = type(self)
        if "_checks" not in cls.__dict__:
            _build_checks(cls)
        return {name: getattr(self, name) for name in cls._order}

    @classmethod
    def from_body(cls, body: Mapping[str, Any], *, hypothesis_id: str | None = None) -> Self:
        """The message of a hypothesis body; :class:`MessageError` names the missing, unknown or bad field."""
        if "_checks" not in cls.__dict__:
            _build_checks(cls)
        if not isinstance(body, Mapping):
            raise MessageError(
                cls.level, None, f"body must be a map, got {type(body).__name__}", hypothesis_id=hypothesis_id
            )
        missing = cls._required.difference(body)
        unknown = set(body).difference(cls._names)
        if missing or unknown:
            name = min(missing) if missing else min(map(str, unknown))
            raise MessageError(
                cls.level, name, "missing" if missing else "not a field of this level", hypothesis_id=hypothesis_id
            )
        try:
            return cls(**body)
        except MessageError as err:
            raise MessageError(cls.level, err.field, err.problem, hypothesis_id=hypothesis_id) from None

    @classmethod
    def from_hypothesis(cls, hypothesis: Hypothesis) -> Self:
        """The message a hypothesis carries; it must be on this class's level."""
        if hypothesis.level != cls.level:
            raise MessageError(
                cls.level,
                None,
                f"hypothesis {hypothesis.id} is on level {hypothesis.level}",
                hypothesis_id=hypothesis.id,
            )
        return cls.from_body(hypothesis.body, hypothesis_id=hypothesis.id)


def message_class(level: str) -> type[Message]:
    """The message class of ``level``; ``KeyError`` names the known levels."""
    try:
        return MESSAGES[level]
    except KeyError:
        raise KeyError(f"no message class for level {level!r}; levels: {', '.join(MESSAGES)}") from None


def post(
    board: Board,
    message: Message,
    *,
    links: Iterable[str] = (),
    credibility: float = 1.0,
    addressed_to: str | None = None,
    deadline_s: float | None = None,
) -> Hypothesis:
    """Post ``message`` on its level under its id (:meth:`Message.id`); keywords as ``Board.post``."""
    return board.post(
        message.level,
        message.to_body(),
        id=message.id(),
        links=links,
        credibility=credibility,
        addressed_to=addressed_to,
        deadline_s=deadline_s,
    )


# -- validation ------------------------------------------------------------------------------------


def _doc(text: str, **extra: Any) -> dict[str, Any]:
    return {"doc": text, **extra}


def _check_for(hint: Any, meta: Mapping[str, Any]) -> _Check:
    """A function returning its argument (or a normalised copy of a scalar), or raising ValueError/TypeError."""
    origin = typing.get_origin(hint)
    if origin in (types.UnionType, typing.Union):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        inner = _check_for(args[0], meta)
        return lambda v: None if v is None else inner(v)
    base = origin or hint
    if base is int:

        def check_int(v: Any) -> Any:
            if type(v) is int:
                return v
            if isinstance(v, np.integer):
                return int(v)
            raise TypeError(f"must be an integer, got {type(v).__name__}")

        return check_int
    if base is float:

        def check_float(v: Any) -> Any:
            if type(v) is float:
                return v
            if isinstance(v, (int, np.integer, np.floating)) and not isinstance(v, bool):
                return float(v)
            raise TypeError(f"must be a number, got {type(v).__name__}")

        return check_float
    if base is bool:

        def check_bool(v: Any) -> Any:
            if isinstance(v, (bool, np.bool_)):
                return bool(v)
            raise TypeError(f"must be true or false, got {type(v).__name__}")

        return check_bool
    if base is str:

        def check_str(v: Any) -> Any:
            if isinstance(v, str):
                return v
            raise TypeError(f"must be a string, got {type(v).__name__}")

        return check_str
    if base is list:
        length = meta.get("length")

        def check_list(v: Any) -> Any:
            if not isinstance(v, (list, tuple)):
                raise TypeError(f"must be a list, got {type(v).__name__}")
            if length is not None and len(v) != length:
                raise ValueError(f"must have {length} entries, got {len(v)}")
            return v

        return check_list
    if base is dict:

        def check_dict(v: Any) -> Any:
            if isinstance(v, dict):
                return v
            raise TypeError(f"must be a map, got {type(v).__name__}")

        return check_dict
    if base is np.ndarray:
        dtype = None if meta.get("dtype") is None else np.dtype(meta["dtype"])
        ndim = meta.get("ndim")
        channels = meta.get("channels")

        def check_array(v: Any) -> Any:
            if not isinstance(v, np.ndarray):
                raise TypeError(f"must be a numpy array, got {type(v).__name__}")
            if dtype is not None and v.dtype != dtype:
                raise TypeError(f"must have dtype {dtype}, got {v.dtype}")
            if ndim is not None and v.ndim != ndim:
                raise ValueError(f"must have {ndim} dimensions, got shape {v.shape}")
            if channels is not None and v.shape[-1] != channels:
                raise ValueError(f"must have {channels} channels (last axis), got shape {v.shape}")
            return v

        return check_array
    raise TypeError(f"unsupported field type {hint!r}")


def _build_checks(cls: type[Message]) -> tuple[tuple[str, _Check], ...]:
    hints = typing.get_type_hints(cls)
    fields = dataclasses.fields(cls)  # type: ignore[arg-type]
    cls._checks = tuple((f.name, _check_for(hints[f.name], f.metadata)) for f in fields)
    cls._required = frozenset(
        f.name for f in fields if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    )
    cls._names = frozenset(f.name for f in fields)
    cls._order = tuple(f.name for f in fields)
    return cls._checks


# -- the levels ------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Scenario(Message):
    """The run's input: which scenario file to localize."""

    level: ClassVar[str] = "scenario"
    posted_by: ClassVar[str] = "user (``mapinterp run``)"
    id_pattern: ClassVar[str] = "scenario"
    path: str = field(metadata=_doc("absolute path of the scenario file"))
    strategy: str = field(metadata=_doc('"associative" or "prior"'))

    def id(self) -> str:
        return scenario_id()


def scenario_id() -> str:
    """Hypothesis id of the run's scenario."""
    return "scenario"


@dataclass(frozen=True, slots=True)
class Viewframe(Message):
    """One a-priori view synthesised from the map at a route point."""

    level: ClassVar[str] = "viewframe"
    posted_by: ClassVar[str] = "map renderer"
    id_pattern: ClassVar[str] = "vf-<index:06d>"
    index: int = field(metadata=_doc("viewframe index k (its route point)"))
    pose: list = field(metadata=_doc("[x, y, z, heading_deg, pitch_deg], world metres and degrees", length=5))
    skyline: np.ndarray = field(
        metadata=_doc(
            "(n,) float32 horizon elevation per azimuth bin, degrees, NaN: none (models.skyline)",
            dtype="float32",
            ndim=1,
        )
    )
    description: dict | None = field(
        default=None,
        metadata=_doc(
            "symbolic description (SymbolicDescription.to_dict); null when the pixels are in the cache "
            "entry named by entry (the description is in the entry too; the map carries what the agents use of it)"
        ),
    )
    image: np.ndarray | None = field(
        default=None,
        metadata=_doc(
            "(H, W, 3) uint8 RGB, null: in the cache entry named by entry (read with pixels())",
            dtype="uint8",
            ndim=3,
            channels=3,
        ),
    )
    mask: np.ndarray | None = field(
        default=None,
        metadata=_doc(
            "(H, W) int16 landmark index per pixel, -1 none; null: in the cache entry named by entry",
            dtype="int16",
            ndim=2,
        ),
    )
    background: np.ndarray | None = field(
        default=None,
        metadata=_doc(
            "(H, W, 3) uint8 RGB, the same view without landmarks, or null when none is in view "
            "(or when the pixels are in the cache entry named by entry)",
            dtype="uint8",
            ndim=3,
            channels=3,
        ),
    )
    entry: str | None = field(
        default=None,
        metadata=_doc(
            "absolute path of the viewframe cache entry holding this viewframe's image, mask and "
            "background at row index (models.viewframe_cache), null: they are inline"
        ),
    )
    entry_count: int | None = field(
        default=None, metadata=_doc("viewframes in that entry (checked when it is read), null: inline")
    )

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        if self.entry is None:
            for name in ("image", "mask", "description"):
                if getattr(self, name) is None:
                    what = "its description" if name == "description" else "its pixels"
                    raise MessageError(self.level, name, f"missing: a viewframe without an entry carries {what}")
            if self.entry_count is not None:
                raise MessageError(self.level, "entry_count", "given without an entry")
            return
        for name in ("image", "mask", "background"):
            if getattr(self, name) is not None:
                raise MessageError(self.level, name, "a viewframe naming a cache entry carries no pixel arrays")
        if self.description is not None:
            raise MessageError(
                self.level,
                "description",
                "a viewframe naming a cache entry carries no description (it is in the entry)",
            )
        if not self.entry.startswith("/"):
            raise MessageError(self.level, "entry", f"must be an absolute path, got {self.entry!r}")
        if self.entry_count is None or not 0 <= self.index < self.entry_count:
            raise MessageError(
                self.level, "entry_count", f"must be a count above the index {self.index}, got {self.entry_count}"
            )

    @classmethod
    def of(cls, viewframe: models_viewframes.Viewframe, *, entry: str | None = None, count: int | None = None) -> Self:
        """The message of a rendered viewframe (:class:`models.viewframes.Viewframe`): its pose as
        a list, its skyline; the depth map stays behind (no agent reads it). Without ``entry``, the
        pixels inline: its image and background as C-contiguous arrays, its mask as int16, and its
        symbolic description as plain data. With ``entry`` (the absolute path of the cache entry
        the viewframe was read from, holding ``count`` viewframes; the viewframe's row is its
        index), no pixel arrays and no description (both are in the entry; no agent reads the
        description from a message: the ``map`` carries what they use of it): a reader gets the
        pixels with :meth:`pixels`."""
        p = viewframe.pose
        pose = [p.x, p.y, p.z, p.heading_deg, p.pitch_deg]
        index = int(viewframe.index)
        if entry is not None:
            return cls(index=index, pose=pose, skyline=viewframe.skyline, entry=entry, entry_count=count)
        background = viewframe.background
        return cls(
            index=index,
            pose=pose,
            description=viewframe.description.to_dict(),
            skyline=viewframe.skyline,
            image=np.ascontiguousarray(viewframe.image),
            mask=viewframe.mask.astype(np.int16),
            background=None if background is None else np.ascontiguousarray(background),
        )

    def pixels(self, *, agent: str) -> Pixels:
        """The viewframe's image, mask and background (:class:`models.viewframe_cache.Pixels`): the
        message's own arrays when inline, else read from the cache entry it names (memory-mapped,
        opened once per process; copies; see :meth:`PixelsRef.pixels` for the errors)."""
        from models.viewframe_cache import Pixels

        ref = self.reference()
        if ref is None:
            assert self.image is not None and self.mask is not None  # __post_init__
            return Pixels(image=self.image, mask=self.mask, background=self.background)
        return ref.pixels(agent=agent)

    def reference(self) -> PixelsRef | None:
        """Where this viewframe's pixels are when it names a cache entry (None: inline): all an
        agent need keep of it to read them later (about 100 bytes)."""
        if self.entry is None:
            return None
        assert self.entry_count is not None  # __post_init__
        return PixelsRef(index=self.index, entry=self.entry, count=self.entry_count)

    @classmethod
    def read(cls, board: Board, index: int) -> Self:
        """Viewframe ``index`` read back from the blackboard, for an agent that missed its event
        (it joined late or restarted); :class:`RuntimeError` when the board does not hold it."""
        got = board.get(viewframe_id(index))
        if got is None:
            raise RuntimeError(f"viewframe {index} is on neither the event stream nor the blackboard")
        return cls.from_hypothesis(got)

    def id(self) -> str:
        return viewframe_id(self.index)


@dataclass(frozen=True, slots=True)
class PixelsRef:
    """Where the pixels of viewframe ``index`` are: row ``index`` of the viewframe cache entry
    ``entry`` (its folder, absolute), which holds ``count`` viewframes (:meth:`Viewframe.reference`)."""

    index: int
    entry: str
    count: int

    def pixels(self, *, agent: str) -> Pixels:
        """The viewframe's pixels read from the entry (:func:`models.viewframe_cache.read_pixels`).
        :class:`models.errors.CacheEntryError` naming the entry, the viewframe and ``agent`` (the
        reader) when this host cannot read the entry or it is not the one the reference names
        (another count: stale)."""
        from models.errors import CacheEntryError
        from models.viewframe_cache import read_pixels

        try:
            return read_pixels(self.entry, self.index, count=self.count)
        except CacheEntryError as err:
            raise CacheEntryError(
                err.path,
                f"agent {agent}, viewframe {viewframe_id(self.index)}: {err.message}. The map renderer posts "
                "viewframes by reference to its viewframe cache: every agent's host must see that folder at the "
                "same path (a shared folder), or set render: {inline: true} in the scenario to post the pixels inline",
            ) from None


def viewframe_id(index: int) -> str:
    """Hypothesis id of viewframe ``index`` on the viewframe level."""
    return f"vf-{index:06d}"


def viewframe_index(hypothesis_id: str) -> int | None:
    """The viewframe index a viewframe hypothesis id names (:func:`viewframe_id`), else None."""
    head, _, digits = hypothesis_id.partition("-")
    return int(digits) if head == "vf" and digits.isdigit() else None


@dataclass(frozen=True, slots=True)
class Map(Message):
    """The map is complete: everything the other agents need of it besides the viewframe images.

    The per-viewframe parts are arrays, so that a consumer decodes them in one copy each (a
    route of 10,000 viewframes as nested lists and maps was 3.2 MB to parse into 18.5 MB of
    objects, in every consumer): ``poses`` one row per viewframe, ``visible`` and ``placements``
    one row per landmark seen in a viewframe (build them from maps with :meth:`of`; read them as
    maps with :meth:`seen`, :meth:`visible_sets` and :meth:`placement_table`)."""

    level: ClassVar[str] = "map"
    posted_by: ClassVar[str] = "map renderer"
    id_pattern: ClassVar[str] = "map"
    scenario: str = field(metadata=_doc("scenario name"))
    path: str = field(metadata=_doc("absolute path of the scenario file"))
    viewframes: int = field(metadata=_doc("number of viewframes"))
    priors: dict = field(metadata=_doc("P(L): {landmark id: prior}"))
    landmarks: list = field(metadata=_doc("[{id, kind, index, x, y}, ...] in scenario order (index: the position)"))
    route: np.ndarray = field(
        metadata=_doc("(N, 2) float64 route points (x, y), world metres", dtype="float64", ndim=2, channels=2)
    )
    poses: np.ndarray = field(
        metadata=_doc(
            "(V, 5) float64 the pose of each viewframe: x, y, z, heading_deg, pitch_deg, world metres and degrees",
            dtype="float64",
            ndim=2,
            channels=5,
        )
    )
    visible: np.ndarray = field(
        metadata=_doc(
            "(M, 3) int32 the landmarks visible in the viewframes, a row (k, landmark index, pixels) each, "
            "by viewframe k, in each viewframe's description order",
            dtype="int32",
            ndim=2,
            channels=3,
        )
    )
    memory: dict = field(metadata=_doc("the scenario's memory settings (MemorySpec.model_dump)"))
    placements: np.ndarray | None = field(
        default=None,
        metadata=_doc(
            "(M, 3) float64 where the viewframe of each visible row shows its landmark: elevation_deg, "
            "azimuth_deg, size_deg, angles from the optical axis (models.placement); null: not known",
            dtype="float64",
            ndim=2,
            channels=3,
        ),
    )
    entry: str | None = field(
        default=None,
        metadata=_doc(
            "absolute path of the viewframe cache entry (folder) the viewframes came from or were written "
            "into (models.viewframe_cache), null: rendered without a cache"
        ),
    )
    route_points: np.ndarray | None = field(
        default=None,
        metadata=_doc(
            "(V,) int32 the route point each viewframe belongs to, non-decreasing (render.views_per_leg > 1: "
            "viewframes between the route points, models.route_views); null: viewframe k is route point k",
            dtype="int32",
            ndim=1,
        ),
    )

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        n, lms, rows = self.viewframes, len(self.landmarks), self.visible
        if self.poses.shape[0] != n:
            raise MessageError(self.level, "poses", f"must have a row per viewframe ({n}), got {self.poses.shape[0]}")
        rp = self.route_points
        if rp is None and n != len(self.route):
            raise MessageError(
                self.level,
                "route_points",
                f"needed when the viewframes ({n}) are not the route points ({len(self.route)})",
            )
        if rp is not None:
            if rp.shape != (n,):
                raise MessageError(self.level, "route_points", f"must have one per viewframe ({n}), got {rp.shape}")
            if n and (rp.min() < 0 or rp.max() >= len(self.route) or (np.diff(rp) < 0).any()):
                raise MessageError(
                    self.level, "route_points", f"must be route points in [0, {len(self.route)}), non-decreasing"
                )
        if len(rows):
            k, lm, px = rows[:, 0], rows[:, 1], rows[:, 2]
            if k.min() < 0 or k.max() >= n or (np.diff(k) < 0).any():
                raise MessageError(self.level, "visible", f"viewframes must be in [0, {n}), in order")
            if lm.min() < 0 or lm.max() >= lms:
                raise MessageError(self.level, "visible", f"landmark indices must be in [0, {lms})")
            if px.min() < 0:
                raise MessageError(self.level, "visible", "pixels must be >= 0")
        if self.placements is not None and self.placements.shape[0] != len(rows):
            raise MessageError(
                self.level,
                "placements",
                f"must have a row per visible row ({len(rows)}), got {self.placements.shape[0]}",
            )

    @classmethod
    def of(
        cls,
        *,
        scenario: str,
        path: str,
        priors: Mapping[str, float],
        landmarks: Sequence[Mapping[str, Any]],
        route: Sequence[Sequence[float]],
        poses: Sequence[Sequence[float]],
        visible: Mapping[int, Mapping[str, int]],
        memory: Mapping[str, Any],
        placements: Mapping[int, Mapping[str, Sequence[float]]] | None = None,
        entry: str | None = None,
        route_points: Sequence[int] | None = None,
    ) -> Self:
        """The map of ``poses`` (one per viewframe), ``visible`` ``{k: {landmark id: pixels}}`` and
        ``placements`` ``{k: {landmark id: (elevation_deg, azimuth_deg, size_deg)}}`` (each landmark
        of ``visible[k]``; None: not known) as maps: made into the message's arrays, rows in the
        maps' order. A landmark id not in ``landmarks`` raises :class:`MessageError`."""
        index = {str(lm["id"]): i for i, lm in enumerate(landmarks)}
        rows: list[tuple[int, int, int]] = []
        places: list[Sequence[float]] = []
        for k in sorted(visible):
            for lm, px in visible[k].items():
                if lm not in index:
                    raise MessageError(
                        cls.level, "visible", f"viewframe {k}: landmark {lm!r} is not a landmark of the map"
                    )
                rows.append((int(k), index[lm], int(px)))
                if placements is not None:
                    got = (placements.get(k) or {}).get(lm)
                    if got is None:
                        raise MessageError(cls.level, "placements", f"viewframe {k}: no placement of landmark {lm!r}")
                    places.append(got)
        return cls(
            scenario=scenario,
            path=path,
            viewframes=len(poses),
            priors={str(k): float(v) for k, v in priors.items()},
            landmarks=[dict(lm) for lm in landmarks],
            route=np.asarray(route, dtype=np.float64).reshape(-1, 2),
            poses=np.asarray(poses, dtype=np.float64).reshape(-1, 5),
            visible=np.asarray(rows, dtype=np.int32).reshape(-1, 3),
            placements=None if placements is None else np.asarray(places, dtype=np.float64).reshape(-1, 3),
            memory=dict(memory),
            entry=entry,
            route_points=None if route_points is None else np.asarray(route_points, dtype=np.int32).ravel(),
        )

    def pose(self, k: int) -> list[float]:
        """Viewframe ``k``'s pose ``[x, y, z, heading_deg, pitch_deg]`` (world metres, degrees)."""
        return [float(v) for v in self.poses[k]]

    def seen(self) -> dict[int, dict[str, int]]:
        """``{k: {landmark id: pixels}}`` for every viewframe k (empty: none visible), in the rows' order."""
        ids = [str(lm["id"]) for lm in self.landmarks]
        out: dict[int, dict[str, int]] = {k: {} for k in range(self.viewframes)}
        for k, lm, px in self.visible.tolist():
            out[k][ids[lm]] = px
        return out

    def visible_sets(self, *, min_pixels: int = 0) -> dict[int, frozenset[str]]:
        """``{k: landmark ids visible in viewframe k with at least min_pixels pixels}`` for every viewframe k."""
        return {k: frozenset(lm for lm, px in v.items() if px >= min_pixels) for k, v in self.seen().items()}

    def placement_table(self) -> dict[int, dict[str, tuple[float, float, float]]]:
        """``{k: {landmark id: (elevation_deg, azimuth_deg, size_deg)}}`` for every viewframe k, or
        ``{}`` when the map has no placements."""
        if self.placements is None:
            return {}
        ids = [str(lm["id"]) for lm in self.landmarks]
        out: dict[int, dict[str, tuple[float, float, float]]] = {k: {} for k in range(self.viewframes)}
        for (k, lm, _), (el, az, size) in zip(self.visible.tolist(), self.placements.tolist()):
            out[k][ids[lm]] = (el, az, size)
        return out

    def id(self) -> str:
        return map_id()


def map_id() -> str:
    """Hypothesis id of the map."""
    return "map"


@dataclass(frozen=True, slots=True)
class Index(Message):
    """One indexer shard has stored its viewframes."""

    level: ClassVar[str] = "index"
    posted_by: ClassVar[str] = "associative indexer(s)"
    id_pattern: ClassVar[str] = "index-<shard>"
    shard: int = field(metadata=_doc("this shard"))
    shards: int = field(metadata=_doc("number of shards"))
    viewframes: int = field(metadata=_doc("viewframes stored in this shard"))
    featureless: list[int] = field(
        default_factory=list,
        metadata=_doc("viewframes of this shard not stored: featureless (constant) images, never ranked by it"),
    )

    def id(self) -> str:
        return index_id(self.shard)


def index_id(shard: int) -> str:
    """Hypothesis id of shard ``shard``'s index."""
    return f"index-{shard}"


@dataclass(frozen=True, slots=True)
class SensorFrame(Message):
    """One camera image of the mission."""

    level: ClassVar[str] = "sensor_frame"
    posted_by: ClassVar[str] = "camera"
    id_pattern: ClassVar[str] = "sf-<frame:06d>"
    frame: int = field(metadata=_doc("frame number, in mission order"))
    image: np.ndarray = field(metadata=_doc("(H, W, 3) uint8 RGB", dtype="uint8", ndim=3, channels=3))
    source: str = field(metadata=_doc('the image file, or "simulated"'))
    time: float | None = field(default=None, metadata=_doc("when the frame was taken, seconds, or null"))
    columns: list | None = field(
        default=None,
        metadata=_doc(
            "[first, last) image columns holding the scene (a narrower camera image padded to the camera's "
            "width, models.sensor.fit_to_camera), or null: all",
            length=2,
        ),
    )

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        if self.columns is not None:
            first, last = self.columns
            width = self.image.shape[1]
            if not (type(first) is int and type(last) is int and 0 <= first < last <= width):
                raise MessageError(self.level, "columns", f"must be [first, last) with 0 <= first < last <= {width}")

    def id(self) -> str:
        return frame_id(self.frame)


def frame_id(frame: int) -> str:
    """Hypothesis id of camera frame ``frame`` on the sensor_frame level."""
    return f"sf-{frame:06d}"


@dataclass(frozen=True, slots=True)
class Truth(Message):
    """The true pose of one camera frame: for evaluation only, no agent consumes it."""

    level: ClassVar[str] = "truth"
    posted_by: ClassVar[str] = "camera"
    id_pattern: ClassVar[str] = "truth-<frame:06d>"
    frame: int = field(metadata=_doc("frame number"))
    pose: list = field(metadata=_doc("[x, y, heading_deg], world metres and degrees", length=3))

    def id(self) -> str:
        return truth_id(self.frame)


def truth_id(frame: int) -> str:
    """Hypothesis id of frame ``frame``'s truth."""
    return f"truth-{frame:06d}"


@dataclass(frozen=True, slots=True)
class Ranking(Message):
    """One ranking source's viewframes ranked for one camera frame, best first (an associative shard, or the skyline)."""

    level: ClassVar[str] = "ranking"
    posted_by: ClassVar[str] = "associative indexer(s), skyline"
    id_pattern: ClassVar[str] = "rk-<frame:06d>-<shard>"  # shard: the shard number, or the source if not associative
    frame: int = field(metadata=_doc("frame number"))
    frame_time: float = field(metadata=_doc("timestamp of the camera frame's hypothesis (latency)"))
    shard: int = field(metadata=_doc("the shard ranked (0 for a source of one shard)"))
    shards: int = field(metadata=_doc("number of shards of this source"))
    viewframes: list = field(metadata=_doc("viewframe indices k, best first"))
    variances: list = field(
        metadata=_doc(
            "the source's error of each, same order (associative: error variance; skyline: truncated L1 in degrees)"
        )
    )
    reliability: float = field(metadata=_doc("robust standard deviations the best stands below the rest"))
    source: str = field(default="associative", metadata=_doc('"associative" or "skyline": whose errors these are'))
    shifts: list | None = field(
        default=None,
        metadata=_doc(
            "[[heading_deg, pitch_deg], ...] the camera's best turn and tilt against each viewframe, same order, "
            "or null"
        ),
    )
    time: float | None = field(default=None, metadata=_doc("the camera frame's time, seconds, or null"))
    profile: np.ndarray | None = field(
        default=None,
        metadata=_doc(
            "skyline: the camera frame's horizon profile it matched, (n,) float32 elevation per azimuth bin, "
            "degrees, NaN: none (models.skyline); null for other sources",
            dtype="float32",
            ndim=1,
        ),
    )

    def id(self) -> str:
        return ranking_id(self.frame, self.shard, self.source)

    @classmethod
    def of(
        cls,
        ranking: MemoryRanking,
        *,
        frame: int,
        frame_time: float,
        shard: int,
        shards: int,
        source: str = "associative",
        shifts: list | None = None,
        time: float | None = None,
    ) -> Ranking:
        """The message of a memory's :class:`~models.associative.Ranking`."""
        return cls(
            frame=frame,
            frame_time=frame_time,
            shard=shard,
            shards=shards,
            source=source,
            shifts=shifts,
            time=time,
            **ranking.to_dict(),
        )

    def ranking(self) -> MemoryRanking:
        """As a :class:`models.associative.Ranking`."""
        from models.associative import Ranking as MemoryRanking

        return MemoryRanking.from_dict(
            {"viewframes": self.viewframes, "variances": self.variances, "reliability": self.reliability}
        )


def ranking_id(frame: int, shard: int, source: str = "associative") -> str:
    """Hypothesis id of ranking source ``source``'s shard ``shard`` for frame ``frame`` (the associative
    shards keep ``rk-<frame>-<shard>``; another source is ``rk-<frame>-<source>``)."""
    return f"rk-{frame:06d}-{shard}" if source == "associative" else f"rk-{frame:06d}-{source}"


@dataclass(frozen=True, slots=True)
class Query(Message):
    """A yes/no question to a landmark detector: is landmark L in frame F, as seen from viewframe k?"""

    level: ClassVar[str] = "query"
    posted_by: ClassVar[str] = "scheduler"
    id_pattern: ClassVar[str] = "q-<frame:06d>-<number>"
    frame: int = field(metadata=_doc("frame number"))
    number: int = field(metadata=_doc("1 for the frame's first query, 2 for the next, ..."))
    landmark: str = field(metadata=_doc("landmark id"))
    landmark_index: int = field(metadata=_doc("the landmark's value in the viewframe mask"))
    kind: str = field(metadata=_doc("landmark kind (which detector)"))
    viewframe: int = field(metadata=_doc("candidate viewframe k"))
    p: float = field(metadata=_doc("P(L|A): probability the landmark is present"))

    def id(self) -> str:
        return query_id(self.frame, self.number)


def query_id(frame: int, number: int) -> str:
    """Hypothesis id of the ``number``-th query (from 1) of frame ``frame``."""
    return f"q-{frame:06d}-{number}"


@dataclass(frozen=True, slots=True)
class Answer(Message):
    """A landmark detector's answer to one query."""

    level: ClassVar[str] = "answer"
    posted_by: ClassVar[str] = "landmark detector"
    id_pattern: ClassVar[str] = "ans-<query>"
    query: str = field(metadata=_doc("id of the query answered"))
    frame: int = field(metadata=_doc("frame number"))
    landmark: str = field(metadata=_doc("landmark id"))
    viewframe: int = field(metadata=_doc("candidate viewframe k"))
    present: bool | None = field(metadata=_doc("true, false, or null when undecided"))
    score: float = field(metadata=_doc("detector score in [-1, 1]"))
    location: list | None = field(metadata=_doc("(row, col) of the detection in the camera image, or null"))
    detector: str = field(metadata=_doc("detector name"))
    reason: str = field(metadata=_doc("why the detector answered so"))
    llr: float | None = field(
        default=None, metadata=_doc("log-likelihood ratio of the landmark being there (calibrated), or null")
    )
    where: list | None = field(
        default=None,
        metadata=_doc(
            "[elevation_deg, azimuth_deg, size_deg] of the landmark's best match in the camera image, angles from "
            "the optical axis (models.placement), or null"
        ),
    )

    def id(self) -> str:
        return answer_id(self.query)


def answer_id(query: str) -> str:
    """Hypothesis id of the answer to query ``query`` (one answer per query)."""
    return f"ans-{query}"


@dataclass(frozen=True, slots=True)
class Position(Message):
    """The scheduler's decision for one camera frame (the results file is made of these)."""

    level: ClassVar[str] = "position"
    posted_by: ClassVar[str] = "scheduler"
    id_pattern: ClassVar[str] = "pos-<frame:06d>"
    frame: int = field(metadata=_doc("frame number"))
    viewframe: int | None = field(metadata=_doc("chosen viewframe k, or null: not localized"))
    position: list | None = field(metadata=_doc("[x, y] of the chosen viewframe, world metres, or null"))
    heading_deg: float | None = field(metadata=_doc("heading of the chosen viewframe, degrees, or null"))
    confidence: float = field(metadata=_doc("belief in the decision, [0, 1]"))
    queries: int = field(metadata=_doc("detector queries answered"))
    backtracks: int = field(metadata=_doc("candidates discarded by an absent landmark"))
    latency_ms: float = field(metadata=_doc("camera frame posted to decision, milliseconds"))
    ranking: list = field(metadata=_doc("[[k, variance], ...] the merged ranking's first 5"))
    reason: str = field(metadata=_doc("why this decision (and what degraded it)"))
    degraded: list = field(
        metadata=_doc("queries without an answer, and a track of the frame before that did not come: [str, ...]")
    )
    steps: list = field(metadata=_doc("the scene analysis's steps: [{...}, ...]"))
    strategy: str = field(metadata=_doc('"associative" or "prior"'))
    track_prior: bool = field(default=False, metadata=_doc("the candidates were conditioned on the track"))
    verified: bool = field(
        default=False, metadata=_doc("the ranking was re-scored by the frame's verification (render and compare)")
    )

    def id(self) -> str:
        return position_id(self.frame)

    @staticmethod
    def at(pose: Sequence[float] | None) -> tuple[list[float] | None, float | None]:
        """``(position, heading_deg)`` of a decision at a viewframe of pose ``[x, y, z, heading_deg, ...]``
        (None: no viewframe chosen): the one place a position is computed."""
        if pose is None:
            return None, None
        return [float(pose[0]), float(pose[1])], float(pose[3])


def position_id(frame: int) -> str:
    """Hypothesis id of frame ``frame``'s position."""
    return f"pos-{frame:06d}"


@dataclass(frozen=True, slots=True)
class Pose(Message):
    """The refined camera pose of one decided frame: between route points, with heading and pitch."""

    level: ClassVar[str] = "pose"
    posted_by: ClassVar[str] = "refiner"
    id_pattern: ClassVar[str] = "pose-<frame:06d>"
    frame: int = field(metadata=_doc("frame number"))
    position: str = field(metadata=_doc("id of the position hypothesis refined"))
    viewframe: int = field(metadata=_doc("the decision's viewframe k"))
    x: float = field(metadata=_doc("world x, metres"))
    y: float = field(metadata=_doc("world y, metres"))
    heading_deg: float = field(metadata=_doc("heading, degrees ccw from +x"))
    pitch_deg: float = field(metadata=_doc("pitch, degrees up"))
    sigma_along_m: float = field(metadata=_doc("standard deviation along the heading, metres"))
    sigma_across_m: float = field(metadata=_doc("standard deviation across the heading, metres"))
    sigma_heading_deg: float = field(metadata=_doc("standard deviation of the heading, degrees"))
    score: float = field(metadata=_doc("the refined view's score (models.refine; lower is better)"))
    start_score: float = field(metadata=_doc("the route point's score"))
    renders: int = field(metadata=_doc("views rendered"))
    route_position: list = field(metadata=_doc("[x, y] of the route point refined from", length=2))
    route_heading_deg: float = field(metadata=_doc("its heading, degrees"))

    def id(self) -> str:
        return pose_id(self.frame)


def pose_id(frame: int) -> str:
    """Hypothesis id of frame ``frame``'s refined pose."""
    return f"pose-{frame:06d}"


@dataclass(frozen=True, slots=True)
class Track(Message):
    """The tracker's estimate of the vehicle's place on the route at one camera frame."""

    level: ClassVar[str] = "track"
    posted_by: ClassVar[str] = "tracker"
    id_pattern: ClassVar[str] = "tr-<frame:06d>"
    frame: int = field(metadata=_doc("frame number"))
    route_point: int = field(metadata=_doc("most probable route point (viewframe index)"))
    arc_m: float = field(metadata=_doc("arc length along the route, metres from route point 0"))
    position: list = field(metadata=_doc("[x, y] world metres", length=2))
    heading_deg: float = field(metadata=_doc("the route's direction there, degrees ccw from +x"))
    confidence: float = field(metadata=_doc("posterior probability of route_point, [0, 1]"))
    state: str = field(metadata=_doc('"tracking" or "lost"'))
    evidence: bool = field(metadata=_doc("the frame had evidence (else: prediction only)"))
    belief: np.ndarray = field(metadata=_doc("(N,) float32 posterior probability of each route point", ndim=1))
    prior_next: np.ndarray = field(metadata=_doc("(N,) float32 predicted probability for the next frame", ndim=1))
    loglik: np.ndarray | None = field(
        metadata=_doc(
            "(S,) float32 the frame's evidence on the route (for the offline smoothing: only with "
            "tracking.smoothing), or null",
            ndim=1,
        )
    )
    dt: float | None = field(metadata=_doc("seconds since the previous frame, or null"))
    window_next: list | None = field(
        default=None,
        metadata=_doc(
            "[first, last] route points holding the motion's prediction for the next frame (all but "
            "models.index.WINDOW_TAIL of prior_next without its kidnap part, which is even over the route), or null"
        ),
    )

    def id(self) -> str:
        return track_id(self.frame)


def track_id(frame: int) -> str:
    """Hypothesis id of the track at camera frame ``frame``."""
    return f"tr-{frame:06d}"


@dataclass(frozen=True, slots=True)
class TrackQuery(Message):
    """The scheduler's request to the tracker: track frame F from its position (answered by the track)."""

    level: ClassVar[str] = "track_query"
    posted_by: ClassVar[str] = "scheduler"
    id_pattern: ClassVar[str] = "tq-<frame:06d>"
    frame: int = field(metadata=_doc("frame number"))
    position: str = field(metadata=_doc("id of the frame's position hypothesis"))

    def id(self) -> str:
        return track_query_id(self.frame)


def track_query_id(frame: int) -> str:
    """Hypothesis id of the scheduler's track query for frame ``frame``."""
    return f"tq-{frame:06d}"


@dataclass(frozen=True, slots=True)
class VerifyQuery(Message):
    """The scheduler's request to the verifier: render and compare frame F's first candidates (answered by a verification)."""

    level: ClassVar[str] = "verify_query"
    posted_by: ClassVar[str] = "scheduler"
    id_pattern: ClassVar[str] = "vq-<frame:06d>"
    frame: int = field(metadata=_doc("frame number"))
    viewframes: list = field(
        metadata=_doc("the candidates' viewframes, the fused ranking's first route points in order")
    )

    def id(self) -> str:
        return verify_query_id(self.frame)


def verify_query_id(frame: int) -> str:
    """Hypothesis id of the scheduler's verification request for frame ``frame``."""
    return f"vq-{frame:06d}"


@dataclass(frozen=True, slots=True)
class Verification(Message):
    """The verifier's render-and-compare scores of one frame's candidates (models.verify)."""

    level: ClassVar[str] = "verification"
    posted_by: ClassVar[str] = "verifier"
    id_pattern: ClassVar[str] = "ver-<frame:06d>"
    frame: int = field(metadata=_doc("frame number"))
    query: str = field(metadata=_doc("id of the verify query answered"))
    viewframes: list = field(metadata=_doc("the candidates' viewframes, as asked"))
    correlations: list = field(
        metadata=_doc("memory-pattern correlation of the camera image with each candidate's aligned view, [-1, 1]")
    )
    headings_deg: list = field(metadata=_doc("each aligned view's heading, degrees ccw from +x"))
    renders: int = field(metadata=_doc("views rendered"))

    def id(self) -> str:
        return verification_id(self.frame)


def verification_id(frame: int) -> str:
    """Hypothesis id of the verification of frame ``frame``'s candidates."""
    return f"ver-{frame:06d}"


SCENARIO = Scenario.level
VIEWFRAME = Viewframe.level
MAP = Map.level
INDEX = Index.level
SENSOR_FRAME = SensorFrame.level
TRUTH = Truth.level
RANKING = Ranking.level
QUERY = Query.level
ANSWER = Answer.level
POSITION = Position.level
POSE = Pose.level
TRACK = Track.level
TRACK_QUERY = TrackQuery.level
VERIFY_QUERY = VerifyQuery.level
VERIFICATION = Verification.level


# -- the table ---------------------------------------------------------------------------------------


def _type_name(hint: Any, meta: Mapping[str, Any]) -> str:
    origin = typing.get_origin(hint)
    if origin in (types.UnionType, typing.Union):
        inner = next(a for a in typing.get_args(hint) if a is not type(None))
        return _type_name(inner, meta) + " | null"
    base = origin or hint
    if base is np.ndarray:
        return f"array {meta['dtype']}" if meta.get("dtype") else "array"
    return {int: "int", float: "float", str: "str", bool: "bool", list: "list", dict: "map"}[base]


def level_fields(cls: type[Message]) -> list[tuple[str, str, str]]:
    """``(field, type, doc)`` of each field of a message class, in order."""
    hints = typing.get_type_hints(cls)
    return [(f.name, _type_name(hints[f.name], f.metadata), f.metadata.get("doc", "")) for f in dataclasses.fields(cls)]  # type: ignore[arg-type]


def levels_table() -> str:
    """The levels table (markdown): one row per field of each level's message class."""
    rows = ["| level | posted by | id | field | type | meaning |", "|---|---|---|---|---|---|"]
    for level, cls in MESSAGES.items():
        for i, (name, kind, doc) in enumerate(level_fields(cls)):
            head = (f"`{level}`", cls.posted_by.replace("``", "`"), f"`{cls.id_pattern}`") if i == 0 else ("", "", "")
            rows.append(f"| {' | '.join(head)} | `{name}` | {kind} | {doc} |")
    return "\n".join(rows)


if __doc__ is not None:
    __doc__ += "Levels (generated from the classes)::\n\n" + "\n".join(
        "    " + line for line in levels_table().splitlines()
    )


if __name__ == "__main__":
    print(levels_table())
