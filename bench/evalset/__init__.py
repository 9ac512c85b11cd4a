"""The held-out evaluation set: terrains, drives and camera frames the defaults were not tuned on.

One set serves the single-frame benchmark (issue 10) and the tracker (issue 9). Its cases are
generated on first use, deterministically from the seeds in :data:`TERRAINS`, and cached.

Getting cases::

    from bench.evalset import cases
    for case in cases("heldout"):                 # or "tuning", "fresh"; names=["h-mesas"], kinds=["sweep"]
        results = run_mission(case.scenario_path)  # a normal scenario file with sensor.frames
        for frame in case.frames:                  # time order
            frame.image, frame.truth, frame.route_index, frame.pitch_deg, frame.event ...

**Splits.** ``"tuning"`` (seeds 1xxx) is the only split on which parameters may be chosen;
``"heldout"`` (seeds 2xxx) is for reporting, and has been reported on by many sessions;
``"fresh"`` (seeds 3xxx) is kept for one final measurement: terrains, a renderer, frame sizes
and sensors that neither other split has (below). The three share no seed, no terrain and no
window of a real DEM (:func:`seeds`, :func:`case_names`; tests check it). Nothing may be
chosen on ``heldout`` or ``fresh``; do not run or look at localization on ``fresh`` before
the measurement it is kept for.
``"confirm"`` (seeds 4xxx, session 13) mixes the others' families, renderers and frame sizes
with new seeds and terrain realisations (and a topobathy window none of them uses); it decides the
verification's default by a rule written down before it was run (BENCHMARKS.md).

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
* The ``fresh`` split's terrains: five procedural families the others lack (transverse dunes
  with slip faces, 6 m cells; a plateau with an escarpment and a cliffed canyon; rolling hills
  with flat lakes; a volcanic cone with a crater and radial gullies, given as contours every
  20 m; an alpine valley of 1100 m relief whose frames see 20 km, past the viewframes' 5 km),
  a topobathy window north of the held-out one (a coast and flat sea) and two Jacksboro windows
  clear of every other (the north-east one; the south-west one given as contours every 15 m);
  cells of 6-25 m, route spacings of 20-50 m, routes that keep off water.
* The ``fresh`` split's camera frames come, but for one terrain's (the ray caster's, at
  1280x720), from a third renderer (:mod:`bench.evalset.raster`: a numpy triangle-mesh
  rasteriser with a z-buffer, per-face Lambert shading under a sun of its own, ground
  coloured by world-space noise in palettes of its own, flat water, snow, strata, a sky with
  clouds, distance haze, landmark boxes in colours of its own, then a white-balance cast and
  chromatic aberration before the ray caster's sensor effects), at sizes the others lack:
  1280x720, 640x360 and 512x288 (16:9), 480x640 (portrait), 96x72 (tiny), and 320x240 and
  640x480.
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
    TUNING_SPLITS,
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
    "TUNING_SPLITS",
    "ERROR_BOUNDS",
    "ERROR_PROFILES",
    "CAMERA",
    "GENERATOR_VERSION",
    "default_out_dir",
    "one_view_a_point",
]
