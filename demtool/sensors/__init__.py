"""Planetary sensor models: frame and line-scan cameras of the USGS Community Sensor
Model, pinholes, lens distortion, and the readers that build them.

Every model implements :class:`SensorModel` (image ↔ body-fixed ground, rays, sun);
:func:`read_sensor` reads any supported file into one.

Names are imported lazily (PEP 562, :func:`demtool.lazy.lazy_exports`): ``import
demtool.sensors`` loads no model, and :func:`read_sensor` loads only the module of the
kind of file it reads (an ISD line scanner never imports the RPC, ``.tsai`` or push-frame
code; ~0.03 CPU s of the ~0.25 s that importing every kind took, the rest being numpy,
which every model needs).
"""

from demtool.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "base": ("Detector", "Ray", "SensorModel", "lagrange_interp",
             "ray_ellipsoid_intersection"),
    "distortion": ("Distortion",),
    "frame": ("FrameSensor",),
    "isd": ("read_isd", "sensor_from_isd"),
    "linescan": ("LineScanSensor",),
    "pinhole": ("PinholeCamera",),
    "pushframe": ("PushFrameSensor",),
    "readers": ("read_sensor", "read_sensors"),
    "rpc": ("RpcSensor",),
    "rpc_files": ("read_rpc",),
    "tsai": ("TsaiCamera", "read_tsai"),
})
