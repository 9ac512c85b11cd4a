"""Where the local metric grid lies on the Earth: map CRS, working CRS, origin (pyproj).

Every model works in *local metres* (see :mod:`models.terrain`): x east, y north, the centre of
the south-west DEM cell at (0, 0). A georeferenced map adds a :class:`MapFrame` that ties those
local metres to coordinates on the Earth::

    map CRS (the DEM's or contour file's own CRS, e.g. EPSG:4326 or EPSG:32617)
        | pyproj (identity when the map CRS is projected in metres)
    working CRS (projected, metres: the map CRS itself, else a transverse Mercator centred on the map)
        | minus origin
    local metres (x, y)

Coordinates are always (x, y) = (easting, northing) or (lon, lat), never (lat, lon): pyproj is
used with ``always_xy=True``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from pyproj import CRS, Transformer

__all__ = ["MapFrame", "parse_crs", "working_crs", "crs_name"]

log = logging.getLogger(__name__)

LONLAT = "EPSG:4326"


def parse_crs(value: Any) -> CRS:
    """A :class:`pyproj.CRS` from anything pyproj reads (``"EPSG:4326"``, WKT, PROJ string).

    Raises ``ValueError`` with pyproj's reason for a string it does not know.
    """
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        return CRS.from_user_input(value)
    except CRSError as exc:
        raise ValueError(f"unknown CRS {value!r} ({exc})") from None


def crs_name(crs: CRS) -> str:
    """``EPSG:nnnn`` when the CRS has an authority code, else its WKT."""
    auth = crs.to_authority(min_confidence=90)
    return f"{auth[0]}:{auth[1]}" if auth else crs.to_wkt()


def is_metric(crs: CRS) -> bool:
    """True for a projected CRS whose axes are in metres."""
    if not crs.is_projected:
        return False
    units = {ax.unit_name.lower() for ax in crs.axis_info[:2]}
    return units <= {"metre", "meter", "m"}


def working_crs(crs: CRS, *, lon: float, lat: float) -> CRS:
    """The projected metric CRS local metres are offsets in.

    ``crs`` itself when it is projected in metres, else a transverse Mercator on the WGS84
    ellipsoid centred on (``lon``, ``lat``) (scale 1 on its central meridian: at map scale its
    distances and directions are those on the ground).
    """
    if is_metric(crs):
        return crs
    from pyproj import CRS

    return CRS.from_proj4(
        f"+proj=tmerc +lat_0={lat:.8f} +lon_0={lon:.8f} +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs"
    )


@dataclass(frozen=True, eq=False)
class MapFrame:
    """Ties local metres to a CRS: local ``(x, y)`` is ``working - origin``.

    ``crs`` is the map's own CRS (results and scenario coordinates default to it), ``work`` the
    projected metric CRS of :func:`working_crs`, ``origin`` the working-CRS coordinates of local
    (0, 0). Example: a UTM GeoTIFF whose south-west cell centre is at (500010, 4100010) has
    ``work == crs`` and ``origin == (500010.0, 4100010.0)``.
    """

    crs: CRS
    work: CRS
    origin: tuple[float, float]

    @property
    def name(self) -> str:
        """The map CRS as ``EPSG:nnnn`` (or WKT)."""
        return crs_name(self.crs)

    @cached_property
    def _to_map(self) -> Transformer:
        from pyproj import Transformer

        return Transformer.from_crs(self.work, self.crs, always_xy=True)

    @cached_property
    def _to_lonlat(self) -> Transformer:
        from pyproj import Transformer

        return Transformer.from_crs(self.work, LONLAT, always_xy=True)

    def to_local(self, x: Any, y: Any, *, crs: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """Local metres of points given in ``crs`` (default: the map CRS); arrays of the inputs' shape."""
        from pyproj import Transformer

        src = self.crs if crs is None else parse_crs(crs)
        t = Transformer.from_crs(src, self.work, always_xy=True)
        wx, wy = t.transform(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        return np.asarray(wx) - self.origin[0], np.asarray(wy) - self.origin[1]

    def to_map(self, x: Any, y: Any) -> tuple[np.ndarray, np.ndarray]:
        """Map-CRS coordinates of local metres ``(x, y)``."""
        wx = np.asarray(x, dtype=np.float64) + self.origin[0]
        wy = np.asarray(y, dtype=np.float64) + self.origin[1]
        mx, my = self._to_map.transform(wx, wy)
        return np.asarray(mx), np.asarray(my)

    def to_lonlat(self, x: Any, y: Any) -> tuple[np.ndarray, np.ndarray]:
        """(lon, lat) degrees (WGS84) of local metres ``(x, y)``."""
        wx = np.asarray(x, dtype=np.float64) + self.origin[0]
        wy = np.asarray(y, dtype=np.float64) + self.origin[1]
        lon, lat = self._to_lonlat.transform(wx, wy)
        return np.asarray(lon), np.asarray(lat)

    def describe(self) -> dict[str, Any]:
        """A JSON-able summary: map CRS, working CRS, origin."""
        return {
            "crs": self.name,
            "working_crs": crs_name(self.work),
            "origin": [float(self.origin[0]), float(self.origin[1])],
        }
