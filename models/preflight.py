"""Pre-run checks: everything about a scenario that can be known before a run starts.

:func:`check_scenario` is what ``mapinterp run``, the scenario pytest plugin and every other
caller of :func:`knowledge_sources.mission.run_mission` meet first, so that an error which an
agent would otherwise meet in the middle of a run (a DEM of strings, a landmark off the map, a
camera image that is not an image) stops the command at once, with one line naming the file
and the field::

    scenarios/x.yaml: terrain.dem: scenarios/data/x.npy: DEM must be a 2-D array ...
    scenarios/x.yaml: sensor.frames[2].image: scenarios/frames/2.png: not a readable image ...
    scenarios/x.yaml: landmarks[0]: 'H1' at (9000, 10) is outside the terrain (x 0..2550, y 0..2550 m)

The scenario file itself is validated on load (:mod:`models.scenario`: types, finite numbers,
bounds); these checks read the files it names and relate them to each other. The map is read as
the map renderer reads it (:func:`models.terrain_sources.scenario_terrain`: a truncated or colour
raster, nodata cells with ``terrain.nodata: refuse``, spikes with ``terrain.spikes: refuse``, contour
files without heights are refused here), and every camera image as the camera reads it
(:func:`models.sensor.frames_from_files`: decoded in full, so a truncated or damaged file is
caught, and mapped onto the camera's field of view, so an image that sees too little of it is)::

    scenarios/x.yaml: sensor.frames[0].image: f0.jpg: the JPEG file is truncated or damaged ...
    scenarios/x.yaml: sensor.frames[0].image: slit.png: the image (240x960 pixels) sees only 19 % ...
    scenarios/x.yaml: terrain.contours: c.gpkg: no contour heights: no attribute named like an elevation ...
"""

from __future__ import annotations

import logging

from models.environment import check_extents
from models.errors import ScenarioError
from models.scenario import Scenario
from models.sensor import frames_from_files
from models.terrain import Terrain
from models.terrain_sources import scenario_terrain

__all__ = ["check_scenario", "frame_count"]

log = logging.getLogger(__name__)


def frame_count(scenario: Scenario) -> int:
    """How many camera frames the scenario's sensor gives (0 without a ``sensor`` block)."""
    sensor = scenario.sensor
    if sensor is None:
        return 0
    if sensor.frames:
        return len(sensor.frames)
    sim = sensor.simulate
    if sim is None:
        return 0
    if sim.drive is not None:  # a drive's length depends on its speeds and stops: the camera's seed
        from models.sensor import drive_poses

        return len(drive_poses(scenario.route, sim.drive, rng=sim.seed if sim.seed is not None else scenario.seed))
    return len(range(0, len(scenario.route), sim.stride)) * sim.per_point


def check_scenario(scenario: Scenario, *, mission: bool = True) -> Terrain:
    """Read every file ``scenario`` names and check what the schema alone cannot; returns the terrain.

    With ``mission`` (a run), the scenario must also give camera frames. Raises
    :class:`ScenarioError` naming the scenario file and the field (and the data file when it is
    the culprit).
    """
    path = scenario.path
    terrain = scenario_terrain(scenario)
    check_extents(scenario, terrain)
    if mission:
        if scenario.sensor is None:
            raise ScenarioError(path, "sensor", "a run needs camera frames: give sensor.frames or sensor.simulate")
        if frame_count(scenario) == 0:
            raise ScenarioError(path, "sensor", "gives no camera frame")
    if scenario.sensor is not None and scenario.sensor.frames:
        frames_from_files(scenario)  # every image read as the camera will read it
    log.debug("scenario %s passed the pre-run checks", path)
    return terrain
