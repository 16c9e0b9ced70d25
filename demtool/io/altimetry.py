"""Laser altimetry shots from CSV tables: LOLA RDR, MOLA PEDR, or any table of
longitude, latitude and height or radius named by its columns.

* **LOLA RDR** (the PDS Geosciences Node's RDR query CSV, as in ISIS's lidar tests;
  ``LOLARDR.FMT``): no header or a header, columns UTC time, longitude (° E),
  latitude (°), radius (km), …; without a header the first four columns are read in that
  order, and a column of ephemeris seconds, when one matches the UTC times (TDB past
  J2000), is kept as the shots' times.
* **MOLA PEDR** (``pedr2tab`` output): a header with ``long_East``, ``lat_North``,
  ``planet_rad`` (m) or ``topography`` (m above the areoid), ``EphemerisTime``, ``orbit``.
* Any other CSV: a header naming the columns; the longitude, latitude and radius or
  height columns are found by name (``lon``/``longitude``, ``lat``/``latitude``,
  ``radius``/``rad``, ``height``/``elevation``/``topography``) or given (``columns``).
  Radii are kilometres when the column's name says ``km`` or the values are below
  100 000 (no body of a planetary radius in metres is that small: Phobos is 11 km, a
  radius in metres ≥ 1e5 for every body above 100 km), metres otherwise.

Times: UTC is converted to ephemeris seconds (TDB past J2000, as ISDs count) with
TAI − UTC from the leap-second table (IERS Bulletin C) and TT − TAI = 32.184 s
(TDB − TT, < 2 ms, ignored).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from demtool.errors import InputError

#: a shot radius farther than this share of a body's radius from it is another body's
#: (relief on the Moon and Mars stays within ±21 km, < 1 % of their radii)
BODY_TOLERANCE = 0.05
#: TAI − UTC (s) from each date on (IERS Bulletin C)
LEAP_SECONDS = [("1996-01-01", 30), ("1997-07-01", 31), ("1999-01-01", 32),
                ("2006-01-01", 33), ("2009-01-01", 34), ("2012-07-01", 35),
                ("2015-07-01", 36), ("2017-01-01", 37)]
_J2000_UTC = datetime(2000, 1, 1, 11, 58, 55, 816000, tzinfo=UTC)
_NAMES = {
    "lon": ("longitude", "lon", "long", "pt_long", "long_east", "lon_e", "longitude_e",
            "lon_east"),
    "lat": ("latitude", "lat", "pt_lat", "lat_north", "lat_n"),
    "radius": ("radius", "pt_rad", "planet_rad", "radius_km", "radius_m", "rad", "r"),
    "height": ("height", "elevation", "topography", "topo", "h", "height_m", "elev"),
    "time": ("utc", "time", "coordinated_universal_time", "date", "datetime"),
    "et": ("ephemeristime", "ephemeris_time", "et", "tdb"),
    "track": ("orbit", "track", "orbit_number", "pass"),
    "sigma": ("sigma", "sigma_m", "uncertainty", "height_sigma", "radius_sigma"),
}


@dataclass(frozen=True)
class Shots:
    """Altimetry shots.

    Attributes
    ----------
    lon, lat : (N,) float64
        Planetocentric longitude (° east, as in the file) and latitude, degrees.
    radius : (N,) float64 or None
        Distance from the body's centre, metres (None when the file gives heights).
    height : (N,) float64 or None
        Metres above the body's reference surface, when the file gives heights.
    time : (N,) float64 or None
        Ephemeris seconds (TDB past J2000), when the file has times.
    sigma : (N,) float64 or None
        Each shot's stated standard deviation (metres; a ``sigma`` column), if any.
    track : (N,) int
        Track of each shot: the file's orbit column, else runs of shots without a gap
        of more than ten times their median spacing in time (0 without times).
    source : str
    """

    lon: np.ndarray
    lat: np.ndarray
    radius: np.ndarray | None
    height: np.ndarray | None
    time: np.ndarray | None
    track: np.ndarray
    source: str
    sigma: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.lon)


def utc_to_et(text: str) -> float:
    """Ephemeris seconds of an ISO UTC time (``2010-01-27T06:19:47.0138``)."""
    text = text.strip().rstrip("Z")
    match = re.fullmatch(r"(\d{4}-\d{2}-\d{2})[T ](\d{2}):(\d{2}):(\d{2})(\.\d+)?", text)
    if match is None:
        raise ValueError(f"not an ISO UTC time: {text!r}")
    date, hh, mm, ss, frac = match.groups()
    moment = datetime.fromisoformat(f"{date}T{hh}:{mm}:{ss}").replace(tzinfo=UTC)
    leap = 32
    for start, value in LEAP_SECONDS:
        if date >= start:
            leap = value
    return ((moment - _J2000_UTC).total_seconds() + float(frac or 0.0)
            + (leap - 32))


def _find(header: list[str], key: str, given: str | None, source: Path) -> int | None:
    names = [h.strip().lower() for h in header]
    if given is not None:
        if given.lower() not in names:
            raise InputError(f"{source}: no column {given!r} (columns: {', '.join(header)})")
        return names.index(given.lower())
    for alias in _NAMES[key]:
        for i, name in enumerate(names):
            if re.sub(r"[\s(\[].*$", "", name) == alias or name == alias:
                return i
    return None


def _tracks(time, given) -> np.ndarray:
    if given is not None:
        _, index = np.unique(given, return_inverse=True)
        return index.astype(np.int64)
    if time is None or len(time) < 2:
        return np.zeros(0 if time is None else len(time), dtype=np.int64)
    order = np.argsort(time)
    gaps = np.diff(time[order])
    spacing = float(np.median(gaps)) if len(gaps) else 0.0
    breaks = np.concatenate([[0], np.cumsum(gaps > 10 * max(spacing, 1e-6))])
    track = np.empty(len(time), dtype=np.int64)
    track[order] = breaks
    return track


def read_shots(path: str | os.PathLike, *, lon: str | None = None, lat: str | None = None,
               radius: str | None = None, height: str | None = None) -> Shots:
    """Read an altimetry CSV (module docstring); ``lon``, ``lat``, ``radius``,
    ``height``: column names, when the names are not the usual ones.

    Raises
    ------
    InputError
        No longitude/latitude/radius-or-height columns, a value that is not a number,
        or no shot.
    """
    import csv

    from demtool.io.files import require_file

    source = require_file(path, "altimetry table")
    try:
        rows = [r for r in csv.reader(source.read_text(encoding="utf-8",
                                                       errors="replace").splitlines())
                if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#")]
    except OSError as exc:
        raise InputError(f"{source}: cannot read ({exc.strerror or exc})") from None
    if not rows:
        raise InputError(f"{source}: no altimetry shots")
    first = [c.strip() for c in rows[0]]

    def number(text):
        try:
            float(text)
            return True
        except ValueError:
            return False

    has_header = not number(first[1] if len(first) > 1 else first[0])
    body = rows[1:] if has_header else rows
    if has_header:
        cols = {k: _find(first, k, g, source) for k, g in
                (("lon", lon), ("lat", lat), ("radius", radius), ("height", height),
                 ("time", None), ("et", None), ("track", None), ("sigma", None))}
        if radius is None and height is not None:
            cols["radius"] = None
        if cols["lon"] is None or cols["lat"] is None or (cols["radius"] is None and
                                                          cols["height"] is None):
            raise InputError(f"{source}: cannot tell the longitude, latitude and radius or "
                             f"height columns of {', '.join(first)}; name them "
                             "(--shots-lon, --shots-lat, --shots-radius or --shots-height)")
        if cols["radius"] is not None:
            cols["height"] = None
        names = [first[i].lower() if i is not None else "" for i in (cols["radius"],)]
    else:  # LOLA RDR order: UTC, longitude, latitude, radius (km)
        if len(first) < 4:
            raise InputError(f"{source}: a CSV without a header needs the LOLA RDR columns "
                             "(UTC, longitude, latitude, radius km); this one has "
                             f"{len(first)}")
        cols = {"time": 0, "lon": 1, "lat": 2, "radius": 3, "height": None, "et": None,
                "track": None, "sigma": None}
        names = ["radius_km"]
    try:
        table = {k: np.array([float(r[i]) for r in body]) for k, i in cols.items()
                 if i is not None and k not in ("time", "track")}
    except (ValueError, IndexError) as exc:
        raise InputError(f"{source}: a shot's value is not a number ({exc})") from None
    if not len(table["lon"]):
        raise InputError(f"{source}: no altimetry shots")
    time = table.get("et")
    if time is None and cols["time"] is not None:
        try:
            time = np.array([utc_to_et(r[cols["time"]]) for r in body])
        except (ValueError, IndexError):
            time = None
    if not has_header and time is not None:
        # a column of ephemeris seconds equal to the UTC times (the RDR's transmit time)
        for i in range(4, len(first)):
            try:
                column = np.array([float(r[i]) for r in body])
            except (ValueError, IndexError):
                continue
            if np.all(np.abs(column - time) < 0.01):
                time = column
                break
    values = table.get("radius")
    r = h = None
    if values is not None:
        kilometres = "km" in names[0] or float(np.nanmedian(np.abs(values))) < 1e5
        r = values * (1000.0 if kilometres else 1.0)
    else:
        h = table["height"]
    track_values = None
    if cols.get("track") is not None:
        track_values = [row[cols["track"]] for row in body]
    return Shots(lon=table["lon"], lat=table["lat"], radius=r, height=h, time=time,
                 track=_tracks(time, track_values), source=str(Path(source)),
                 sigma=table.get("sigma"))
