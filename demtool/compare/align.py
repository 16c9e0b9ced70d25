"""Chained co-registration (``--align``): offset, Nuth & Kääb, ICP, Nuth & Kääb + ICP."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from demtool.compare.coreg import ShiftResult, nuth_kaab, vertical_offset
from demtool.compare.grids import shift_dem
from demtool.compare.icp import apply_similarity, icp_point_to_plane
from demtool.errors import ParameterError
from demtool.logs import get_logger

__all__ = ["ALIGN_METHODS", "Alignment", "coregister"]

log = get_logger(__name__)

ALIGN_METHODS = ("none", "offset", "nuth-kaab", "icp", "nuth-kaab+icp")

# A horizontal shift uncertainty above this (pixels) is flagged in the report and log.
WARN_SIGMA_PX = 0.1


@dataclass
class Alignment:
    """The co-registration applied to a DEM.

    Attributes
    ----------
    method : str
        One of :data:`ALIGN_METHODS`.
    shift : dict
        ``dx_px``, ``dy_px``, ``dz``: the total translation that, added to the DEM,
        aligns it with the reference (x right, y down, grid pixels; dz metres).  With
        ICP, the translation of the DEM's centroid (ICP starts from the Nuth & Kääb
        shift in ``nuth-kaab+icp``, so its translation is the total).
    shift_uncertainty : dict
        One-sigma uncertainties of the same three numbers (inf: unconstrained).
    steps : list of dict
        Each step's method and fitted parameters.
    warnings : list of str
        Messages for the user (poorly constrained shift, no convergence).
    """

    method: str
    shift: dict[str, float] = field(default_factory=lambda: dict(dx_px=0.0, dy_px=0.0, dz=0.0))
    shift_uncertainty: dict[str, float] = field(
        default_factory=lambda: dict(dx_px=0.0, dy_px=0.0, dz=0.0))
    steps: list[dict[str, Any]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready description."""
        return {"method": self.method, "shift": dict(self.shift),
                "shift_uncertainty": dict(self.shift_uncertainty), "steps": self.steps,
                "warnings": list(self.warnings)}

    def _add(self, dx: float, dy: float, dz: float, sx: float, sy: float, sz: float) -> None:
        self.shift = {"dx_px": float(self.shift["dx_px"] + dx),
                      "dy_px": float(self.shift["dy_px"] + dy),
                      "dz": float(self.shift["dz"] + dz)}
        old = self.shift_uncertainty
        self.shift_uncertainty = {"dx_px": float(np.hypot(old["dx_px"], sx)),
                                  "dy_px": float(np.hypot(old["dy_px"], sy)),
                                  "dz": float(np.hypot(old["dz"], sz))}


def _shift_step(name: str, result: ShiftResult) -> dict[str, Any]:
    return {"method": name, "dx_px": result.dx_px, "dy_px": result.dy_px, "dz": result.dz,
            "sigma_dx_px": result.sigma_dx_px, "sigma_dy_px": result.sigma_dy_px,
            "sigma_dz": result.sigma_dz, "iterations": result.iterations,
            "converged": result.converged, "count": result.count}


def coregister(dem: np.ndarray, reference: np.ndarray, *, method: str = "nuth-kaab",
               spacing: tuple[float, float] = (1.0, 1.0), mask: np.ndarray | None = None,
               icp_scale: bool = False, warn_sigma_px: float = WARN_SIGMA_PX,
               seed: int = 0) -> tuple[np.ndarray, Alignment]:
    """Align a DEM to a reference on the same grid.

    Parameters
    ----------
    dem, reference : (H, W) float arrays, metres, NaN = invalid, on one grid
        Not modified.
    method : str
        ``none``, ``offset`` (median vertical offset), ``nuth-kaab`` (horizontal and
        vertical shift, :func:`demtool.compare.coreg.nuth_kaab`), ``icp``
        (point-to-plane, :func:`demtool.compare.icp.icp_point_to_plane`) or
        ``nuth-kaab+icp`` (the shift first, then ICP from there).
    spacing : (float, float)
        Pixel size (x, y), metres (ICP works in metres).
    mask : (H, W) bool, optional
        True on pixels that may be used for the fit (stable terrain).
    icp_scale : bool
        Let ICP fit an isotropic scale too.
    warn_sigma_px : float
        Horizontal shift uncertainty (pixels) above which a warning is issued.
    seed : int
        Seed of the bootstrap.

    Returns
    -------
    aligned : (H, W) float64
        The DEM with the transform applied (NaN where it has no value).
    alignment : Alignment
        What was fitted and applied.
    """
    if method not in ALIGN_METHODS:
        raise ParameterError(f"unknown alignment {method!r}: should be one of "
                             + ", ".join(ALIGN_METHODS))
    alignment = Alignment(method=method)
    aligned = np.asarray(dem, dtype=np.float64).copy()
    if method == "offset":
        result = vertical_offset(aligned, reference, mask=mask)
        aligned = aligned + result.dz
        alignment.steps.append(_shift_step("offset", result))
        alignment._add(0.0, 0.0, result.dz, 0.0, 0.0, result.sigma_dz)
    if method in ("nuth-kaab", "nuth-kaab+icp"):
        result = nuth_kaab(aligned, reference, mask=mask, seed=seed)
        aligned = shift_dem(aligned, result.dx_px, result.dy_px, result.dz)
        alignment.steps.append(_shift_step("nuth-kaab", result))
        alignment._add(result.dx_px, result.dy_px, result.dz, result.sigma_dx_px,
                       result.sigma_dy_px, result.sigma_dz)
        if not result.converged:
            alignment.warnings.append(f"Nuth & Kääb did not converge in {result.iterations} "
                                      "iterations")
    if method in ("icp", "nuth-kaab+icp"):
        # ICP starts from the shift found so far but moves the original DEM's points
        # (no resampling of the DEM before the fit); its translation is the total one.
        sx, sy = float(spacing[0]), float(spacing[1])
        start = alignment.shift
        if method == "icp":
            start = {"dx_px": 0.0, "dy_px": 0.0,
                     "dz": vertical_offset(dem, reference, mask=mask).dz}
        icp = icp_point_to_plane(
            np.asarray(dem, dtype=np.float64), reference, spacing=(sx, sy), mask=mask,
            estimate_scale=icp_scale, seed=seed,
            initial_translation_m=np.array([start["dx_px"] * sx, -start["dy_px"] * sy,
                                            start["dz"]]))
        aligned = apply_similarity(np.asarray(dem, dtype=np.float64), icp, spacing=(sx, sy))
        alignment.steps.append({"method": "icp", **icp.as_dict()})
        t, st = icp.translation_m, icp.sigma_translation_m
        alignment.shift = {"dx_px": float(t[0] / sx), "dy_px": float(-t[1] / sy),
                           "dz": float(t[2])}
        alignment.shift_uncertainty = {"dx_px": float(st[0] / sx), "dy_px": float(st[1] / sy),
                                       "dz": float(st[2])}
        if not icp.converged:
            alignment.warnings.append(f"ICP did not converge in {icp.iterations} iterations")
    sigma = alignment.shift_uncertainty
    worst = max(sigma["dx_px"], sigma["dy_px"])
    if method not in ("none", "offset") and not worst <= warn_sigma_px:
        alignment.warnings.append(
            f"the horizontal shift is poorly constrained (1-sigma {sigma['dx_px']:.3g}, "
            f"{sigma['dy_px']:.3g} px > {warn_sigma_px} px): the terrain is too flat or "
            "too noisy to fix it; treat the shift as uncertain")
    for message in alignment.warnings:
        log.warning("%s", message)
    return aligned, alignment
