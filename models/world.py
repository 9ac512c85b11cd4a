"""A scenario's world: the environment model, the camera emulator, the route poses, the viewframes
and the camera (sensor) frames, built once from the scenario.

Everything that renders a scenario (the map renderer and camera agents, ``mapinterp table``,
``render`` and ``report``, ``bench/`` and ``bench/tuning/``) gets these from one :class:`World`,
so there is one way from a scenario file to its viewframes and its camera frames::

    with World.from_scenario("scenarios/hills.yaml") as world:
        viewframes = world.viewframes      # rendered and described at every route point
        frames = world.sensor_frames       # read from sensor.frames, or simulated

Each part is built on first use and kept: camera frames read from files need no renderer, and
a world that only simulates frames renders no viewframes. Viewframes come from the viewframe
cache when it holds them (:mod:`models.viewframe_cache`; then no renderer is opened for them) and
are stored there after rendering; :meth:`World.summary` gives what a map needs of them (poses,
the landmarks visible in each) from the cache entry without reading them. The camera emulator holds an
offscreen renderer: close the world (or use it as a context manager) to release it. World
coordinates are (x, y, z) metres, images (row, col); see :mod:`models.camera_emulator`.
"""

from __future__ import annotations

import hashlib
import logging
import threading
import weakref
from collections.abc import Callable, Iterator
from functools import cached_property
from pathlib import Path
from typing import Any, NamedTuple, TypeVar, cast

from models.camera_emulator import CameraEmulator, Pose
from models.environment import EnvironmentModel, build_environment
from models.route_views import view_poses
from models.scenario import Scenario, load_scenario
from models.sensor import SensorFrame, frames_from_files, iter_simulated_frames, simulate_frames
from models.symbolic import landmark_priors
from models.terrain import Terrain
from models.terrain_sources import scenario_terrain
from models.viewframe_cache import EntrySummary, ViewframeCache, cache_key, entry_summary
from models.viewframes import Viewframe, render_viewframes, render_viewframes_parallel, route_poses

__all__ = ["World"]

log = logging.getLogger(__name__)


class World:
    """The world of one scenario (see the module docstring).

    Parameters
    ----------
    scenario : Scenario
    terrain : Terrain, optional
        An already loaded terrain (default: the scenario's, loaded on first use).
    progress : callable(done, total), optional
        Called after each viewframe is rendered (progress bars).
    cache : ViewframeCache, None or "env"
        Where rendered viewframes are kept between runs; None: no cache; "env" (default): the
        cache the environment names (:meth:`ViewframeCache.from_env`).
    **lod
        ``tile_cells``, ``levels``, ``lod_factor``, ``refine`` of :class:`EnvironmentModel`.
    """

    def __init__(
        self,
        scenario: Scenario,
        *,
        terrain: Terrain | None = None,
        progress: Callable[[int, int], None] | None = None,
        cache: ViewframeCache | str | None = "env",
        **lod: Any,
    ) -> None:
        self.scenario = scenario
        self._progress = progress
        self._terrain = terrain
        self._lod = lod
        if isinstance(cache, str) and cache != "env":
            raise ValueError(f'cache must be a ViewframeCache, None or "env", not {cache!r}')
        self.cache: ViewframeCache | None = ViewframeCache.from_env() if isinstance(cache, str) else cache
        #: the viewframe cache entry (folder) :attr:`viewframes` came from or were written into;
        #: None until they are built, and when they were rendered without a cache
        self.entry: Path | None = None
        self._emulator: CameraEmulator | None = None
        self._key: str | None = None
        self._summary: EntrySummary | None = None

    @classmethod
    def from_scenario(cls, scenario: Scenario | str | Path, **options: Any) -> World:
        """The world of a scenario, or of a scenario file (loaded and validated)."""
        return cls(scenario if isinstance(scenario, Scenario) else load_scenario(scenario), **options)

    # -- the parts, each built on first use ------------------------------------------------
    @cached_property
    def terrain(self) -> Terrain:
        """The scenario's terrain (heights and cell size), loaded without building any mesh: the
        viewframe cache's key and the route poses need only it. Shared with the other worlds of
        the same scenario alive in this process (:func:`_shared`)."""
        if self._terrain is not None:
            return self._terrain
        return _shared(self._share_key("terrain"), lambda: scenario_terrain(self.scenario))

    @cached_property
    def environment(self) -> EnvironmentModel:
        """F* = T(F, L): the terrain and the placed landmarks, as meshes for rendering. Shared with
        the other worlds of the same scenario and level of detail alive in this process (the
        camera's and the refiner's, each rendering it with its own emulator: :func:`_shared`)."""
        if self._terrain is not None:  # a terrain of the caller's: this world's own
            return build_environment(self.scenario, terrain=self.terrain, **self._lod)
        return _shared(
            self._share_key("environment"),
            lambda: build_environment(self.scenario, terrain=self.terrain, **self._lod),
        )

    def _share_key(self, part: str) -> tuple[Any, ...]:
        """What ``part`` ("terrain", "environment") of this world is made from: the scenario (all of
        it: a digest of its JSON), the folder its relative paths resolve against, the size and time of the
        terrain files it names, and for the environment the level-of-detail options."""
        spec = self.scenario.terrain
        files: list[tuple[str, int | None, int | None]] = []
        for name in (spec.dem, spec.contours):
            if name is not None:
                path = name if name.is_absolute() else self.scenario.base_dir / name
                try:
                    st = path.stat()
                    files.append((str(path), st.st_mtime_ns, st.st_size))
                except OSError:
                    files.append((str(path), None, None))  # loading it names the error
        lod = tuple(sorted((str(k), repr(v)) for k, v in self._lod.items())) if part == "environment" else ()
        scenario = hashlib.sha256(self.scenario.model_dump_json().encode()).hexdigest()  # a long route: not its text
        return (part, scenario, str(self.scenario.base_dir), tuple(files), lod)

    @property
    def emulator(self) -> CameraEmulator:
        """The camera emulator of :attr:`environment` (one offscreen renderer, until :meth:`close`)."""
        if self._emulator is None:
            self._emulator = CameraEmulator(self.environment, self.scenario.camera)
        return self._emulator

    @cached_property
    def poses(self) -> list[Pose]:
        """The camera pose of every viewframe (:func:`models.route_views.view_poses`: at every
        route point, and between them with ``render.views_per_leg`` > 1)."""
        return view_poses(self.scenario, self.terrain)

    @cached_property
    def route_poses(self) -> list[Pose]:
        """The camera pose at every route point (:func:`models.viewframes.route_poses`), where
        simulated camera frames are taken."""
        return route_poses(self.scenario, self.terrain)

    @cached_property
    def viewframes(self) -> list[Viewframe]:
        """The viewframe at every route point, rendered and symbolically described (or read from
        the viewframe cache); rendered by worker processes as the scenario's ``render`` block says
        (:class:`models.scenario.RenderSpec`). With a cache, each viewframe is written into the
        cache's entry as it is rendered and the result is that entry, memory-mapped: the
        rendered arrays are never all in memory (without a cache they are)."""
        key = None
        if self.cache is not None:
            key = self._cache_key()
            cached = self.cache.load(key)
            if cached is not None:
                if self._progress is not None:
                    self._progress(len(cached), len(cached))
                self.entry = self.cache.path(key)
                return cached
        if self.cache is None or key is None:
            return self._render(sink=None)
        cache = self.cache
        try:
            writer = cache.writer(key, len(self.poses))
        except OSError as err:
            log.warning("viewframe cache %s: cannot store (%s); the run goes on without it", cache.root, err)
            return self._render(sink=None)
        try:
            self._render(sink=writer.put)
            writer.commit()
        except OSError as err:
            log.warning("viewframe cache %s: cannot store (%s); rendering again, kept in memory", cache.root, err)
            writer.abort()
            return self._render(sink=None)
        finally:
            writer.abort()
        back = cache.read(key)  # the entry just written, memory-mapped
        if back is None:
            return self._render(sink=None)
        self.entry = cache.path(key)
        return back

    def _cache_key(self) -> str:
        """The viewframe cache key of this world's viewframes (computed once): of the terrain alone,
        not the environment's meshes, so a hit renders nothing."""
        if self._key is None:
            self._key = cache_key(self.scenario, self.terrain, lod=self._lod)
        return self._key

    def renders_entry(self, entry: str | Path | None) -> bool:
        """The viewframe cache entry folder ``entry`` holds the viewframes this world's emulator
        renders, pixel for pixel (its name is this world's cache key: the same terrain, landmarks,
        route, camera, level of detail and renderer), so a view it would render at a viewframe's
        pose may be read from the entry instead. False for None or another entry."""
        return entry is not None and Path(entry).name == self._cache_key()

    def summary(self) -> EntrySummary | None:
        """What a map needs of the viewframes (:class:`models.viewframe_cache.EntrySummary`: the
        index and pose of each, the landmarks visible in each with their pixels and centroids),
        from the viewframe cache entry that holds them, without reading the viewframes or parsing
        their descriptions (:func:`models.viewframe_cache.entry_summary`); it sets :attr:`entry`.
        None without a cache, when the cache does not hold them, or when the entry cannot be
        summarised: then :attr:`viewframes` reads (or renders) them."""
        if self._summary is not None:
            return self._summary
        if self.cache is None:
            return None
        key = self._cache_key()
        if key not in self.cache:
            return None
        summary = entry_summary(self.cache.path(key))
        if summary is None:
            return None
        self.cache.hits += 1
        self.entry = self.cache.path(key)
        self._summary = summary
        return summary

    def _render(self, *, sink: Callable[[int, Viewframe], None] | None) -> list[Viewframe]:
        """Every route point's viewframe, rendered (see :attr:`viewframes`); with ``sink``, each is
        given to it as it is rendered (written into the cache) and none is kept."""
        step = self.scenario.skyline.step_deg
        workers = self.scenario.render.worker_count(len(self.poses))
        if workers > 1:
            frames = render_viewframes_parallel(
                self.environment,
                self.scenario.camera,
                self.poses,
                workers=workers,
                skyline_step_deg=step,
                progress=self._progress,
                sink=sink,
            )
        else:
            frames = render_viewframes(
                self.emulator, self.poses, skyline_step_deg=step, progress=self._progress, sink=sink
            )
        log.info("rendered %d viewframes of %s in %d process(es)", len(self.poses), self.scenario.name, workers)
        return frames

    @cached_property
    def sensor_frames(self) -> list[SensorFrame]:
        """The mission's camera frames: the files of ``sensor.frames`` (resized to the camera),
        or frames simulated along the route by ``sensor.simulate``; none without a sensor block."""
        sensor = self.scenario.sensor
        if sensor is None:
            return []
        if sensor.frames:
            return frames_from_files(self.scenario)
        return simulate_frames(self.scenario, self.emulator, self.route_poses)

    def iter_sensor_frames(self) -> Iterator[SensorFrame]:
        """:attr:`sensor_frames` one by one, each simulated as it is asked for (read from files,
        they are all read first); the same frames in the same order. Not kept (unless
        :attr:`sensor_frames` was asked for)."""
        sensor = self.scenario.sensor
        if "sensor_frames" in self.__dict__ or sensor is None or sensor.frames:
            yield from self.sensor_frames
            return
        yield from iter_simulated_frames(self.scenario, self.emulator, self.route_poses)

    @cached_property
    def priors(self) -> dict[str, float]:
        """The a-priori landmark probabilities P(L) over the viewframes, by landmark id."""
        ids = [lm.id for lm in self.scenario.landmarks]
        if self._summary is not None and "viewframes" not in self.__dict__:  # not read: from the summary
            seen = [_Seen(visible) for visible in self._summary.visible()]
            return landmark_priors(cast(list[Any], seen), landmark_ids=ids)
        return landmark_priors([vf.description for vf in self.viewframes], landmark_ids=ids)

    # -- lifecycle ---------------------------------------------------------------------------
    def close(self) -> None:
        """Release the camera emulator's renderer (the parts already built stay usable)."""
        if self._emulator is not None:
            self._emulator.close()
            self._emulator = None

    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _Seen(NamedTuple):
    """The landmark ids a viewframe shows: all :func:`models.symbolic.landmark_priors` reads of a
    description (its ``visible``)."""

    visible: list[str]


#: the terrains and environments of the worlds alive in this process, by what they are made from
#: (World._share_key): built once, kept while a world uses them
_SHARED: weakref.WeakValueDictionary[tuple[Any, ...], Any] = weakref.WeakValueDictionary()
_SHARED_LOCKS: dict[tuple[Any, ...], threading.Lock] = {}
_SHARED_GUARD = threading.Lock()

_Part = TypeVar("_Part")


def _shared(key: tuple[Any, ...], build: Callable[[], _Part]) -> _Part:
    """The part ``key`` names, built by ``build`` unless a world alive in this process has it (the
    map renderer, the camera and the refiner of a mission each load the scenario: one terrain of
    1951 x 1951 cells and one environment instead of three and two, about 250 MB and 3 to 7 s
    of a 10,000-viewframe mission's setup). A second world asking while it is built waits for it.
    Nothing in a terrain or an environment changes once built (the tile meshes an environment
    builds on first use are the same whoever asks first)."""
    with _SHARED_GUARD:
        lock = _SHARED_LOCKS.setdefault(key, threading.Lock())
    with lock:
        got = _SHARED.get(key)
        if got is None:
            got = build()
            _SHARED[key] = got
        return cast(_Part, got)
