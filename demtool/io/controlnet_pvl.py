"""The PVL text form of ISIS control networks (versions 3 to 5), read into
:class:`demtool.io.controlnet.ControlNetwork`.

``Object = ControlNetwork`` with ``NetworkId``, ``TargetName``, ... and ``Version``, then
one ``Object = ControlPoint`` per point (``PointType``, ``PointId``, ``AprioriX/Y/Z``,
``AprioriCovarianceMatrix`` (xx, xy, xz, yy, yz, zz, m²), ``Adjusted...``, flags) with
a ``Group = ControlMeasure`` per measure (``SerialNumber``, ``MeasureType``, ``Sample``,
``Line``, residuals, sigmas, ``Reference``, ``Ignore``); keywords as ISIS
``ControlNetVersioner::toPvl`` writes them and ``readPvlV0005`` reads them.  Pixel
coordinates are converted as in :mod:`demtool.io.controlnet` (ISIS − 0.5).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from demtool.errors import InputError
from demtool.io.controlnet_model import (
    _OBSOLETE,
    ISIS_PIXEL_OFFSET,
    ControlMeasure,
    ControlNetwork,
    ControlPoint,
    _covariance,
)


def _value(group, key: str):
    value = group.get(key)
    if value is None:
        return None
    if hasattr(value, "value"):  # pvl Quantity with units
        value = value.value
    return value


def _number(group, key: str, offset: float = 0.0):
    value = _value(group, key)
    return None if value is None else float(value) + offset


def _flag(group, key: str):
    value = _value(group, key)
    if value is None:
        return None
    return value if isinstance(value, bool) else str(value).strip().lower() in ("true", "yes")


def _text(group, key: str):
    value = _value(group, key)
    return None if value is None else str(value)


def read_pvl_network(label, source: Path) -> ControlNetwork:
    """The network of a parsed PVL label (``label["ControlNetwork"]``)."""
    network = label["ControlNetwork"]
    version = int(network.get("Version", 1))
    if version < 3:
        raise InputError(f"{source}: PVL control network version {version} is not supported "
                         "(3 to 5 are); convert it with ISIS cnetbin2pvl")
    points = []
    for key, value in network.items():
        if key != "ControlPoint":
            continue
        pid = _text(value, "PointId")
        if pid is None:
            raise InputError(f"{source}: control point {len(points)} has no PointId")
        kind = _text(value, "PointType") or "Free"
        kind = _OBSOLETE.get(kind, kind)
        if kind not in ("Free", "Constrained", "Fixed"):
            raise InputError(f"{source}: point {pid}: unknown PointType {kind!r}")
        measures = []
        for mkey, group in value.items():
            if mkey != "ControlMeasure":
                continue
            serial = _text(group, "SerialNumber")
            if serial is None:
                raise InputError(f"{source}: point {pid}: a measure has no SerialNumber")
            log = []
            for name, number in (("GoodnessOfFit", 2), ("MinimumPixelZScore", 3),
                                 ("MaximumPixelZScore", 4), ("PixelShift", 5),
                                 ("WholePixelCorrelation", 6), ("SubPixelCorrelation", 7)):
                if _value(group, name) is not None:
                    log.append((number, _number(group, name), None, None))
            measures.append(ControlMeasure(
                serial=serial, type=_text(group, "MeasureType") or "Candidate",
                line=_number(group, "Line", -ISIS_PIXEL_OFFSET),
                sample=_number(group, "Sample", -ISIS_PIXEL_OFFSET),
                line_residual=_number(group, "LineResidual"),
                sample_residual=_number(group, "SampleResidual"),
                chooser_name=_text(group, "ChooserName"), datetime=_text(group, "DateTime"),
                edit_lock=_flag(group, "EditLock"), ignore=_flag(group, "Ignore"),
                jigsaw_rejected=_flag(group, "JigsawRejected"),
                diameter=_number(group, "Diameter"),
                apriori_line=_number(group, "AprioriLine", -ISIS_PIXEL_OFFSET),
                apriori_sample=_number(group, "AprioriSample", -ISIS_PIXEL_OFFSET),
                line_sigma=_number(group, "LineSigma"),
                sample_sigma=_number(group, "SampleSigma"), log=log))
        xyz = [_number(value, f"Apriori{a}") for a in "XYZ"]
        adjusted = [_number(value, f"Adjusted{a}") for a in "XYZ"]
        points.append(ControlPoint(
            id=pid, type=kind, measures=measures,
            chooser_name=_text(value, "ChooserName"), datetime=_text(value, "DateTime"),
            edit_lock=_flag(value, "EditLock"), ignore=_flag(value, "Ignore"),
            jigsaw_rejected=_flag(value, "JigsawRejected"),
            apriori_surface_point_source=_text(value, "AprioriXYZSource"),
            apriori_surface_point_source_file=_text(value, "AprioriXYZSourceFile"),
            apriori_radius_source=_text(value, "AprioriRadiusSource"),
            apriori_radius_source_file=_text(value, "AprioriRadiusSourceFile"),
            latitude_constrained=_flag(value, "LatitudeConstrained"),
            longitude_constrained=_flag(value, "LongitudeConstrained"),
            radius_constrained=_flag(value, "RadiusConstrained"),
            apriori_xyz=None if None in xyz else np.array(xyz),
            apriori_covariance=_covariance(value.get("AprioriCovarianceMatrix") or [],
                                           str(source), f"point {pid}: "
                                           "AprioriCovarianceMatrix"),
            adjusted_xyz=None if None in adjusted else np.array(adjusted),
            adjusted_covariance=_covariance(value.get("AdjustedCovarianceMatrix") or [],
                                            str(source), f"point {pid}: "
                                            "AdjustedCovarianceMatrix")))
        reference = [i for i, (mkey, group) in enumerate(
            (k, g) for k, g in value.items() if k == "ControlMeasure")
            if _flag(group, "Reference")]
        if reference:
            points[-1].reference_index = reference[0]
    return ControlNetwork(
        network_id=_text(network, "NetworkId") or "", target_name=_text(network,
                                                                         "TargetName") or "",
        points=points, created=_text(network, "Created"),
        last_modified=_text(network, "LastModified"),
        description=_text(network, "Description"), user_name=_text(network, "UserName"),
        version=version)
