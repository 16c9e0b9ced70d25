"""The one entry point for ISIS3 camera cubes: :func:`read_isis_cube` dispatches a cube
with SPICE attached to the reader of its ISIS camera class, after the one-line
refusals of cubes no camera can be built from
(:func:`demtool.sensors.isis_kinds.refuse_unread_kinds`)."""

from __future__ import annotations

from pathlib import Path


def read_isis_cube(path: str | Path):
    """Any ISIS3 camera cube with attached SPICE, by its ISIS camera class
    (:func:`demtool.sensors.isis_kinds.camera_kind`): a line-scan cube as
    :func:`~demtool.sensors.isis_linescan.read_linescan_cube`, a push-frame cube as
    :func:`demtool.sensors.isis_pushframe.read_pushframe_cube`, a frame camera through
    :func:`demtool.sensors.isis.read_cube`; cubes no camera can be built from are refused
    first with their reason (:func:`demtool.sensors.isis_kinds.refuse_unread_kinds`)."""
    from demtool.sensors.isis import read_cube
    from demtool.sensors.isis_kinds import camera_kind, refuse_unread_kinds
    from demtool.sensors.isis_label import read_label
    from demtool.sensors.isis_linescan import read_linescan_cube

    p = Path(path)
    label, data = read_label(p)
    refuse_unread_kinds(p, label)
    kind = camera_kind(label)
    if kind == "linescan":
        return read_linescan_cube(p, label, data)
    if kind == "pushframe":
        from demtool.sensors.isis_pushframe import read_pushframe_cube

        return read_pushframe_cube(p, label, data)
    return read_cube(p)
