"""Rational polynomial camera (RPC00B): the model of Pléiades, WorldView, SPOT products.

An RPC maps geodetic longitude, latitude and height to image line and sample through
ratios of cubic polynomials of the normalised coordinates (NIMA STDI-0002 RPC00B;
GDAL's ``GDALRPCTransformer``):

``P = (lat − LAT_OFF) / LAT_SCALE``, ``L = (lon − LONG_OFF) / LONG_SCALE``,
``H = (h − HEIGHT_OFF) / HEIGHT_SCALE``;
``line = LINE_OFF + LINE_SCALE · Num_L(P, L, H) / Den_L(P, L, H)``, sample likewise;

each polynomial has 20 terms in RPC00B order: ``1, L, P, H, LP, LH, PH, L², P², H², PLH,
L³, LP², LH², L²P, P³, PH², L²H, P²H, H³``.  Image coordinates are the RPC's with the
first pixel's centre at (0, 0) (GDAL's RPC convention), i.e. CSM ``line = RPC line + 0.5``.
Heights are metres above the body's ellipsoid: WGS84 for Earth (the RPC's datum), given
by ``radii`` otherwise.

Image to ground solves the two RPC equations for (lon, lat) at a given height by Newton
iterations (analytic Jacobian, from the normalised centre), as ASP's ``RPCModel``
and GDAL's RPC transformer do; the imaging ray joins the ground points at the top and
bottom of the RPC's height range.

Readers: GeoTIFF RPC tags (rasterio's ``dataset.rpcs``), GDAL/DigitalGlobe ``_RPC.TXT``
(``KEY: value`` lines) and DigitalGlobe ``.RPB`` (``key = value;``, coefficient lists in
parentheses).  A malformed line is refused naming the file and the line.

References: GDAL ``alg/gdal_rpc.cpp``; ASP ``src/asp/Camera/RPCModel.cc``.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from demtool.errors import InputError
from demtool.sensors.base import Ray, SensorModel

#: WGS84 semi-major and semi-minor axes, metres.
WGS84 = (6378137.0, 6356752.314245179)
#: The 10 offsets/scales of an RPC00B, with their ``_RPC.TXT`` names and ``.RPB`` names.
SCALARS = {"line_off": ("LINE_OFF", "lineOffset"), "samp_off": ("SAMP_OFF", "sampOffset"),
           "lat_off": ("LAT_OFF", "latOffset"), "long_off": ("LONG_OFF", "longOffset"),
           "height_off": ("HEIGHT_OFF", "heightOffset"),
           "line_scale": ("LINE_SCALE", "lineScale"), "samp_scale": ("SAMP_SCALE", "sampScale"),
           "lat_scale": ("LAT_SCALE", "latScale"), "long_scale": ("LONG_SCALE", "longScale"),
           "height_scale": ("HEIGHT_SCALE", "heightScale")}
COEFFS = {"line_num_coeff": ("LINE_NUM_COEFF", "lineNumCoef"),
          "line_den_coeff": ("LINE_DEN_COEFF", "lineDenCoef"),
          "samp_num_coeff": ("SAMP_NUM_COEFF", "sampNumCoef"),
          "samp_den_coeff": ("SAMP_DEN_COEFF", "sampDenCoef")}


def _terms(L, P, H):
    """The 20 RPC00B monomials, stacked on a new last axis."""
    one = np.ones_like(L)
    return np.stack([one, L, P, H, L * P, L * H, P * H, L * L, P * P, H * H, P * L * H,
                     L ** 3, L * P * P, L * H * H, L * L * P, P ** 3, P * H * H, L * L * H,
                     P * P * H, H ** 3], axis=-1)


def _terms_dL(L, P, H):
    z, one = np.zeros_like(L), np.ones_like(L)
    return np.stack([z, one, z, z, P, H, z, 2 * L, z, z, P * H, 3 * L * L, P * P, H * H,
                     2 * L * P, z, z, 2 * L * H, z, z], axis=-1)


def _terms_dP(L, P, H):
    z, one = np.zeros_like(L), np.ones_like(L)
    return np.stack([z, z, one, z, L, z, H, z, 2 * P, z, L * H, z, 2 * L * P, z, L * L,
                     3 * P * P, H * H, z, 2 * P * H, z], axis=-1)


def geodetic_to_xyz(lon, lat, height, radii) -> np.ndarray:
    """Body-fixed XYZ (metres, S + (3,)) of geodetic lon/lat (degrees) and height."""
    a, b = radii
    lon, lat = np.radians(lon), np.radians(lat)
    e2 = 1.0 - (b * b) / (a * a)
    n = a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    h = np.asarray(height, dtype=np.float64)
    return np.stack([(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon),
                     (n * (1.0 - e2) + h) * np.sin(lat)], axis=-1)


def xyz_to_geodetic(xyz, radii) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Geodetic lon, lat (degrees) and height (metres) of body-fixed XYZ (Bowring's
    iteration, converged to 1e-12 rad in a few steps)."""
    xyz = np.asarray(xyz, dtype=np.float64)
    a, b = radii
    e2 = 1.0 - (b * b) / (a * a)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - e2))
    for _ in range(6):
        n = a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
        height = np.where(np.abs(np.cos(lat)) > 1e-9, p / np.cos(lat) - n,
                          np.abs(z) - b)
        lat = np.arctan2(z, p * (1.0 - e2 * n / (n + height)))
    n = a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    height = np.where(np.abs(np.cos(lat)) > 1e-9, p / np.cos(lat) - n, np.abs(z) - b)
    return np.degrees(np.arctan2(y, x)), np.degrees(lat), height


class RpcSensor(SensorModel):
    """An RPC00B camera (see the module docstring).

    Parameters
    ----------
    rpc : dict
        The ten offsets/scales (keys of :data:`SCALARS`) and the four 20-coefficient
        arrays (keys of :data:`COEFFS`).
    lines, samples : int
        Image size in pixels (0 when unknown: an RPC file carries none).
    radii : (float, float)
        Ellipsoid of the heights, metres (WGS84 for Earth).
    name : str
    """

    kind = "rpc"

    def __init__(self, rpc: dict, *, lines: int = 0, samples: int = 0,
                 radii: tuple[float, float] = WGS84, name: str = ""):
        self.rpc = {k: float(rpc[k]) for k in SCALARS}
        for key in COEFFS:
            values = np.asarray(rpc[key], dtype=np.float64).reshape(-1)
            if values.size != 20 or not np.all(np.isfinite(values)):
                raise ValueError(f"'{key}' needs 20 finite coefficients, got {values.size}")
            self.rpc[key] = values
        for key in ("line_scale", "samp_scale", "lat_scale", "long_scale", "height_scale"):
            if self.rpc[key] == 0 or not np.isfinite(self.rpc[key]):
                raise ValueError(f"'{key}' is {self.rpc[key]}: scales must be non-zero")
        self.lines, self.samples = int(lines), int(samples)
        self.radii = (float(radii[0]), float(radii[1]))
        self.name = str(name)

    def __repr__(self) -> str:
        return f"RpcSensor(name={self.name!r}, size={self.lines}x{self.samples})"

    # -- forward -----------------------------------------------------------------------
    def _normalised(self, lon, lat, height):
        r = self.rpc
        return ((np.asarray(lon, dtype=np.float64) - r["long_off"]) / r["long_scale"],
                (np.asarray(lat, dtype=np.float64) - r["lat_off"]) / r["lat_scale"],
                (np.asarray(height, dtype=np.float64) - r["height_off"]) / r["height_scale"])

    def lonlat_to_image(self, lon, lat, height) -> tuple[np.ndarray, np.ndarray]:
        """CSM (line, sample) of geodetic lon/lat (degrees) and height (metres)."""
        r = self.rpc
        L, P, H = np.broadcast_arrays(*self._normalised(lon, lat, height))
        t = _terms(L, P, H)
        with np.errstate(divide="ignore", invalid="ignore"):
            line = (t @ r["line_num_coeff"]) / (t @ r["line_den_coeff"])
            sample = (t @ r["samp_num_coeff"]) / (t @ r["samp_den_coeff"])
        return (line * r["line_scale"] + r["line_off"] + 0.5,
                sample * r["samp_scale"] + r["samp_off"] + 0.5)

    def _jacobian(self, L, P, H):
        """d(line_n, samp_n) / d(L, P) of the normalised model, each S-shaped."""
        r = self.rpc
        t, tl, tp = _terms(L, P, H), _terms_dL(L, P, H), _terms_dP(L, P, H)
        out = []
        for num, den in (("line_num_coeff", "line_den_coeff"),
                         ("samp_num_coeff", "samp_den_coeff")):
            n, d = t @ r[num], t @ r[den]
            for dt in (tl, tp):
                out.append(((dt @ r[num]) * d - n * (dt @ r[den])) / (d * d))
        return out  # dline/dL, dline/dP, dsamp/dL, dsamp/dP

    # -- inverse -----------------------------------------------------------------------
    def image_to_lonlat(self, line, sample, height=0.0, *, tolerance: float = 1e-9,
                        max_iterations: int = 30):
        """Geodetic (lon, lat) in degrees seen at image (line, sample) at ``height``
        metres, by Newton iterations on the normalised RPC (NaN where they diverge)."""
        r = self.rpc
        line, sample, height = np.broadcast_arrays(np.asarray(line, dtype=np.float64),
                                                   np.asarray(sample, dtype=np.float64),
                                                   np.asarray(height, dtype=np.float64))
        want_l = (line - 0.5 - r["line_off"]) / r["line_scale"]
        want_s = (sample - 0.5 - r["samp_off"]) / r["samp_scale"]
        H = (height - r["height_off"]) / r["height_scale"]
        L = np.zeros(line.shape)
        P = np.zeros(line.shape)
        for _ in range(max_iterations):
            t = _terms(L, P, H)
            with np.errstate(divide="ignore", invalid="ignore"):
                fl = (t @ r["line_num_coeff"]) / (t @ r["line_den_coeff"]) - want_l
                fs = (t @ r["samp_num_coeff"]) / (t @ r["samp_den_coeff"]) - want_s
                a, b, c, d = self._jacobian(L, P, H)
                det = a * d - b * c
                dL = (d * fl - b * fs) / det
                dP = (a * fs - c * fl) / det
            L, P = L - dL, P - dP
            if not np.any(np.abs(dL) + np.abs(dP) > tolerance):
                break
        bad = ~(np.abs(dL) + np.abs(dP) <= 1e3 * tolerance)
        lon = np.where(bad, np.nan, L * r["long_scale"] + r["long_off"])
        lat = np.where(bad, np.nan, P * r["lat_scale"] + r["lat_off"])
        return lon, lat

    def image_to_ground(self, line, sample, height=0.0) -> np.ndarray:
        """Body-fixed XYZ (metres, S + (3,)) of image points at geodetic ``height``."""
        lon, lat = self.image_to_lonlat(line, sample, height)
        return geodetic_to_xyz(lon, lat, np.broadcast_to(height, np.shape(lon)), self.radii)

    def image_to_ray(self, line, sample) -> Ray:
        """The ray through the ground points at the top and bottom of the RPC's height
        range (``HEIGHT_OFF ± HEIGHT_SCALE``), from the top, unit direction downwards."""
        r = self.rpc
        top = self.image_to_ground(line, sample, r["height_off"] + abs(r["height_scale"]))
        bottom = self.image_to_ground(line, sample, r["height_off"] - abs(r["height_scale"]))
        direction = bottom - top
        direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
        return Ray(top, direction)

    def ground_to_image(self, xyz) -> tuple[np.ndarray, np.ndarray]:
        """CSM (line, sample) of body-fixed points (metres)."""
        lon, lat, height = xyz_to_geodetic(xyz, self.radii)
        return self.lonlat_to_image(lon, lat, height)

    def camera_center(self, line) -> np.ndarray:
        """An RPC carries no sensor position: NaN (S + (3,))."""
        return np.full(np.shape(line) + (3,), np.nan)

    def sun_position(self, line) -> np.ndarray:
        """An RPC carries no sun: zeros (``demtool camera`` says so)."""
        return np.zeros(np.shape(line) + (3,))


# ---------------------------------------------------------------------------------------
# Readers
# ---------------------------------------------------------------------------------------

def _number(path: Path, number: int, key: str, text: str) -> float:
    token = text.strip().rstrip(";").strip().strip("()").strip().rstrip(",").split()
    try:
        value = float(token[0]) if token else float("nan")
    except ValueError:
        value = float("nan")
    if not np.isfinite(value):
        raise InputError(f"{path}: line {number}: '{key}' is not a number ({text.strip()!r})")
    return value


def parse_rpc_txt(text: str, path: str | Path = "<rpc>") -> dict:
    """Parse GDAL/DigitalGlobe ``_RPC.TXT`` text (``KEY: value [unit]`` per line,
    ``LINE_NUM_COEFF_1`` … ``_20``) into :class:`RpcSensor`'s ``rpc`` dict."""
    path = Path(path)
    names = {v[0]: k for k, v in SCALARS.items()}
    values: dict[str, float] = {}
    coeffs: dict[str, dict[int, float]] = {k: {} for k in COEFFS}
    prefixes = {v[0]: k for k, v in COEFFS.items()}
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        key, sep, value = line.partition(":")
        key = key.strip().upper()
        if not sep:
            raise InputError(f"{path}: line {number}: cannot parse {line!r} (expected "
                             "'KEY: value')")
        if key in names:
            values[names[key]] = _number(path, number, key, value)
            continue
        match = re.fullmatch(r"(LINE_NUM_COEFF|LINE_DEN_COEFF|SAMP_NUM_COEFF|SAMP_DEN_COEFF)"
                             r"_(\d+)", key)
        if match:
            index = int(match.group(2))
            if not 1 <= index <= 20:
                raise InputError(f"{path}: line {number}: '{key}': coefficients are numbered "
                                 "1 to 20")
            coeffs[prefixes[match.group(1)]][index] = _number(path, number, key, value)
        # other keys (ERR_BIAS, ERR_RAND, MIN_/MAX_LONG…) are not needed
    return _assemble(path, values, {k: [v.get(i) for i in range(1, 21)]
                                    for k, v in coeffs.items()}, 0)


def parse_rpb(text: str, path: str | Path = "<rpb>") -> dict:
    """Parse DigitalGlobe ``.RPB`` text (``key = value;``; coefficient lists
    ``key = ( v1, v2, … );`` over several lines) into the ``rpc`` dict."""
    path = Path(path)
    names = {v[1]: k for k, v in SCALARS.items()}
    lists = {v[1]: k for k, v in COEFFS.items()}
    values: dict[str, float] = {}
    coeffs: dict[str, list] = {}
    current: str | None = None
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.upper().startswith(("BEGIN_GROUP", "END_GROUP", "END;")):
            continue
        if current is not None:
            for item in (s for s in line.replace(")", " ").replace(";", " ").split(",")
                         if s.strip()):
                coeffs[current].append(_number(path, number, current, item))
            if ")" in line:
                current = None
            continue
        key, sep, value = (part.strip() for part in line.partition("="))
        if not sep:
            raise InputError(f"{path}: line {number}: cannot parse {line!r} (expected "
                             "'key = value;')")
        if key in lists:
            current = lists[key]
            coeffs[current] = []
            rest = value.lstrip("(")
            for item in (s for s in rest.replace(")", " ").replace(";", " ").split(",")
                         if s.strip()):
                coeffs[current].append(_number(path, number, key, item))
            if ")" in value:
                current = None
        elif key in names:
            values[names[key]] = _number(path, number, key, value)
    return _assemble(path, values, coeffs, 1)


def _assemble(path: Path, values: dict, coeffs: dict, style: int) -> dict:
    for key, spelled in SCALARS.items():
        if key not in values:
            raise InputError(f"{path}: lacks the RPC key '{spelled[style]}'")
    out = dict(values)
    for key, spelled in COEFFS.items():
        got = coeffs.get(key)
        if got is None or any(v is None for v in got):
            missing = (spelled[style] if got is None else
                       f"{spelled[style]}_{[v is None for v in got].index(True) + 1}")
            raise InputError(f"{path}: lacks the RPC key '{missing}'")
        if len(got) != 20:
            raise InputError(f"{path}: '{spelled[style]}' has {len(got)} coefficients, "
                             "expected 20")
        out[key] = np.asarray(got, dtype=np.float64)
    return out


def _image_size(path: Path) -> tuple[int, int, Path | None]:
    """(lines, samples, image) of the image an RPC file sits beside, or (0, 0, None)."""
    stem = re.sub(r"(_RPC)$", "", path.stem, flags=re.IGNORECASE)
    for suffix in (".tif", ".TIF", ".tiff", ".TIFF", ".ntf", ".NTF", ".jp2", ".JP2"):
        candidate = path.with_name(stem + suffix)
        if candidate.exists():
            import rasterio

            try:
                with rasterio.open(candidate) as ds:
                    return int(ds.height), int(ds.width), candidate
            except rasterio.errors.RasterioIOError:
                continue
    return 0, 0, None


def read_rpc(path: str | Path, *, radii: tuple[float, float] | None = None) -> RpcSensor:
    """Read an RPC model: GeoTIFF RPC tags, ``_RPC.TXT`` or ``.RPB``.

    The image size comes from the GeoTIFF, or from the image beside an RPC text file
    (same name without ``_RPC``); otherwise it is 0 x 0 and the model says so in its
    ``notes``.  ``radii`` (metres) replaces WGS84 for another body.

    Raises
    ------
    InputError
        Unreadable file, a malformed line (named by its number), a missing key, a
        coefficient list of the wrong length, a zero scale.
    """
    p = Path(path)
    notes: list[str] = []
    try:
        head = p.read_bytes()[:4]
    except OSError as exc:
        raise InputError(f"{p}: cannot read RPC model ({exc.strerror or exc})") from None
    if head[:4] in (b"II*\0", b"MM\0*", b"II+\0", b"MM\0+"):
        import rasterio

        try:
            with rasterio.open(p) as ds:
                rpcs, lines, samples = ds.rpcs, ds.height, ds.width
        except rasterio.errors.RasterioIOError as exc:
            raise InputError(f"{p}: cannot read GeoTIFF ({exc})") from None
        if rpcs is None:
            raise InputError(f"{p}: not a sensor model: the GeoTIFF carries no RPC tags")
        rpc = {k: getattr(rpcs, k) for k in list(SCALARS) + list(COEFFS)}
    else:
        try:
            text = p.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            raise InputError(f"{p}: not a text RPC file") from None
        rpc = parse_rpb(text, p) if "=" in text.split("\n", 1)[0] or p.suffix.lower() \
            == ".rpb" else parse_rpc_txt(text, p)
        lines, samples, image = _image_size(p)
        if image is None:
            notes.append("the RPC file gives no image size and no image lies beside it")
    try:
        model = RpcSensor(rpc, lines=lines, samples=samples,
                          radii=WGS84 if radii is None else radii,
                          name=re.sub(r"_RPC$", "", p.stem, flags=re.IGNORECASE))
    except ValueError as exc:
        raise InputError(f"{p}: {exc}") from None
    model.notes = notes
    return model
