"""Reflectance models shared by the renderer (``synth``) and shape from shading (``refine``).

All functions are vectorised over arrays of cosines; angles are in degrees where named
``*_deg``.  A small registry (:data:`MODELS`) lets ``refine`` pick a model by name;
a Hapke model can be added by registering a function with the same signature.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def mcewen_L(phase_deg: np.ndarray | float) -> np.ndarray:
    """Limb-darkening weight L(α) of the lunar-Lambert model.

    McEwen (1991), *Photometric functions for photoclinometry and other applications*,
    Icarus 92, 298–311; the cubic fit used by Grumpe & Wöhler (2014):
    ``L(α) = 1 − 0.019 α + 2.42e-4 α² − 1.46e-6 α³`` with α the phase angle in degrees.
    """
    a = np.asarray(phase_deg, dtype=np.float64)
    return 1.0 - 0.019 * a + 2.42e-4 * a**2 - 1.46e-6 * a**3


def lunar_lambert(mu0: np.ndarray, mu: np.ndarray, phase_deg: np.ndarray | float,
                  albedo: np.ndarray | float = 1.0) -> np.ndarray:
    """Lunar-Lambert reflectance ``R = ρ (2L μ0 / (μ0 + μ) + (1 − L) μ0)``.

    McEwen (1991), eq. 4 (with L from :func:`mcewen_L`).

    Parameters
    ----------
    mu0 : array
        Cosine of the incidence angle (surface normal · sun direction).
    mu : array
        Cosine of the emission angle (surface normal · view direction).
    phase_deg : array or float
        Phase angle (sun–surface–viewer) in degrees.
    albedo : array or float
        ρ, the normal albedo.

    Returns
    -------
    array
        Reflectance; 0 where the surface faces away from the sun (μ0 ≤ 0) or the viewer.
    """
    mu0 = np.asarray(mu0, dtype=np.float64)
    mu = np.asarray(mu, dtype=np.float64)
    L = mcewen_L(phase_deg)
    lit = (mu0 > 0) & (mu > 0)
    safe_mu0 = np.where(lit, mu0, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        lommel_seeliger = np.where(lit, 2.0 * safe_mu0 / (safe_mu0 + np.where(lit, mu, 1.0)), 0.0)
    return albedo * (L * lommel_seeliger + (1.0 - L) * safe_mu0)


def lambert(mu0: np.ndarray, mu: np.ndarray, phase_deg: np.ndarray | float,
            albedo: np.ndarray | float = 1.0) -> np.ndarray:
    """Lambert reflectance ``R = ρ max(μ0, 0)`` (μ and phase unused; same signature)."""
    mu0 = np.asarray(mu0, dtype=np.float64)
    return albedo * np.clip(mu0, 0.0, None)


ReflectanceModel = Callable[..., np.ndarray]

MODELS: dict[str, ReflectanceModel] = {
    "lunar-lambert": lunar_lambert,
    "lambert": lambert,
}


def get_model(name: str) -> ReflectanceModel:
    """A reflectance model by name; ValueError listing the known ones."""
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(f"unknown reflectance model {name!r}: should be one of "
                         + ", ".join(MODELS)) from None


def phase_angle_deg(sun_vector: np.ndarray, view_vector: np.ndarray) -> np.ndarray:
    """Phase angle in degrees between unit vectors toward the sun and toward the viewer."""
    s = np.asarray(sun_vector, dtype=np.float64)
    v = np.asarray(view_vector, dtype=np.float64)
    cosine = np.sum(s * v, axis=-1) / (np.linalg.norm(s, axis=-1) * np.linalg.norm(v, axis=-1))
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


def sun_vector(incidence_deg: float, azimuth_deg: float) -> np.ndarray:
    """Unit vector toward the sun from its incidence (zenith) angle and azimuth.

    Azimuth is measured clockwise from north (+Y) toward east (+X), in a frame with
    X east, Y north, Z up.
    """
    i = np.radians(incidence_deg)
    a = np.radians(azimuth_deg)
    return np.array([np.sin(i) * np.sin(a), np.sin(i) * np.cos(a), np.cos(i)])


# --------------------------------------------------------------------------------------
# Partial derivatives with respect to the cosines (used by the SfS solver in ``refine``)
# --------------------------------------------------------------------------------------


def _float_array(value) -> np.ndarray:
    """``value`` as a float array, keeping float32 (the SfS solver's dtype) as float32."""
    array = np.asarray(value)
    return array if array.dtype in (np.float32, np.float64) else array.astype(np.float64)


def _weak(value):
    """A 0-d value as a Python float, so it does not promote float32 arrays to float64."""
    return float(value) if np.ndim(value) == 0 else np.asarray(value)


def lunar_lambert_partials(mu0: np.ndarray, mu: np.ndarray, phase_deg: np.ndarray | float,
                           albedo: np.ndarray | float = 1.0
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lunar-Lambert reflectance and its partial derivatives ∂R/∂μ0 and ∂R/∂μ.

    From McEwen (1991), eq. 4, ``R = ρ (2L μ0 / (μ0 + μ) + (1 − L) μ0)``:
    ``∂R/∂μ0 = ρ (2L μ / (μ0 + μ)² + 1 − L)`` and ``∂R/∂μ = −2ρL μ0 / (μ0 + μ)²``.

    R is 0 where μ0 ≤ 0 or μ ≤ 0, as in :func:`lunar_lambert`; the derivatives are
    those of the lit branch at the clamped cosines ``max(μ0, 1e-6)``, ``max(μ, 1e-6)``,
    so a solver in attached shadow is still pointed toward the lit side.  float32
    inputs give float32 outputs.

    Returns
    -------
    R, dR_dmu0, dR_dmu : arrays
        Broadcast shape of the inputs.
    """
    mu0 = _float_array(mu0)
    mu = _float_array(mu)
    L = _weak(mcewen_L(phase_deg))
    albedo = _weak(albedo)
    lit = (mu0 > 0) & (mu > 0)
    c0 = np.maximum(mu0, 1e-6)
    c = np.maximum(mu, 1e-6)
    inv_total = 1.0 / (c0 + c)
    reflectance = np.where(lit, albedo * (2.0 * L * c0 * inv_total + (1.0 - L) * c0), 0.0)
    d_mu0 = albedo * (2.0 * L * c * inv_total**2 + (1.0 - L))
    d_mu = -albedo * 2.0 * L * c0 * inv_total**2
    return reflectance.astype(c0.dtype), d_mu0, d_mu


def lambert_partials(mu0: np.ndarray, mu: np.ndarray, phase_deg: np.ndarray | float,
                     albedo: np.ndarray | float = 1.0
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lambert reflectance ``ρ max(μ0, 0)`` and its partials (∂R/∂μ0 = ρ, ∂R/∂μ = 0)."""
    mu0 = _float_array(mu0)
    mu = _float_array(mu)
    albedo = _weak(albedo)
    shape = np.broadcast_shapes(mu0.shape, mu.shape, np.shape(albedo))
    reflectance = np.broadcast_to(albedo * np.clip(mu0, 0.0, None), shape)
    d_mu0 = np.broadcast_to(albedo * np.ones_like(mu0), shape)
    return reflectance, d_mu0, np.zeros(shape, dtype=mu0.dtype)


ReflectancePartials = Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray]]

#: Models with analytic partials; a model absent here is differentiated numerically.
PARTIALS: dict[str, ReflectancePartials] = {
    "lunar-lambert": lunar_lambert_partials,
    "lambert": lambert_partials,
}


def get_partials(name: str) -> ReflectancePartials:
    """``(R, ∂R/∂μ0, ∂R/∂μ)`` of a registered model: analytic where known, else central
    differences of :func:`get_model` (step 1e-4 in each cosine)."""
    if name in PARTIALS:
        return PARTIALS[name]
    model = get_model(name)

    def numerical(mu0, mu, phase_deg, albedo=1.0):
        step = 1e-4
        mu0 = np.asarray(mu0, dtype=np.float64)
        mu = np.asarray(mu, dtype=np.float64)
        c0 = np.maximum(mu0, step)
        c = np.maximum(mu, step)
        d_mu0 = (model(c0 + step, c, phase_deg, albedo)
                 - model(c0 - step, c, phase_deg, albedo)) / (2 * step)
        d_mu = (model(c0, c + step, phase_deg, albedo)
                - model(c0, c - step, phase_deg, albedo)) / (2 * step)
        return model(mu0, mu, phase_deg, albedo), d_mu0, d_mu

    return numerical
