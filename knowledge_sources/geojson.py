"""A georeferenced run as GeoJSON (RFC 7946: WGS84 lon/lat) that QGIS and geojson.io open.

A pure function from a results file and the scenario's map frame to a FeatureCollection; each
feature's ``properties.kind`` says what it is:

* ``route`` (LineString) and ``route_point`` (Point, ``viewframe`` k): the mission route;
* ``landmark`` (Point, ``id``, ``landmark_kind``): the footprint centres;
* ``truth`` and ``estimate`` (Point, ``frame``, ``correct``, ``error_m``): each camera frame's
  true and estimated position, and ``error`` (LineString truth -> estimate).

The results' own ``*_lonlat`` fields are used where present, so the file shows what the run
reported.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["results_geojson"]


def _point(lonlat: Sequence[float], **props: Any) -> dict[str, Any]:
    return {
        "type": "Feature",
        "properties": props,
        "geometry": {"type": "Point", "coordinates": [float(lonlat[0]), float(lonlat[1])]},
    }


def _line(coords: Sequence[Sequence[float]], **props: Any) -> dict[str, Any]:
    return {
        "type": "Feature",
        "properties": props,
        "geometry": {"type": "LineString", "coordinates": [[float(a), float(b)] for a, b in coords]},
    }


def results_geojson(
    results: dict[str, Any], *, frame: Any, route: Sequence[Sequence[float]], landmarks: Sequence[Any] = ()
) -> dict[str, Any]:
    """The FeatureCollection of one run; ``frame`` a :class:`~models.georef.MapFrame`, ``route``
    the scenario's route in local metres ``(x, y)``, ``landmarks`` objects with ``id``, ``kind``,
    ``x``, ``y`` in local metres."""

    def lonlat(x: float, y: float) -> list[float]:
        lon, lat = frame.to_lonlat(x, y)
        return [float(lon), float(lat)]

    route_ll = [lonlat(x, y) for x, y in route]
    features = [_line(route_ll, kind="route", scenario=results.get("scenario"))]
    features += [_point(p, kind="route_point", viewframe=k) for k, p in enumerate(route_ll)]
    features += [_point(lonlat(lm.x, lm.y), kind="landmark", id=lm.id, landmark_kind=lm.kind) for lm in landmarks]
    for f in results["frames"]:
        props = {
            "frame": f["frame"],
            "correct": f.get("correct"),
            "error_m": f.get("error_m"),
            "viewframe": f.get("viewframe"),
            "truth_viewframe": f.get("truth_viewframe"),
        }
        truth = f.get("truth_lonlat") or (lonlat(*f["truth"][:2]) if f.get("truth") else None)
        est = f.get("position_lonlat") or (lonlat(*f["position"][:2]) if f.get("position") else None)
        if truth is not None:
            features.append(_point(truth, kind="truth", **props))
        if est is not None:
            features.append(_point(est, kind="estimate", confidence=f.get("confidence"), **props))
        if truth is not None and est is not None:
            features.append(_line([truth, est], kind="error", **props))
    return {
        "type": "FeatureCollection",
        "name": f"mapinterp {results.get('scenario')} {results.get('strategy')}",
        "features": features,
    }
