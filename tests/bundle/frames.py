"""A synthetic block of frame cameras over a spherical Moon, for the prior-pose tests.

Six wide-angle frame cameras (40° field of view, 30 km altitude) in a 2 × 3 grid over
a point on the sphere, each looking at the block centre (convergent, ~60 % overlap);
ISDs in ALE's layout (body frame = J2000, so the ISD's rotations are the body-fixed
ones); a procedural texture on the sphere for rendered images.
"""

from __future__ import annotations

import json

import numpy as np

from demtool.sensors.base import Detector, matrix_to_quaternion
from demtool.sensors.frame import FrameSensor

RADIUS = 1_737_400.0
ALTITUDE = 30_000.0
SIZE = 320
PIXEL_MM = 0.025
FOCAL_MM = 11.0
CENTRE_LONLAT = (20.0, 10.0)


def _unit(lon_deg: float, lat_deg: float) -> np.ndarray:
    lon, lat = np.radians(lon_deg), np.radians(lat_deg)
    return np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])


def _look_at(position: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Sensor-to-body rotation of a camera at ``position`` looking (+z) at ``target``."""
    z = target - position
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


def detector(size: int = SIZE) -> Detector:
    """Square pixels over a detector of ``SIZE * PIXEL_MM`` millimetres."""
    per_mm = size / (SIZE * PIXEL_MM)
    return Detector(itrans_sample=np.array([0.0, per_mm, 0.0]),
                    itrans_line=np.array([0.0, 0.0, per_mm]),
                    center_sample=size / 2, center_line=size / 2)


def true_models(count: int = 6, size: int = SIZE) -> list[FrameSensor]:
    """The true cameras: a 2 × (count/2) grid, 6 km apart, aimed at the block centre."""
    centre = _unit(*CENTRE_LONLAT) * RADIUS
    up = centre / RADIUS
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    models = []
    columns = count // 2
    for k in range(count):
        row, col = divmod(k, columns)
        offset = (col - (columns - 1) / 2) * 6000.0 * east + (row - 0.5) * 6000.0 * north
        position = centre + ALTITUDE * up + offset
        rotation = _look_at(position, centre + 0.3 * offset)
        models.append(FrameSensor(position=position, rotation=rotation, focal_length=FOCAL_MM,
                                  detector=detector(size), lines=size, samples=size,
                                  radii=(RADIUS, RADIUS), sun=centre * 1e5,
                                  name=f"frame_{k:02d}"))
    return models


def rotate(rotation: np.ndarray, rotvec: np.ndarray) -> np.ndarray:
    from demtool.bundle.offsets import rotation_matrices

    return rotation_matrices(rotvec) @ rotation


def perturbed(models, *, position_m: float = 50.0, pointing_mrad: float = 0.5, seed: int = 1,
              zero_mean: bool = True, common: bool = False) -> list[FrameSensor]:
    """Models moved by ``position_m`` and turned by ``pointing_mrad`` each, in random
    directions; ``zero_mean``: in opposite directions pairwise (the block's mean pose
    stays true); ``common``: the same offset for all."""
    rng = np.random.default_rng(seed)
    out = []
    dp = dw = np.zeros(3)
    for k, m in enumerate(models):
        if common:
            rng = np.random.default_rng(seed)
        if zero_mean and k % 2 == 1:
            dp, dw = -dp, -dw
        else:
            dp = rng.normal(size=3)
            dp *= position_m / np.linalg.norm(dp)
            dw = rng.normal(size=3)
            dw *= pointing_mrad * 1e-3 / np.linalg.norm(dw)
        out.append(FrameSensor(position=m.position + dp, rotation=rotate(m.rotation, dw),
                               focal_length=m.focal_length, detector=m.detector,
                               lines=m.lines, samples=m.samples, radii=m.radii, sun=m.sun,
                               name=m.name))
    return out


def tie_observations(models, *, count: int = 1500, noise_px: float = 0.2, seed: int = 2):
    """Ground points with ±300 m relief projected into the true models, with noise.

    Returns the observations and the true points (P, 3) in the observations' numbering.
    """
    from demtool.bundle.priors import Observations

    rng = np.random.default_rng(seed)
    lon = CENTRE_LONLAT[0] + rng.uniform(-0.6, 0.6, count)
    lat = CENTRE_LONLAT[1] + rng.uniform(-0.5, 0.5, count)
    directions = np.stack([_unit(a, b) for a, b in zip(lon, lat, strict=True)])
    xyz = directions * (RADIUS + rng.uniform(-300, 300, count))[:, None]
    image, point, line, sample = [], [], [], []
    for i, m in enumerate(models):
        ln, sm = m.ground_to_image(xyz)
        inside = (ln > 0) & (ln < m.lines) & (sm > 0) & (sm < m.samples)
        idx = np.flatnonzero(inside)
        image.append(np.full(len(idx), i))
        point.append(idx)
        line.append(ln[idx] + rng.normal(0, noise_px, len(idx)))
        sample.append(sm[idx] + rng.normal(0, noise_px, len(idx)))
    obs = Observations(np.concatenate(image), np.concatenate(point), np.concatenate(line),
                       np.concatenate(sample))
    seen = np.bincount(obs.point, minlength=count) >= 2
    return obs.subset(np.ones(len(obs.image), dtype=bool)), xyz[seen]


def texture(xyz: np.ndarray, seed: int = 3) -> np.ndarray:
    """Procedural albedo of body-fixed points (..., 3): random sinusoids, 150 m … 3 km."""
    rng = np.random.default_rng(seed)
    value = np.zeros(xyz.shape[:-1])
    local = xyz - _unit(*CENTRE_LONLAT) * RADIUS
    for _ in range(40):
        k = rng.normal(size=3)
        k *= 2 * np.pi / (np.linalg.norm(k) * rng.uniform(150.0, 3000.0))
        value += np.sin(local @ k + rng.uniform(0, 2 * np.pi))
    return value


def relief(xyz: np.ndarray) -> np.ndarray:
    """Heights (m) above the sphere of body-fixed points (..., 3): hills of ±400 m,
    7–11 km wavelengths (slopes below 0.3)."""
    local = xyz - _unit(*CENTRE_LONLAT) * RADIUS
    return (250.0 * np.sin(local @ np.array([2 * np.pi / 9000, 0.0, 2 * np.pi / 11000]))
            + 150.0 * np.cos(local @ np.array([0.0, 2 * np.pi / 7000, 2 * np.pi / 13000])))


def render(model) -> np.ndarray:
    """Float32 image (lines, samples) of :func:`texture` on the terrain of :func:`relief`
    seen by ``model`` (rays intersected with the terrain by fixed-point iteration)."""
    rows, cols = np.mgrid[0:model.lines, 0:model.samples]
    xyz = model.image_to_ground(rows + 0.5, cols + 0.5)
    for _ in range(8):
        xyz = model.image_to_ground(rows + 0.5, cols + 0.5, relief(xyz))
    image = texture(xyz)
    return (100.0 + 20.0 * image).astype(np.float32)


def frame_isd(model: FrameSensor) -> dict:
    """An ALE-layout frame ISD of ``model`` (body frame = J2000, positions in metres)."""
    from demtool.sensors.isd import isd_from_sensor

    return isd_from_sensor(model)


def write_isd(model: FrameSensor, path) -> None:
    path.write_text(json.dumps(frame_isd(model)))


__all__ = ["matrix_to_quaternion", "perturbed", "render", "tie_observations", "true_models",
           "write_block"]


def write_block(folder, *, size: int = 320, count: int = 6, prior: bool = True):
    """Rendered images (GeoTIFF, image frame) and prior ISDs of the block in ``folder``.

    Returns (truth models, image paths, ISD paths)."""
    from demtool import io as dio

    truth = true_models(count, size=size)
    models = perturbed(truth) if prior else truth
    images, isds = [], []
    for true, model in zip(truth, models, strict=True):
        image = folder / f"{true.name}.tif"
        dio.write_raster(image, render(true), transform=dio.image_frame_transform(1.0),
                         tags={"frame": f"image:{true.name}"})
        isd = folder / f"{true.name}.json"
        write_isd(model, isd)
        images.append(image)
        isds.append(isd)
    return truth, images, isds


def write_tsai(model: FrameSensor, path) -> None:
    """The frame camera as an ASP ``.tsai`` pinhole (millimetres, pitch = pixel size)."""
    pitch = float(1.0 / model.detector.itrans_sample[1])
    centre = float((model.samples / 2 - 0.5) * pitch)
    lines = ["VERSION_4", "PINHOLE", f"fu = {model.focal_length!r}",
             f"fv = {model.focal_length!r}", f"cu = {centre!r}", f"cv = {centre!r}",
             "u_direction = 1 0 0", "v_direction = 0 1 0", "w_direction = 0 0 1",
             "C = " + " ".join(repr(float(v)) for v in model.position),
             "R = " + " ".join(repr(float(v)) for v in model.rotation.ravel()),
             f"pitch = {pitch!r}", "NULL", ""]
    path.write_text("\n".join(lines))
