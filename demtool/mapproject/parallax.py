"""The direction of a stereo pair's parallax on the map, for a grid turned along it.

Two orthoimages projected onto one surface show a ground point above (or below) that
surface at two map positions: each camera's ray through the point meets the surface
where that camera's line of sight leans.  The line through the two positions is the
pair's map epipolar direction; ``sgm`` matches along map x, so ``mapproject
--pair-sensor`` turns the grid's x axis along it
(:func:`demtool.maps.crs_option.parallax_aligned_crs`).  ASP's map-projected stereo
searches in 2-D instead (Beyer et al. 2018, §2.3).
"""

from __future__ import annotations

from typing import Any

import numpy as np


def parallax_azimuth(left: Any, right: Any, body: Any, height: float
                     ) -> tuple[float, float, float]:
    """Centre (lon, lat, degrees) of the left image's footprint on the body's surface
    raised by ``height`` (metres), and the azimuth there (degrees clockwise from north)
    of the pair's parallax.

    The point ``dh`` above the centre (ten of the left image's ground pixels) is
    projected into each image and back onto the surface; the azimuth is that of the
    line between the two surface points.

    Raises
    ------
    ValueError
        When a model does not see the point, or the two rays coincide (no parallax).
    """
    from demtool.mapproject.core import _on_surface, native_gsd
    from demtool.maps.frames import enu_frame, lonlat_height_to_xyz, xyz_to_lonlat_height

    surface = body.surface
    centre = _on_surface(left, np.array([0.5 * left.lines]), np.array([0.5 * left.samples]),
                         surface, height)
    lon, lat, _ = xyz_to_lonlat_height(centre[0], radii=surface)
    if not (np.isfinite(lon) and np.isfinite(lat)):
        raise ValueError("the left image's centre does not see the surface")
    dh = 10.0 * native_gsd(left, surface, height)
    above = lonlat_height_to_xyz(lon, lat, height + dh, radii=surface)
    ground = []
    for model in (left, right):
        line, sample = model.ground_to_image(above[None, :])
        ground.append(_on_surface(model, np.atleast_1d(line), np.atleast_1d(sample),
                                  surface, height)[0])
    shift = ground[0] - ground[1]
    east, north, _ = enu_frame(lon, lat) @ shift
    if not np.isfinite(east + north) or np.hypot(east, north) < 1e-3 * dh:
        raise ValueError("the two models see the ground along one line: no parallax")
    return float(lon), float(lat), float(np.degrees(np.arctan2(east, north)))
