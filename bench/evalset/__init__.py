"""The held-out evaluation set: terrains, drives and camera frames the defaults were not tuned on.

One set serves the single-frame benchmark (issue 10) and the tracker (issue 9). Its cases are
generated on first use, deterministically from the seeds in :data:`TERRAINS`, and cached.

Getting cases::

    from bench.evalset import cases
    for case in cases("heldout"):                 # or "tuning"; names=["h-mesas"], kinds=["sweep"]
        results = run_mission(case.scenario_path)  # a normal scenario file with sensor.frames
        for frame in case.frames:                  # time order
            frame.image, frame.truth, frame.route_index, frame.pitch_deg, frame.event ...

**Splits.** ``"tuning"`` (seeds 1xxx) is the only split on which parameters may be chosen;
``"heldout"`` (seeds 2xxx) is for reporting. Their terrains are disjoint (:func:`seeds`,
:func:`case_names`; a test checks it).

**A case** (:class:`Case`): ``name`` ("h-mesas/sweep"), ``split``, ``terrain``, ``kind``
("sweep": one frame per route point in route order; "drive": time order with varying speed,
stops and gaps of several route points; "kidnap": a drive with one jump), ``seed``, ``folder``,
``scenario_path`` (``scenario.yaml``: terrain as ``dem: terrain.npy`` or ``contours:
contours.geojson``, landmarks, route, the scenario camera 160x120, ``sensor.frames`` with
image files and truth (x, y, heading_deg)), ``route``, ``spacing_m``, ``frames``
(:class:`EvalFrame`), ``description``; :meth:`Case.write_scenario` writes a copy with other
``memory``/``scheduler``/... blocks; :meth:`Case.horizons` the true horizon row per column.

The scenario files' ``sensor.frames`` carry image and truth only (the scenario schema has no
frame ``time`` yet): read times and the rest of the truth from ``case.frames``. This API
(:func:`cases`, :class:`Case`, :class:`EvalFrame` and their fields) is kept stable; a change
of what is generated bumps :data:`GENERATOR_VERSION`.

**A frame** (:class:`EvalFrame`): ``index``, ``image`` (path), ``size`` (width, height),
``time_s``, true camera ``x, y, z``, ``heading_deg``, ``pitch_deg``, ``roll_deg``,
``eye_height_m``, ``route_index`` (nearest route point: the results' criterion), ``arc_m``,
``lateral_m``, ``heading_error_deg``, ``along_frac`` (sweeps), ``event`` ("", "stop", "gap",
"kidnap"), ``landmarks_px`` (visible pixels per landmark id in this image), ``truth``.

**What makes it unlike the bundled scenarios**

* Terrains of other statistics (:mod:`bench.evalset.terrains`): ridged multifractal, fBm of
  Hurst 0.4/0.6/0.8, terraced mesas, carved valleys, crops of the two real DEMs matplotlib ships
  (Jacksboro, two windows away from the bundled scenario's; the topobathy coast with a flat
  sea), and contour maps (the map is the contour lines; the frames see the true DEM); cells of
  8-30 m.
* Camera frames from another rendering path (:mod:`bench.evalset.raycast`: a numpy height-field
  ray caster with its own palette, world-space texture, cast shadows, sky gradient, fog, sun),
  sensor effects (vignetting, gain, gamma, blur, motion blur, noise, JPEG), and other
  resolutions (200x150, 320x240, 640x480) than the viewframes' 160x120.
* Larger pose errors (:data:`ERROR_BOUNDS`): +-30 % of the route spacing along, +-4 m across,
  +-5 degrees heading, +-2 degrees pitch and roll, +-0.2 m eye height; and a ``large`` profile
  (:data:`ERROR_PROFILES`; ``cases(split, errors="large")``, ``--errors large`` of
  bench/single_frame.py and bench/tracking.py): +-40 % along, +-8 m across, +-10 degrees heading,
  +-3 degrees pitch and roll.
"""

from bench.evalset.cases import (
    CAMERA,
    ERROR_BOUNDS,
    ERROR_PROFILES,
    GENERATOR_VERSION,
    SPLITS,
    TERRAINS,
    Case,
    EvalFrame,
    TerrainEntry,
    case_names,
    cases,
    default_out_dir,
    one_view_a_point,
    seeds,
)

__all__ = [
    "cases",
    "case_names",
    "seeds",
    "Case",
    "EvalFrame",
    "TerrainEntry",
    "TERRAINS",
    "SPLITS",
    "ERROR_BOUNDS",
    "ERROR_PROFILES",
    "CAMERA",
    "GENERATOR_VERSION",
    "default_out_dir",
    "one_view_a_point",
]
