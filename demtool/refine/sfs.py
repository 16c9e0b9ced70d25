"""Shape from shading constrained by a coarse DEM: the energy and its alternating solver.

Energy (Grumpe & Wöhler 2014, *Recovery of elevation from estimated gradient fields
constrained by digital elevation maps of lower lateral resolution*, ISPRS J.
Photogramm. Remote Sens. 94, 37–54; Horn 1990, IJCV 5(1), 37–75), over the slope
field (p, q) and the heights z, all sums over pixels::

    E  = EI + δ Egrad + γ Eint + τ Edepth + ω Eshadow
    EI    = Σ w (I/ρ − R(p, q))²                    intensity error, local albedo ρ
    Egrad = Σ |f(p) − f(∂z0/∂x)|² + |f(q) − f(∂z0/∂y)|²
    Eint  = Σ (p − ∂z/∂x)² + (q − ∂z/∂y)²           integrability
    Edepth= Σ (f(z) − f(z0))²                       low-passed heights stay put
    Eshadow = Σ_crossings (aᵀ(p, q) − L tan ε)²      shadow lengths (ours, see
                                                    :mod:`demtool.refine.shadow_lengths`)

with f a Gaussian low-pass (σ = 21 px), z0 the coarse DEM and R the unit-albedo
reflectance model.  Units: slopes are dimensionless; heights enter in units of the
x pixel spacing (z / dx), so the study's weights (δ = 0.001, γ = 0.2, τ = 10) do not
depend on the map unit.  ``w`` is 0 in shadows and off the image, and tapers to 0 at
the grid border.  The reported energies are per-pixel means.

Solver, alternating:

* slopes: one Gauss–Newton step of EI + δ Egrad + γ Eint per pixel (a 2 × 2 system
  solved in closed form; Egrad majorised with ‖f‖ ≤ 1), plus a rank-one update per
  shadow crossing for ω Eshadow, with Levenberg–Marquardt damping raised when a step
  does not lower the energy;
* heights: one majorise–minimise step of γ Eint + τ Edepth.  The central-difference
  gradient G of Eint is majorised by the forward-difference Neumann Laplacian
  (GᵀG ≤ DᵀD), which the DCT diagonalises together with the Gaussian f, so the step is
  an exact O(N log N) solve (Simchony, Chellappa & Shao 1990) that never raises the
  energy, keeps the mean height exactly, and has no periodic wrap at the borders.
  (GᵀG itself is DCT-diagonal too, eigenvalues sin²ω; solving with it exactly converges
  faster at wavelengths under 4 px but gave a worse default benchmark, slope ratio 0.53
  vs 0.51, as did 200 instead of 60 iterations: at those scales the image carries
  more model mismatch than relief.)

The albedo and the shadow mask are re-estimated from the current DEM every few
iterations (Grumpe et al. 2015).  The iterations start from ``initial`` (the
coarse DEM smoothed at its noise scale).  One image observes the slope along the sun's
azimuth; a relief component whose wave vector makes an angle θ with that azimuth is
seen with weight cos θ, so only a narrow wedge around θ = 90° is unobserved, and the
integrability term carries the oblique components' information across.  Measured
(issue 12; demo line-scan, demo image-frame, seed 1 sun 120°/65° both routes, the
192-cell scene): refine lowers the across-sun slope error too (0.164 for the start
surface → 0.130 on the demo line-scan), 80 % of what is left is at wavelengths under
6 px, where the stereo DEM's regression on the shading's along-sun slopes has gain
< 0.05 (no information), and replacing the refined relief near θ = 90° by the stereo
DEM's Wiener estimate (spectra from the scene; S from the refined along-sun slopes, N
from their difference to the start surface's) or by the stereo DEM's best linear
predictor made every scene worse (slope ratio +0.01 to +0.07): the refined result is
already the better estimate there.  Per-pixel work runs in the numba kernels of
:mod:`demtool.refine.kernels`; Egrad's fᵀf runs on 4 × 4 block means
(:class:`demtool.refine.filters.BlockGaussianLowpass`; δ = 0.001 makes Egrad a
tie-breaker: δ = 0 changes the default benchmark by < 0.001 in every ratio).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from demtool.errors import ProcessingError
from demtool.logs import get_logger, progress
from demtool.refine.albedo import estimate_albedo
from demtool.refine.filters import (
    BlockGaussianLowpass,
    border_taper,
    dct2,
    gaussian_transfer,
    idct2,
    neumann_laplacian_eigenvalues,
)
from demtool.refine.params import SfsParameters
from demtool.refine.rowwork import on_row_blocks
from demtool.refine.shading import Illumination, reflectance_and_gradient
from demtool.refine.shadow_lengths import (
    correct_slope_step,
    independent_splits,
    segment_residuals,
    shadow_segments,
)
from demtool.refine.shadows import image_shadows, shadow_mask
from demtool.tiling.rows import on_row_parts
from demtool.tiling.tasks import available_cores

log = get_logger(__name__)

#: Fewest lit, valid pixels (fraction of the grid) shape from shading works with.
MIN_LIT_FRACTION = 0.05


@dataclass(frozen=True)
class Energies:
    """The energy terms, per-pixel means (heights in units of the pixel spacing)."""

    intensity: float
    gradient: float
    integrability: float
    depth: float
    total: float
    shadow: float = 0.0

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    def __str__(self) -> str:
        return (f"E={self.total:.6g} (EI={self.intensity:.4g}, Egrad={self.gradient:.4g}, "
                f"Eint={self.integrability:.4g}, Edepth={self.depth:.4g}, "
                f"Eshadow={self.shadow:.4g})")


@dataclass(frozen=True)
class RefineResult:
    """What :func:`refine_heights` returns.

    Attributes
    ----------
    dem : (H, W) float32
        Refined heights, metres, same grid as the input.
    albedo : (H, W) float32
        Local albedo of the final DEM, in the image's unit per unit reflectance.
    shadow : (H, W) bool
        Pixels whose intensity was ignored in the last iterations (shadow, dark).
    energies, initial_energies : Energies
        Energy terms at the end and at the start (with the first albedo estimate).
    history : tuple of Energies
        One entry per accepted iteration.
    iterations : int
        Outer iterations run (accepted or not).
    converged : bool
        True when the relative energy decrease fell below the tolerance.
    stop_reason : str
        Why the loop ended.
    intensity_rms : float
        RMS of I/ρ − R over the lit pixels at the end (unit-albedo reflectance).
    """

    dem: np.ndarray
    albedo: np.ndarray
    shadow: np.ndarray
    energies: Energies
    initial_energies: Energies
    history: tuple[Energies, ...] = field(default_factory=tuple)
    iterations: int = 0
    converged: bool = False
    stop_reason: str = ""
    intensity_rms: float = float("nan")


# --------------------------------------------------------------------------------------
# The solver
# --------------------------------------------------------------------------------------


class _State:
    """Slopes, heights and the quantities derived from them (kept between iterations)."""

    def __init__(self, p, q, z, z_hat, solver: _Solver) -> None:
        self.p, self.q, self.z, self.z_hat = p, q, z, z_hat
        self.gx = np.empty_like(z)
        self.gy = np.empty_like(z)
        solver.kernels.central_gradient(z, solver.aspect, self.gx, self.gy)
        self.R, self.Rp, self.Rq = solver.photometric_terms(p, q)
        self.bp = solver.lowpass.apply(p, solver.p0)
        self.bq = solver.lowpass.apply(q, solver.q0)


class _Solver:
    def __init__(self, image, dem, spacing, illumination, params, valid,
                 image_median=None) -> None:
        from demtool.imaging.reflectance import mcewen_L
        from demtool.refine import kernels

        self.kernels = kernels
        self.params = params
        self.illumination = illumination
        self.model_code = kernels.COMPILED_MODELS.get(params.model, -1)
        self.limb = float(mcewen_L(illumination.phase_deg))
        self.sun = np.ascontiguousarray(illumination.sun, dtype=np.float64)
        self.view = np.ascontiguousarray(illumination.view, dtype=np.float64)
        self.spacing = (float(spacing[0]), float(spacing[1]))
        self.aspect = self.spacing[0] / self.spacing[1]
        self.shape = dem.shape
        self.count = dem.size
        self.mean_height = float(np.mean(dem, dtype=np.float64))
        self.z0 = self.to_pixel_units(dem)
        self.valid = valid
        self.image = np.empty(self.shape, dtype=np.float32)
        self.image_nan = np.empty(self.shape, dtype=np.float32)

        def images(start: int, stop: int) -> None:
            rows, usable = image[start:stop], valid[start:stop]
            self.image[start:stop] = np.where(usable, rows, 0.0)
            self.image_nan[start:stop] = np.where(usable, rows, np.nan)

        on_row_blocks(images, *self.shape)
        if image_median is None:
            image_median = float(np.median(image[valid])) if valid.any() else 0.0
        self.image_median = float(image_median)
        self.taper = border_taper(self.shape, params.border_px)
        self.inner = np.zeros(self.shape, dtype=bool)
        self.inner[1:-1, 1:-1] = True
        transfer = gaussian_transfer(self.shape, params.lowpass_sigma)
        self.g2 = np.empty(self.shape, dtype=np.float32)
        on_row_blocks(lambda start, stop: np.square(transfer[start:stop],
                                                    out=self.g2[start:stop]), *self.shape)
        self.lowpass = BlockGaussianLowpass(self.shape, params.lowpass_sigma)
        self.laplacian = neumann_laplacian_eigenvalues(self.shape, self.aspect)
        self.z0_hat = dct2(self.z0)
        self.p0 = np.empty_like(self.z0)
        self.q0 = np.empty_like(self.z0)
        kernels.central_gradient(self.z0, self.aspect, self.p0, self.q0)
        gamma, tau = np.float32(params.gamma), np.float32(params.tau)
        self.inverse_denominator = np.empty(self.shape, dtype=np.float32)
        self.anchor_hat = np.empty(self.shape, dtype=np.float32)

        def height_step_terms(start: int, stop: int) -> None:
            g2 = self.g2[start:stop]
            denominator = gamma * self.laplacian[start:stop] + tau * g2
            self.inverse_denominator[start:stop] = np.where(denominator > 0, 1.0 / np.where(
                denominator > 0, denominator, 1.0), 0.0)
            self.anchor_hat[start:stop] = tau * g2 * self.z0_hat[start:stop]

        on_row_blocks(height_step_terms, *self.shape)
        # the image's dark and dim pixels do not change with the DEM: computed once
        self.image_masks = image_shadows(self.image_nan, params.shadow_threshold,
                                         median=self.image_median)
        self.segments = shadow_segments(self.image_masks[0], valid, self.spacing,
                                        illumination)
        # groups of shadow crossings without a common pixel: corrected on every core
        self.segment_splits = independent_splits(self.segments, available_cores())

    def to_pixel_units(self, heights: np.ndarray) -> np.ndarray:
        """Heights in metres → pixel units about the coarse DEM's mean, C-ordered float32
        (row parts on every core)."""
        heights = np.asarray(heights)
        out = np.empty(heights.shape, dtype=np.float32)

        def part(start: int, stop: int) -> None:
            out[start:stop] = (np.asarray(heights[start:stop], dtype=np.float64)
                               - self.mean_height) / self.spacing[0]

        on_row_blocks(part, *heights.shape)
        return out

    def state_from_heights(self, heights: np.ndarray) -> _State:
        """The state with z from ``heights`` (metres; the mean is reset to the coarse
        DEM's) and slopes ``(p, q) = G z``."""
        z = self.to_pixel_units(heights)
        z_hat = dct2(z)
        z_hat[0, 0] = self.z0_hat[0, 0]
        z = np.ascontiguousarray(idct2(z_hat), dtype=np.float32)
        p = np.empty_like(z)
        q = np.empty_like(z)
        self.kernels.central_gradient(z, self.aspect, p, q)
        return _State(p, q, z, z_hat, self)

    def photometric_terms(self, p: np.ndarray, q: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """R, ∂R/∂p, ∂R/∂q (compiled kernel, or numpy for models without one)."""
        if self.model_code < 0:
            return reflectance_and_gradient(p, q, self.illumination, self.params.model)
        R, Rp, Rq = (np.empty_like(p) for _ in range(3))
        self.kernels.reflectance_partials(p, q, self.sun, self.view, self.limb,
                                          self.model_code, R, Rp, Rq)
        return R, Rp, Rq

    def heights_metres(self, z: np.ndarray) -> np.ndarray:
        """Pixel units → metres, float32 (row parts on every core)."""
        out = np.empty(z.shape, dtype=np.float32)

        def part(start: int, stop: int) -> None:
            out[start:stop] = (z[start:stop].astype(np.float64) * self.spacing[0]
                               + self.mean_height)

        on_row_blocks(part, *z.shape)
        return out

    def normalised(self, albedo: np.ndarray) -> np.ndarray:
        """I/ρ, float32 (row parts on every core)."""
        out = np.empty(self.shape, dtype=np.float32)
        on_row_parts(lambda start, stop: np.divide(self.image[start:stop], albedo[start:stop],
                                                   out=out[start:stop]), self.shape[0])
        return out

    def photometry(self, state: _State) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Shadow mask, albedo and intensity weight for the current DEM."""
        p = self.params
        shadow = shadow_mask(self.heights_metres(state.z), self.image_nan, self.spacing,
                             self.illumination, threshold=p.shadow_threshold,
                             use_dem=p.cast_shadows, median=self.image_median,
                             image_masks=self.image_masks)
        # lit pixels, the albedo's weight and the intensity weight, on row parts
        # (lit_rows: the count of each block, at its first row)
        albedo_weight = np.empty(self.shape, dtype=bool)
        weight = np.empty(self.shape, dtype=np.float32)
        lit_rows = np.zeros(self.shape[0], dtype=np.int64)

        def lit_part(start: int, stop: int) -> None:
            lit = self.valid[start:stop] & ~shadow[start:stop]
            lit_rows[start] = np.count_nonzero(lit)
            np.logical_and(lit, self.inner[start:stop], out=albedo_weight[start:stop])
            np.multiply(self.taper[start:stop], lit, out=weight[start:stop])

        on_row_blocks(lit_part, *self.shape)
        lit_fraction = int(lit_rows.sum()) / self.count  # = lit.mean(): an exact count
        if lit_fraction < MIN_LIT_FRACTION:
            raise ProcessingError(
                f"only {100 * lit_fraction:.1f}% of the grid is lit and covered by the image "
                f"(at least {100 * MIN_LIT_FRACTION:.0f}% needed): check the sun direction "
                "and --shadow-threshold")
        modelled = self.photometric_terms(state.gx, state.gy)[0]
        # the outermost ring has mirrored (halved) slopes: its modelled reflectance is
        # wrong, so it is left out of the albedo (the taper is 0 there)
        albedo = estimate_albedo(self.image, modelled, sigma=p.albedo_sigma,
                                 weight=albedo_weight)
        return shadow, albedo, weight

    def energies(self, state: _State, normalised: np.ndarray, weight: np.ndarray) -> Energies:
        p = self.params
        n = self.count
        e_i, e_grad, e_int = (float(v) for v in self.kernels.energy_sums(
            state.p, state.q, state.gx, state.gy, self.p0, self.q0, state.bp, state.bq,
            state.R, normalised, weight))
        e_depth = self.kernels.weighted_square_sum(self.g2, state.z_hat, self.z0_hat)
        e_shadow = 0.0
        if p.shadow_weight > 0 and self.segments.count:
            e_shadow = float(np.sum(segment_residuals(state.p, state.q, self.segments) ** 2))
        e_i, e_grad, e_int, e_depth, e_shadow = (e_i / n, e_grad / n, e_int / n, e_depth / n,
                                                 e_shadow / n)
        total = (e_i + p.delta * e_grad + p.gamma * e_int + p.tau * e_depth
                 + p.shadow_weight * e_shadow)
        return Energies(e_i, e_grad, e_int, e_depth, total, e_shadow)

    def step(self, state: _State, normalised: np.ndarray, weight: np.ndarray,
             damping: float) -> _State:
        """One slope (Gauss–Newton) and one height (DCT) update."""
        prm = self.params
        k = self.kernels
        p = np.empty_like(state.p)
        q = np.empty_like(state.q)
        k.slope_step(state.p, state.q, state.gx, state.gy, state.R, state.Rp, state.Rq,
                     normalised, weight, state.bp, state.bq, np.float32(prm.gamma),
                     np.float32(prm.delta), np.float32(damping), p, q)
        correct_slope_step(state.p, state.q, p, q, state.Rp, state.Rq, weight,
                           np.float32(prm.gamma) + np.float32(prm.delta) + np.float32(damping),
                           prm.shadow_weight, self.segments, self.segment_splits)
        # heights: (γ DᵀD + τ fᵀf) z = γ (DᵀD z_k + Gᵀ(p − G z_k)) + τ fᵀf z0
        correction = np.empty_like(p)
        k.integrability_adjoint(p, q, state.gx, state.gy, self.aspect, correction)
        z_hat = np.empty_like(state.z_hat)
        k.height_update(state.z_hat, dct2(correction), self.laplacian, self.anchor_hat,
                        self.inverse_denominator, np.float32(prm.gamma), z_hat)
        z_hat[0, 0] = self.z0_hat[0, 0]  # the mean height is the coarse DEM's
        return _State(p, q, np.ascontiguousarray(idct2(z_hat)), z_hat, self)


def refine_heights(image: np.ndarray, dem: np.ndarray, *, spacing: tuple[float, float],
                   illumination: Illumination, parameters: SfsParameters | None = None,
                   valid: np.ndarray | None = None,
                   initial: np.ndarray | None = None,
                   image_median: float | None = None) -> RefineResult:
    """Refine a coarse DEM by shape from shading of one image on the same grid.

    Parameters
    ----------
    image : (H, W) float
        Intensities on the DEM grid, any linear unit (DN, I/F): the local albedo
        absorbs the scale; NaN = no data.
    dem : (H, W) float
        Coarse heights, metres, finite (fill gaps and remove spikes first, see
        :mod:`demtool.refine.prepare`): the anchor of Egrad and Edepth.
    spacing : (dx, dy)
        Grid spacing along x (columns) and y (rows), metres.
    illumination : Illumination
        Sun and view unit vectors in the grid frame.
    parameters : SfsParameters, optional
        Weights, filters and stopping rule (defaults: the studies').
    valid : (H, W) bool, optional
        Pixels whose intensity may be used (default: finite image pixels).
    initial : (H, W) float, optional
        Heights (metres) the iterations start from (default: ``dem``); its mean is
        replaced by the DEM's.  The parts of the relief a single image does not
        constrain (slopes across the sun) keep what they have here, so a slightly
        smoothed DEM is a better start than a noisy one
        (:func:`demtool.refine.prepare.prepare_dem` gives both).
    image_median : float, optional
        The image's median over its valid pixels, in the image's unit, which the shadow
        threshold scales (default: this ``image``'s; a tile of a larger image passes the
        whole image's, :mod:`demtool.refine.tiled`).

    Returns
    -------
    RefineResult

    Raises
    ------
    ParameterError
        Invalid parameters.
    ProcessingError
        Shapes differ, non-finite heights, a grid too small for the filters, or too
        few lit pixels.
    """
    params = parameters or SfsParameters()
    params.check()
    image = np.asarray(image, dtype=np.float32)
    dem = np.asarray(dem, dtype=np.float64)
    if image.shape != dem.shape or dem.ndim != 2:
        raise ProcessingError(f"image {image.shape} and DEM {dem.shape} must be 2-D arrays "
                              "on the same grid")
    if initial is not None and np.shape(initial) != dem.shape:
        raise ProcessingError(f"initial heights {np.shape(initial)} and DEM {dem.shape} must "
                              "be on the same grid")
    if min(dem.shape) < 8:
        raise ProcessingError(f"the grid {dem.shape} is too small for shape from shading "
                              "(at least 8 × 8 pixels)")
    if not np.all(np.isfinite(dem)) or (initial is not None
                                        and not np.all(np.isfinite(initial))):
        raise ProcessingError("the DEM has non-finite heights; fill them first")
    usable = np.isfinite(image) if valid is None else (np.asarray(valid, bool)
                                                       & np.isfinite(image))
    solver = _Solver(image, dem, spacing, illumination, params, usable, image_median)
    state = solver.state_from_heights(dem if initial is None else initial)
    shadow, albedo, weight = solver.photometry(state)
    normalised = solver.normalised(albedo)
    energy = solver.energies(state, normalised, weight)
    initial = energy
    log.info("sun elevation %.1f°, azimuth %.1f°, phase %.1f°; %.1f%% of the grid in "
             "shadow or without image; initial %s", illumination.sun_elevation_deg,
             illumination.sun_azimuth_deg, illumination.phase_deg, 100 * shadow.mean(),
             energy)
    history = [energy]
    damping = 0.0
    converged = False
    stop_reason = f"reached {params.iterations} iterations"
    iteration = 0
    for iteration in progress(range(1, params.iterations + 1), "refine: SfS iterations",
                              total=params.iterations):
        candidate = solver.step(state, normalised, weight, damping)
        new_energy = solver.energies(candidate, normalised, weight)
        retries = 0
        while new_energy.total > energy.total and retries < 6:
            damping = max(4.0 * damping, 0.05 * params.gamma)
            candidate = solver.step(state, normalised, weight, damping)
            new_energy = solver.energies(candidate, normalised, weight)
            retries += 1
        if new_energy.total > energy.total:
            stop_reason = f"energy stopped decreasing at iteration {iteration}"
            break
        decrease = (energy.total - new_energy.total) / max(energy.total, 1e-30)
        state, energy = candidate, new_energy
        damping = damping / 4.0 if damping > 1e-4 * params.gamma else 0.0
        history.append(energy)
        log.debug("iteration %d: %s, relative decrease %.2e, damping %.3g", iteration, energy,
                  decrease, damping)
        if decrease < params.tolerance:
            converged = True
            stop_reason = (f"converged at iteration {iteration} (relative energy decrease "
                           f"{decrease:.1e} < {params.tolerance:g})")
            break
        if iteration % params.update_every == 0:
            shadow, albedo, weight = solver.photometry(state)
            normalised = solver.normalised(albedo)
            energy = solver.energies(state, normalised, weight)
            log.debug("iteration %d: albedo and shadows updated (%.1f%% shadow), %s",
                      iteration, 100 * shadow.mean(), energy)
    shadow, albedo, weight = solver.photometry(state)
    normalised = solver.normalised(albedo)
    final = solver.energies(state, normalised, weight)
    lit = weight > 0
    residual = (normalised - state.R)[lit]
    rms = float(np.sqrt(np.mean(residual.astype(np.float64) ** 2))) if residual.size else \
        float("nan")
    log.info("%s; final %s; intensity residual RMS %.4f", stop_reason, final, rms)
    return RefineResult(dem=solver.heights_metres(state.z), albedo=albedo, shadow=shadow,
                        energies=final, initial_energies=initial, history=tuple(history),
                        iterations=iteration, converged=converged, stop_reason=stop_reason,
                        intensity_rms=rms)
