"""Planetary sensor models: frame and line-scan cameras of the USGS Community Sensor
Model, pinholes, lens distortion, and the readers that build them.

Every model implements :class:`SensorModel` (image ↔ body-fixed ground, rays, sun);
:func:`read_sensor` reads any supported file into one.
"""

from demtool.sensors.base import (
                                  Detector,
                                  Ray,
                                  SensorModel,
                                  lagrange_interp,
                                  ray_ellipsoid_intersection,
)
from demtool.sensors.distortion import Distortion
from demtool.sensors.frame import FrameSensor
from demtool.sensors.isd import read_isd, sensor_from_isd
from demtool.sensors.linescan import LineScanSensor
from demtool.sensors.pinhole import PinholeCamera
from demtool.sensors.pushframe import PushFrameSensor
from demtool.sensors.readers import read_sensor, read_sensors
from demtool.sensors.rpc import RpcSensor
from demtool.sensors.rpc_files import read_rpc
from demtool.sensors.tsai import TsaiCamera, read_tsai

__all__ = ["Detector", "Distortion", "FrameSensor", "LineScanSensor", "PinholeCamera",
           "PushFrameSensor", "Ray", "RpcSensor", "SensorModel", "TsaiCamera", "lagrange_interp",
           "ray_ellipsoid_intersection",
           "read_isd", "read_rpc", "read_sensor", "read_sensors", "read_tsai", "sensor_from_isd"]
