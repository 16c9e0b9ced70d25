"""The body's map: bodies and their IAU CRSs, planetocentric coordinates, projections, grids.

Pure functions (arrays in, arrays out) shared by the stages that work on a planetary map
(``dem`` through sensor models, ``mapproject``, ``refine`` on the map, ``compare``):

* :mod:`~demtool.maps.bodies` — :class:`Body` (name, NAIF id, radii, reference sphere),
  PROJ's ``IAU_2015`` codes, lookup by NAIF id / name / radii, the body of a CRS.
* :mod:`~demtool.maps.frames` — planetocentric lon/lat/height ↔ body-fixed XYZ, local
  east-north-up frames.
* :mod:`~demtool.maps.projections` — ``--projection auto|equirectangular|
  polar-stereographic`` on the body's sphere; map x/y ↔ lon/lat ↔ XYZ.
* :mod:`~demtool.maps.grids` — :class:`MapGrid`, grids from footprints at a GSD, cell
  centres as XYZ, heights above the sphere, metric grids for degree grids.

Map raster contract: float32 heights in metres above the body's reference sphere
(:attr:`Body.radius`), NaN nodata, the CRS written (``io.write_raster(..., crs=grid.crs)``)
and the tags of :meth:`Body.tags` (``body``, ``body_naif_id``, ``body_radii_m``,
``reference_sphere_radius_m``, ``height_reference``).
"""

from demtool.maps.bodies import (
    Body,
    body_by_naif_id,
    body_by_name,
    body_from_crs,
    body_from_radii,
    iau_code,
    known_bodies,
    same_body,
    to_pyproj_crs,
)
from demtool.maps.frames import (
    WGS84_ELLIPSOID,
    GeodeticEllipsoid,
    enu_frame,
    local_radius,
    longitude_span,
    lonlat_height_to_xyz,
    unit_vector,
    wrap_longitude,
    xyz_to_lonlat_height,
)
from demtool.maps.grids import (
    MapGrid,
    degree_pixel_size,
    grid_from_lonlat,
    grid_from_xyz,
    grid_lonlat,
    grid_xyz,
    height_above_sphere,
    holds_radii,
    metric_grid_for,
    snap_grid,
)
from demtool.maps.projections import (
    POLAR_LATITUDE,
    PROJECTIONS,
    choose_projection,
    crs_radius,
    crs_surface,
    footprint_center,
    lonlat_to_map,
    make_projection,
    map_to_lonlat,
    map_to_xyz,
    projection_on,
    xyz_to_map,
)

__all__ = [
    "WGS84_ELLIPSOID",
    "GeodeticEllipsoid",
    "POLAR_LATITUDE",
    "PROJECTIONS",
    "Body",
    "MapGrid",
    "body_by_naif_id",
    "body_by_name",
    "body_from_crs",
    "body_from_radii",
    "choose_projection",
    "crs_radius",
    "crs_surface",
    "degree_pixel_size",
    "enu_frame",
    "footprint_center",
    "grid_from_lonlat",
    "grid_from_xyz",
    "grid_lonlat",
    "grid_xyz",
    "height_above_sphere",
    "holds_radii",
    "iau_code",
    "known_bodies",
    "local_radius",
    "lonlat_height_to_xyz",
    "lonlat_to_map",
    "make_projection",
    "longitude_span",
    "map_to_lonlat",
    "map_to_xyz",
    "metric_grid_for",
    "projection_on",
    "same_body",
    "snap_grid",
    "to_pyproj_crs",
    "unit_vector",
    "wrap_longitude",
    "xyz_to_lonlat_height",
    "xyz_to_map",
]
