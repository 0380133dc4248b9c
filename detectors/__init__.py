"""Sensor data types, feature detectors and the runtime detection model.

Imports only ``profiles``.
"""

from detectors.sensor_log import (
    Detections,
    Landmarks,
    Mount,
    Odometry,
    PointClouds,
    ReferencePoses,
    ScanBatch,
    SensorLog,
    SensorModel,
    Vehicle,
)

__all__ = [
    "Detections",
    "Landmarks",
    "Mount",
    "Odometry",
    "PointClouds",
    "ReferencePoses",
    "ScanBatch",
    "SensorLog",
    "SensorModel",
    "Vehicle",
]
