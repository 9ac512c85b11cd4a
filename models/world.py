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
are stored there after rendering. The camera emulator holds an
offscreen renderer: close the world (or use it as a context manager) to release it. World
coordinates are (x, y, z) metres, images (row, col); see :mod:`models.camera_emulator`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from functools import cached_property
from pathlib import Path
from typing import Any

from models.camera_emulator import CameraEmulator, Pose
from models.environment import EnvironmentModel, build_environment
from models.route_views import view_poses
from models.scenario import Scenario, load_scenario
from models.sensor import SensorFrame, frames_from_files, simulate_frames
from models.symbolic import landmark_priors
from models.terrain import Terrain
from models.terrain_sources import scenario_terrain
from models.viewframe_cache import ViewframeCache, cache_key
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

    @classmethod
    def from_scenario(cls, scenario: Scenario | str | Path, **options: Any) -> World:
        """The world of a scenario, or of a scenario file (loaded and validated)."""
        return cls(scenario if isinstance(scenario, Scenario) else load_scenario(scenario), **options)

    # -- the parts, each built on first use ------------------------------------------------
    @cached_property
    def terrain(self) -> Terrain:
        """The scenario's terrain (heights and cell size), loaded without building any mesh: the
        viewframe cache's key and the route poses need only it."""
        return self._terrain if self._terrain is not None else scenario_terrain(self.scenario)

    @cached_property
    def environment(self) -> EnvironmentModel:
        """F* = T(F, L): the terrain and the placed landmarks, as meshes for rendering."""
        return build_environment(self.scenario, terrain=self.terrain, **self._lod)

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
            # the terrain alone, not the environment's meshes: a hit renders nothing
            key = cache_key(self.scenario, self.terrain, lod=self._lod)
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

    @cached_property
    def priors(self) -> dict[str, float]:
        """The a-priori landmark probabilities P(L) over the viewframes, by landmark id."""
        ids = [lm.id for lm in self.scenario.landmarks]
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
