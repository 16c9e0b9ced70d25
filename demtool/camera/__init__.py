"""The ``camera`` stage: what a sensor model sees (footprint, GSD, geometry report).

:mod:`~demtool.camera.params` (``CameraParams``), :mod:`~demtool.camera.info` (the pure
core: footprint polygon, ground sample distance, viewing geometry from any
:class:`~demtool.sensors.SensorModel`), :mod:`~demtool.camera.run` (``run_camera``:
files in, report out).  The command is :mod:`demtool.commands.camera`.
"""
