"""An ISD's ``optical_distortion`` block ↔ :class:`~demtool.sensors.distortion.Distortion`.

Every model usgscsm reads (``Utilities.cpp`` ``getDistortionModel`` /
``getDistortionCoeffs``: transverse, radial, kaguyalism, dawnfc, lrolrocnac, cahvor,
lunarorbiter, radtan) with its keys as usgscsm and ALE write them, and the ISIS mission
maps ALE writes that usgscsm does not implement (``legendre`` for New Horizons MVIC
frames, ``themisir``: :mod:`demtool.sensors.distortion_isis`).  ``radial`` with fewer than
three coefficients (Galileo SSI's ISD has one) gets zeros for the missing terms: usgscsm
indexes [0], [1], [2].  ``legendre`` on a line scan (MVIC's TDI mode, whose ISIS map adds
residual row and column tables) is refused by name.

References: DOI-USGS/usgscsm ``src/Utilities.cpp``, ``src/Distortion.cpp``; DOI-USGS/ale
``ale/formatters/formatter.py``, ``ale/base/type_distortion.py``.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from demtool.errors import InputError
from demtool.sensors.distortion import Distortion

FRAME_MODEL = "USGS_ASTRO_FRAME_SENSOR_MODEL"


def distortion_from_isd(keys, isd: Mapping, focal_length: float) -> Distortion:
    """The :class:`Distortion` of an ISD's ``optical_distortion`` (see the module
    docstring); ``keys`` is the ISD reader's key helper (its errors name the file and
    the key)."""
    block = keys.get(isd, "optical_distortion")
    if not isinstance(block, Mapping) or len(block) != 1:
        raise InputError(f"{keys.source}: ISD key 'optical_distortion' must hold exactly one "
                         "model")
    model, params = next(iter(block.items()))
    where = f"optical_distortion.{model}."
    model = str(model).lower()
    if model == "transverse":
        coefficients = np.concatenate([keys.array(params, "x", where, (10,)),
                                       keys.array(params, "y", where, (10,))])
    elif model == "kaguyalism":
        coefficients = np.concatenate([
            [float(keys.get(params, "boresight_x", where))], keys.array(params, "x", where, (4,)),
            [float(keys.get(params, "boresight_y", where))], keys.array(params, "y", where, (4,))])
    elif model == "lunarorbiter":
        # ALE writes the perspective factors and the point of symmetry as usgscsm reads
        # them (perspective_x/_y, center_point_x/_y) and the radial terms k0, k1 (ISIS's
        # INS<code>_OD_K) as 'odk' (older demtool ISDs: 'coefficients').
        radial = next((k for k in ("odk", "coefficients") if k in params), None)
        if radial is None:
            raise InputError(f"{keys.source}: ISD lacks the key '{where}odk' (the radial "
                             "distortion terms k0, k1 of the Lunar Orbiter camera)")
        terms = list(keys.array(params, radial, where))
        if len(terms) not in (1, 2):
            raise InputError(f"{keys.source}: ISD key '{where}{radial}' has {len(terms)} "
                             "values, expected 2 (k0, k1)")
        coefficients = np.array([float(keys.get(params, k, where)) for k in
                                 ("perspective_x", "perspective_y", "center_point_x",
                                  "center_point_y")] + (terms + [0.0])[:2])
    elif model == "cahvor" and "x" in params:
        coefficients = np.concatenate([keys.array(params, "coefficients", where, (3,)),
                                       [float(params["x"]), float(params.get("y", 0.0))]])
    elif model == "cahvor":  # usgscsm reads coefficients[0..4]: k0, k1, k2, x0, y0
        coefficients = keys.array(params, "coefficients", where)[:5]
    elif model == "radial":
        # usgscsm reads ``coefficients`` as given and uses [0], [1], [2]; ALE writes fewer
        # for some cameras (Galileo SSI: [k1]): the missing terms are zero.
        coefficients = keys.array(params, "coefficients", where)
        if 0 < len(coefficients) < 3:
            coefficients = np.concatenate([coefficients, np.zeros(3 - len(coefficients))])
    elif model == "themisir":  # ISIS ThemisIrDistortionMap (ALE's keys)
        coefficients = np.array([float(keys.get(params, k, where))
                                 for k in ("p_alpha1", "p_alpha2", "p_k")])
    elif model == "legendre":  # ISIS NewHorizonsMvicFrameCameraDistortionMap
        if isd.get("name_model") != FRAME_MODEL:
            raise InputError(f"{keys.source}: ISD distortion 'legendre' on a "
                             f"{isd.get('name_model')}: New Horizons MVIC's TDI distortion "
                             "(ISIS NewHorizonsMvicTdiCameraDistortionMap, with its residual "
                             "row and column tables) is not implemented; its framing-mode "
                             "(frame ISD) distortion is")
        pitch_x = 1.0 / abs(float(keys.array(isd, "focal2pixel_samples", shape=(3,))[1]
                                  or np.inf))
        pitch_y = 1.0 / abs(float(keys.array(isd, "focal2pixel_lines", shape=(3,))[2]
                                  or np.inf))
        coefficients = np.concatenate([
            [0.5 * float(isd["image_samples"]) * pitch_x,
             0.5 * float(isd["image_lines"]) * pitch_y],
            keys.array(params, "x_coefficients", where, (20,)),
            keys.array(params, "y_coefficients", where, (20,))])
    else:
        coefficients = keys.array(params, "coefficients", where)
    try:
        return Distortion(model, coefficients, focal_length)
    except ValueError as exc:
        raise InputError(f"{keys.source}: ISD key 'optical_distortion': {exc}") from None


def distortion_block(distortion: Distortion) -> dict:
    """ALE's ``optical_distortion`` block of a :class:`Distortion` (the inverse of the
    reader's :func:`_distortion`; an ideal lens is ALE's zero ``radial``)."""
    model, c = distortion.model, [float(v) for v in distortion.coefficients]
    if model == "none":
        return {"radial": {"coefficients": [0.0, 0.0, 0.0]}}
    if model == "transverse":
        return {model: {"x": c[:10], "y": c[10:]}}
    if model == "kaguyalism":
        return {model: {"boresight_x": c[0], "x": c[1:5], "boresight_y": c[5], "y": c[6:10]}}
    if model == "lunarorbiter":
        return {model: {"perspective_x": c[0], "perspective_y": c[1], "center_point_x": c[2],
                        "center_point_y": c[3], "odk": c[4:6]}}
    if model == "cahvor":
        return {model: {"coefficients": c[:3], "x": c[3], "y": c[4]}}
    if model == "themisir":
        return {model: {"p_alpha1": c[0], "p_alpha2": c[1], "p_k": c[2]}}
    if model == "legendre":
        return {model: {"x_coefficients": c[2:22], "y_coefficients": c[22:42]}}
    return {model: {"coefficients": c}}
