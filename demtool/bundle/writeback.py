"""Adjusted sensor models written back in the format they came in.

* ISD JSON (ALE): the ``instrument_position`` states and ``instrument_pointing``
  quaternions are rewritten so the ISD's model is the adjusted one (ISIS's jigsaw
  updates a cube's SPICE tables the same way); every other key is kept.
* ISIS cube with SPICE: the ISD JSON of the cube's frame model
  (:func:`demtool.sensors.isd.isd_from_sensor`, body frame = J2000, read by usgscsm and
  :func:`demtool.sensors.read_isd`), then adjusted as above.
* ASP ``.tsai``: the ``C`` and ``R`` lines replaced (``C' = C + dC``, ``R' = dR R``).

With a :class:`demtool.bundle.offsets.PoseOffset` (``X' = P + dRᵀ (X − P − dC)``, body
frame): a body-fixed position ``p`` becomes ``P + dR (p − P) + dC`` and a
sensor-to-body rotation ``S`` becomes ``dR S``.  ISDs store J2000 positions
``B(t)ᵀ p`` and J2000-to-sensor pointing ``Q(t)`` with ``S = B Qᵀ``, so
``p_J2000' = Bᵀ (P + dR (B p_J2000 − P) + dC)`` and ``Q' = Q Bᵀ dRᵀ B``, with
``B(t)`` the body rotation at each record's time.
"""

from __future__ import annotations

import copy
import json
import re
from collections.abc import Mapping
from typing import Any

import numpy as np

from demtool.bundle.offsets import PoseOffset
from demtool.errors import ProcessingError
from demtool.sensors.base import matrix_to_quaternion, quaternion_to_matrix
from demtool.sensors.isd import Orientations, isd_from_sensor

_UNITS = {"m": 1.0, "km": 1000.0}


def _body(isd: Mapping) -> Orientations:
    block = isd["body_rotation"]
    quats = np.asarray(block["quaternions"], dtype=np.float64).reshape(-1, 4)[:, [1, 2, 3, 0]]
    constant = block.get("constant_rotation")
    return Orientations(block["ephemeris_times"], quats,
                        None if constant is None else np.asarray(constant).reshape(3, 3))


def adjust_isd(isd: Mapping[str, Any], offset: PoseOffset) -> dict[str, Any]:
    """A copy of an ALE ISD (dict) with its pose moved by ``offset`` (module docstring)."""
    out = copy.deepcopy(dict(isd))
    body = _body(isd)
    d_r = offset.matrix
    position = out["instrument_position"]
    scale = _UNITS[str(position.get("unit", "km")).lower()]
    times = np.asarray(position["ephemeris_times"], dtype=np.float64).reshape(-1)
    b = body.matrices_at(times)
    p_body = np.einsum("nij,nj->ni", b, np.asarray(position["positions"], dtype=np.float64)
                       * scale)
    p_body = offset.from_original(p_body)
    position["positions"] = (np.einsum("nji,nj->ni", b, p_body) / scale).tolist()
    if "velocities" in position:
        v = np.asarray(position["velocities"], dtype=np.float64).reshape(-1, 3)
        turn = np.einsum("nji,jk,nkl->nil", b, d_r, b)  # Bᵀ dR B
        position["velocities"] = np.einsum("nij,nj->ni", turn, v).tolist()
    pointing = out["instrument_pointing"]
    p_times = np.asarray(pointing["ephemeris_times"], dtype=np.float64).reshape(-1)
    q = quaternion_to_matrix(np.asarray(pointing["quaternions"], dtype=np.float64)
                             .reshape(-1, 4)[:, [1, 2, 3, 0]])
    b = body.matrices_at(p_times)
    # the constant rotation C sits before the quaternion's matrix: Q = C M, so M' = M Bᵀ dRᵀ B
    m_new = q @ np.einsum("nji,kj,nkl->nil", b, d_r, b)
    quats = matrix_to_quaternion(m_new)
    pointing["quaternions"] = quats[:, [3, 0, 1, 2]].tolist()
    return out


_FLOAT = r"[-+0-9.eEinfa]+"


def adjust_tsai(text: str, offset: PoseOffset, *, source: str = "<tsai>") -> str:
    """The text of an ASP ``.tsai`` file with ``C`` and ``R`` moved by ``offset``
    (``C' = P + dR (C − P) + dC``, camera-to-world ``R' = dR R``)."""
    values = {}
    for key, size in (("C", 3), ("R", 9)):
        match = re.search(rf"^\s*{key}\s*=\s*((?:{_FLOAT}\s+){{{size - 1}}}{_FLOAT})\s*$",
                          text, flags=re.MULTILINE)
        if match is None:
            raise ProcessingError(f"{source}: no '{key} =' line with {size} numbers")
        values[key] = (match, np.array(match.group(1).split(), dtype=np.float64))
    centre = offset.from_original(values["C"][1])
    rotation = offset.matrix @ values["R"][1].reshape(3, 3)
    out = text
    for key, new in (("R", rotation.ravel()), ("C", centre)):
        match = values[key][0]
        line = f"{key} = " + " ".join(repr(float(v)) for v in new)
        out = out[:match.start()] + line + out[match.end():]
        if key == "R":  # C comes before R in the file: re-find it in the edited text
            values["C"] = (re.search(rf"^\s*C\s*=\s*((?:{_FLOAT}\s+){{2}}{_FLOAT})\s*$", out,
                                     flags=re.MULTILINE), values["C"][1])
    return out


def model_isd(model) -> dict[str, Any]:
    """The ISD of a frame or line-scan model read from a cube (or built in memory)."""
    try:
        return isd_from_sensor(model)
    except ValueError as exc:
        raise ProcessingError(f"{model.name}: {exc}") from None


def dumps_isd(isd: Mapping[str, Any]) -> str:
    """ISD JSON text (indented)."""
    return json.dumps(isd, indent=1)
