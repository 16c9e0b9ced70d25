"""Readers of JPL's CAHV / CAHVOR / CAHVORE camera models (:mod:`demtool.sensors.cahvor`).

* ASP's and JPL's text files (``.cahv``, ``.cahvor``, ``.cahvore``): ``KEY = numbers``
  lines, as VisionWorkbench's ``CAHVORModel`` / ``CAHVOREModel`` constructors read them
  (``src/vw/Camera/CAHVOREModel.cc``: C A H V O R E T P, T = 1 perspective, 2 fish-eye,
  3 general with linearity P) and JPL's ``cmod_cahvor_write`` writes them (with
  ``Model``, ``Dimensions``, the covariance ``S`` and ``Hs Hc Vs Vc Theta``);
* the ``GEOMETRIC_CAMERA_MODEL`` (MER) / ``GEOMETRIC_CAMERA_MODEL_PARMS`` (MSL, Mars
  2020) group of a PDS3 label: ``MODEL_TYPE`` and ``MODEL_COMPONENT_1`` … ``_9`` in the
  order of ``MODEL_COMPONENT_ID``, the frame in ``REFERENCE_COORD_SYSTEM_NAME``.
"""

from __future__ import annotations

import numpy as np

from demtool.sensors.cahvor import CahvoreCamera

_TEXT_KEYS = {"C": 3, "A": 3, "H": 3, "V": 3, "O": 3, "R": 3, "E": 3, "T": 1, "P": 1,
              "DIMENSIONS": 2}
#: frames of MSL / Mars 2020 / MER labels that are local to the rover or its site
LOCAL_FRAMES = ("ROVER", "SITE", "LOCAL_LEVEL", "RSM", "ARM", "RMECH", "NAV")


def _fail(path, message: str):
    from demtool.errors import InputError

    return InputError(f"{path}: {message}")


def build_cahvore(values: dict, path, *, width: int = 0, height: int = 0,
                  radii=None, name: str = "") -> CahvoreCamera:
    """A checked :class:`CahvoreCamera` from its components (C, A, H, V; O and R for
    CAHVOR; E, T (1 perspective, 2 fish-eye, 3 general) and P for CAHVORE).

    Raises
    ------
    InputError
        One line naming ``path`` and the component: missing, not finite, or a geometry
        no camera has (A or O of no length, H or V along A, O more than 90° off A, a
        linearity outside −1 … 1, an unknown T).
    """
    for key in ("C", "A", "H", "V"):
        if key not in values:
            raise _fail(path, f"the camera model lacks the component '{key}'")
    kind = "cahvore" if "E" in values else "cahvor" if "O" in values or "R" in values \
        else "cahv"
    if kind != "cahv" and ("O" not in values or "R" not in values):
        raise _fail(path, f"the {kind.upper()} model lacks the component "
                          f"'{'O' if 'O' not in values else 'R'}'")
    for key, value in values.items():
        if not np.all(np.isfinite(np.asarray(value, dtype=np.float64))):
            raise _fail(path, f"the component '{key}' is not finite ({value})")
    A = np.asarray(values["A"], dtype=np.float64)
    O = np.asarray(values.get("O", A), dtype=np.float64)  # noqa: E741
    for key, vector in (("A", A), ("O", O)):
        if not np.linalg.norm(vector) > 0:
            raise _fail(path, f"the component '{key}' has no length")
    a = A / np.linalg.norm(A)
    for key in ("H", "V"):
        vector = np.asarray(values[key], dtype=np.float64)
        if not np.linalg.norm(np.cross(a, vector)) > 1e-9 * np.linalg.norm(vector):
            raise _fail(path, f"the component '{key}' is parallel to A: no image axis")
    if not O @ a > 0:
        raise _fail(path, "the optical axis O points more than 90° away from the axis A")
    linearity = 1.0
    if kind == "cahvore":
        mtype = int(round(float(np.ravel(values.get("T", [np.nan]))[0]))) \
            if "T" in values else None
        if mtype == 1:
            linearity = 1.0
        elif mtype == 2:
            linearity = 0.0
        elif mtype == 3:
            if "P" not in values:
                raise _fail(path, "a CAHVORE model of type T = 3 lacks its linearity 'P'")
            linearity = float(np.ravel(values["P"])[0])
            if not -1.0 <= linearity <= 1.0:
                raise _fail(path, f"the CAHVORE linearity P = {linearity:g} is outside "
                                  "-1 ... 1")
        else:
            shown = "missing" if "T" not in values else f"{float(np.ravel(values['T'])[0]):g}"
            raise _fail(path, f"the CAHVORE type T = {shown} is not 1 "
                              "(perspective), 2 (fish-eye) or 3 (general)")
    return CahvoreCamera(C=values["C"], A=A, H=values["H"], V=values["V"], O=O,
                         R=values.get("R", np.zeros(3)), E=values.get("E", np.zeros(3)),
                         linearity=linearity, width=width, height=height,
                         body_radii=None if radii is None else (float(radii[0]),
                                                                float(radii[1])),
                         name=name, model_name=kind)


def parse_cahvor_text(text: str, path="<cahvor>") -> dict:
    """Components of an ASP / JPL ``.cahvor`` / ``.cahvore`` file: ``KEY = numbers`` lines
    (VisionWorkbench ``CAHVORModel``/``CAHVOREModel`` read C A H V O R [E T P]; JPL's
    ``cmod_cahvor_write`` adds ``Model``, ``Dimensions``, the covariance ``S`` and the
    derived ``Hs Hc Vs Vc Theta``, which are read (Dimensions) or skipped).  Comments
    after ``#`` are ignored."""
    values: dict[str, np.ndarray] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if "=" not in line:
            continue
        key, _, rest = (part.strip() for part in line.partition("="))
        key = key.upper()
        if key not in _TEXT_KEYS or key in values:
            continue
        try:
            numbers = np.array([float(v) for v in rest.replace(",", " ").split()])
        except ValueError:
            raise _fail(path, f"line {number}: '{key}' has a non-numeric value "
                              f"({rest!r})") from None
        if numbers.size != _TEXT_KEYS[key]:
            raise _fail(path, f"line {number}: '{key}' needs {_TEXT_KEYS[key]} numbers, got "
                              f"{rest!r}")
        values[key] = numbers
    return values


def read_cahvor(path, *, radii=None) -> CahvoreCamera:
    """Read an ASP / JPL ``.cahv``, ``.cahvor`` or ``.cahvore`` text file.

    ``radii`` (metres) names the body when the vectors are body-fixed; without it the
    frame is local (a rover's or a site's).  The image size comes from ``Dimensions``
    (JPL) or, when absent, from the image (``rectify``)."""
    from pathlib import Path

    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8", errors="strict")
    except OSError as exc:
        raise _fail(p, f"cannot read the camera model ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise _fail(p, "not a text CAHVOR file") from None
    values = parse_cahvor_text(text, p)
    size = values.pop("DIMENSIONS", np.zeros(2))
    return build_cahvore(values, p, width=int(size[0]), height=int(size[1]), radii=radii,
                         name=p.stem)


def _pvl_value(text: str):
    """Numbers of a PVL value: ``1.5``, ``(1, 2, 3)``, ``"2"``, ``1.0 <m>``."""
    import re

    body = re.sub(r"<[^>]*>", " ", text).replace("(", " ").replace(")", " ")
    body = body.replace(",", " ").replace('"', " ").replace("'", " ")
    return np.array([float(v) for v in body.split()], dtype=np.float64)


def read_pds3_cahvor(path, *, radii=None, text: str | None = None) -> CahvoreCamera:
    """Read the ``GEOMETRIC_CAMERA_MODEL`` (``_PARMS``) group of a PDS3 label (MER, MSL,
    Mars 2020 EDRs and RDRs: ``MODEL_TYPE``, ``MODEL_COMPONENT_1`` … ``_9`` in the order of
    ``MODEL_COMPONENT_ID``, C A H V O R E T P; the size from the IMAGE object's ``LINES``
    and ``LINE_SAMPLES``).  ``REFERENCE_COORD_SYSTEM_NAME`` says the frame (a rover's or a
    site's: local)."""
    import re
    from pathlib import Path

    p = Path(path)
    if text is None:
        try:
            with open(p, "rb") as handle:
                text = handle.read(400_000).decode("latin-1")
        except OSError as exc:
            raise _fail(p, f"cannot read the label ({exc.strerror or exc})") from None
    label = text.split("\nEND\n", 1)[0] if "\nEND\n" in text else text
    group = re.search(r"GROUP\s*=\s*(GEOMETRIC_CAMERA_MODEL\w*)(.*?)END_GROUP\s*=\s*\1",
                      label, re.S)
    if group is None:
        raise _fail(p, "the PDS3 label has no GEOMETRIC_CAMERA_MODEL group")
    body = group.group(2)
    entries = dict(re.findall(r"^\s*([A-Z_0-9^]+)\s*=\s*((?:\([^)]*\))|[^\n]*)", body, re.M))
    model_type = entries.get("MODEL_TYPE", "").strip().strip('"').upper()
    if model_type not in ("CAHV", "CAHVOR", "CAHVORE"):
        raise _fail(p, f"the camera model is {model_type or 'of no MODEL_TYPE'}, not CAHV, "
                       "CAHVOR or CAHVORE")
    ids = ["C", "A", "H", "V", "O", "R", "E", "T", "P"]
    if "MODEL_COMPONENT_ID" in entries:
        ids = [v.strip().strip('"').upper() for v in
               entries["MODEL_COMPONENT_ID"].strip("() \n").split(",")]
    values = {}
    for index, key in enumerate(ids, start=1):
        raw = entries.get(f"MODEL_COMPONENT_{index}")
        if raw is None:
            continue
        try:
            values[key] = _pvl_value(raw)
        except ValueError:
            raise _fail(p, f"MODEL_COMPONENT_{index} ({key}) is not numeric: "
                           f"{raw.strip()!r}") from None
        if values[key].size != _TEXT_KEYS.get(key, values[key].size):
            raise _fail(p, f"MODEL_COMPONENT_{index} ({key}) needs {_TEXT_KEYS[key]} "
                           f"numbers, got {raw.strip()!r}")
    if model_type == "CAHV":
        values.pop("O", None), values.pop("R", None)
    if model_type != "CAHVORE":
        values.pop("E", None)
    image = re.search(r"OBJECT\s*=\s*IMAGE\b(.*?)END_OBJECT", label, re.S)
    width = height = 0
    if image is not None:
        lines = re.search(r"^\s*LINES\s*=\s*(\d+)", image.group(1), re.M)
        samples = re.search(r"^\s*LINE_SAMPLES\s*=\s*(\d+)", image.group(1), re.M)
        height = int(lines.group(1)) if lines else 0
        width = int(samples.group(1)) if samples else 0
    frame = entries.get("REFERENCE_COORD_SYSTEM_NAME", "").strip().strip('"').upper()
    if radii is None and frame and not any(word in frame for word in LOCAL_FRAMES):
        raise _fail(p, f"the camera model is in the frame {frame}, neither a rover's nor a "
                       "site's; give the body (its radii) if the frame is body-fixed")
    model = build_cahvore(values, p, width=width, height=height, radii=radii, name=p.stem)
    if model.model_name != model_type.lower():
        raise _fail(p, f"MODEL_TYPE is {model_type} but the components make a "
                       f"{model.model_name.upper()} model")
    return model


def cahvor_text(model: CahvoreCamera) -> str:
    """The model as VisionWorkbench's ``CAHVORModel::write`` / ``CAHVOREModel::write`` write
    it (``KEY = numbers`` lines; T = 1 perspective, 2 fish-eye, 3 general with P), plus
    JPL's ``Dimensions`` line when the size is known."""
    def line(key, vector):
        return f"{key} = " + " ".join(f"{float(v):.17g}" for v in np.ravel(vector)) + "\n"

    text = "" if not model.width else f"Dimensions = {model.width} {model.height}\n"
    for key in ("C", "A", "H", "V") + (("O", "R") if model.model_name != "cahv" else ()):
        text += line(key, getattr(model, key))
    if model.model_name == "cahvore":
        mtype = 1 if model.linearity == 1.0 else 2 if model.linearity == 0.0 else 3
        text += line("E", model.E) + f"T = {mtype}\n" + line("P", model.linearity)
    return text
