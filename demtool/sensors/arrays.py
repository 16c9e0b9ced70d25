"""Frame sensor models as plain arrays (for ``rectify.npz``), and pointing corrections.

A calibrated ``rectify.npz`` carries its two camera models, so that ``dem`` triangulates
through exactly the models (pointing correction included) that rectified the pair, with
no path back to the original ISD, cube or ``.tsai``.  Frame models only: a
:class:`~demtool.sensors.frame.FrameSensor` (ISD, ISIS cube) or a
:class:`~demtool.sensors.pinhole.PinholeCamera` / :class:`~demtool.sensors.tsai.TsaiCamera`.

Every key is prefixed (``sensor_left_``, ``sensor_right_``); the model type is the key
``<prefix>type``.  Pure conversions: arrays in, arrays out, no file I/O.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from demtool.sensors.base import Detector, SensorModel
from demtool.sensors.distortion import Distortion
from demtool.sensors.frame import FrameSensor
from demtool.sensors.pinhole import PinholeCamera
from demtool.sensors.tsai import TsaiCamera

FRAME_TYPES = ("frame", "pinhole", "tsai", "cahvor")


def model_type(model: SensorModel) -> str:
    """``"frame"``, ``"pinhole"`` or ``"tsai"``; ``"linescan"``/other for the rest."""
    if isinstance(model, FrameSensor):
        return "frame"
    if isinstance(model, TsaiCamera):
        return "tsai"
    if isinstance(model, PinholeCamera):
        return "pinhole"
    if type(model).__name__ == "CahvoreCamera":
        return "cahvor"
    return str(getattr(model, "kind", type(model).__name__))


def model_to_arrays(model: SensorModel, prefix: str) -> dict[str, np.ndarray]:
    """The arrays of a frame model, keys prefixed by ``prefix``.

    Raises
    ------
    ValueError
        For a model other than a frame camera or a pinhole.
    """
    kind = model_type(model)
    out: dict[str, Any] = {"type": np.asarray(kind), "name": np.asarray(model.name)}
    if kind == "frame":
        d = model.detector
        out.update(position=model.position, rotation=model.rotation,
                   focal_length=np.asarray(model.focal_length),
                   itrans_sample=np.asarray(d.itrans_sample, dtype=np.float64),
                   itrans_line=np.asarray(d.itrans_line, dtype=np.float64),
                   detector=np.array([d.center_sample, d.center_line, d.start_sample,
                                      d.start_line, d.sample_summing, d.line_summing]),
                   distortion_model=np.asarray(model.distortion.model),
                   distortion=np.asarray(model.distortion.coefficients, dtype=np.float64),
                   distortion_focal_length=np.asarray(model.distortion.focal_length),
                   size=np.array([model.lines, model.samples]),
                   radii=np.asarray(model.radii, dtype=np.float64), sun=model.sun,
                   time=np.asarray(model.time), z_direction=np.asarray(model.z_direction))
    elif kind in ("pinhole", "tsai"):
        out.update(K=model.K, R=model.R, t=model.t, size=np.array([model.height, model.width]),
                   distortion=(np.zeros(0) if model.distortion is None
                               else np.asarray(model.distortion)))
        if kind == "tsai":
            lens = model.lens_model
            out.update(lens_model=np.asarray("" if lens is None else lens.model),
                       lens=np.zeros(0) if lens is None else lens.coefficients,
                       lens_focal_length=np.asarray(1.0 if lens is None else lens.focal_length),
                       radii=np.asarray(model.body_radii if model.body_radii is not None
                                        else (np.nan, np.nan), dtype=np.float64),
                       pitch=np.asarray(model.pitch))
    elif kind == "cahvor":
        out.update(C=model.C, A=model.A, H=model.H, V=model.V, O=model.O, R=model.R,
                   E=model.E, linearity=np.asarray(model.linearity),
                   size=np.array([model.height, model.width]),
                   model_name=np.asarray(model.model_name),
                   radii=np.asarray(model.body_radii if model.body_radii is not None
                                    else (np.nan, np.nan), dtype=np.float64))
    else:
        raise ValueError(f"cannot store a {kind} model in rectify.npz (frame cameras only)")
    return {prefix + key: np.asarray(value) for key, value in out.items()}


def model_from_arrays(arrays: dict[str, np.ndarray], prefix: str) -> SensorModel:
    """The model written by :func:`model_to_arrays` (KeyError when a key is missing)."""
    def get(key):
        return arrays[prefix + key]

    kind = str(get("type"))
    name = str(get("name"))
    if kind == "frame":
        det = get("detector")
        detector = Detector(np.asarray(get("itrans_sample")), np.asarray(get("itrans_line")),
                            *(float(v) for v in det))
        lines, samples = (int(v) for v in get("size"))
        return FrameSensor(position=get("position"), rotation=get("rotation"),
                           focal_length=float(get("focal_length")), detector=detector,
                           distortion=Distortion(str(get("distortion_model")),
                                                 get("distortion"),
                                                 float(get("distortion_focal_length"))),
                           lines=lines, samples=samples, radii=tuple(get("radii")),
                           sun=get("sun"), name=name, time=float(get("time")),
                           z_direction=float(get("z_direction")))
    if kind in ("pinhole", "tsai"):
        height, width = (int(v) for v in get("size"))
        distortion = get("distortion")
        common = dict(K=get("K"), R=get("R"), t=get("t"), width=width, height=height,
                      distortion=distortion if distortion.size else None, name=name)
        if kind == "pinhole":
            return PinholeCamera(**common)
        lens_name = str(get("lens_model"))
        radii = get("radii")
        return TsaiCamera(**common,
                          lens_model=(Distortion(lens_name, get("lens"),
                                                 float(get("lens_focal_length")))
                                      if lens_name else None),
                          body_radii=None if not np.all(np.isfinite(radii)) else tuple(radii),
                          pitch=float(get("pitch")))
    if kind == "cahvor":
        from demtool.sensors.cahvor import CahvoreCamera

        height, width = (int(v) for v in get("size"))
        radii = get("radii")
        return CahvoreCamera(C=get("C"), A=get("A"), H=get("H"), V=get("V"), O=get("O"),
                             R=get("R"), E=get("E"), linearity=float(get("linearity")),
                             width=width, height=height, name=name,
                             model_name=str(get("model_name")),
                             body_radii=None if not np.all(np.isfinite(radii))
                             else tuple(radii))
    raise KeyError(prefix + "type")


def rotation_vector_matrix(omega: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (axis × angle, radians), Rodrigues' formula."""
    omega = np.asarray(omega, dtype=np.float64).reshape(3)
    angle = float(np.linalg.norm(omega))
    if angle < 1e-15:
        return np.eye(3)
    k = omega / angle
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


def rotate_pointing(model: SensorModel, rotation: np.ndarray) -> SensorModel:
    """The same camera turned about its centre: every ray direction ``d`` becomes
    ``rotation @ d`` (both in the body-fixed / world frame); the centre stays.

    Parameters
    ----------
    model : FrameSensor or PinholeCamera
    rotation : (3, 3) float, a rotation in the body-fixed (world) frame

    Returns
    -------
    A new model of the same type.
    """
    import dataclasses

    rotation = np.asarray(rotation, dtype=np.float64)
    kind = model_type(model)
    if kind == "frame":
        arrays = model_to_arrays(model, "")
        arrays["rotation"] = rotation @ model.rotation
        return model_from_arrays(arrays, "")
    if kind in ("pinhole", "tsai"):
        R = model.R @ rotation.T
        return dataclasses.replace(model, R=R, t=-R @ model.center)
    if kind == "cahvor":
        return model.turned(rotation)
    raise ValueError(f"cannot turn a {kind} model")
