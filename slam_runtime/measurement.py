"""Range-bearing measurement model of point landmarks seen from a sensor mounted on the vehicle.

Vectorised over any leading axes (particles x components): the vehicle pose
(..., 3), the mount (3,) and landmark positions (..., 2) give the predicted
measurement (..., 2) = (range, bearing) in the sensor frame and its Jacobian
with respect to the landmark position (..., 2, 2), as the EKF map update of
RB-PHD-SLAM needs (thesis eqs. 3.17-3.18).

A circular landmark is represented by its centre; the circle detector reports
the centre's range and bearing, so no radius term enters the model.
"""

from __future__ import annotations

import numpy as np

from detectors.geometry import compose


def sensor_pose(vehicle: np.ndarray, mount: np.ndarray) -> np.ndarray:
    """(..., 3) sensor poses from vehicle poses (..., 3) and the mount (3,) in the vehicle frame."""
    return compose(vehicle, mount)


def predict(sensor: np.ndarray, landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Predicted (range, bearing) (..., 2) and d(range, bearing)/d(landmark) (..., 2, 2).

    sensor (..., 3) and landmarks (..., 2) broadcast against each other.
    """
    dx = landmarks[..., 0] - sensor[..., 0]
    dy = landmarks[..., 1] - sensor[..., 1]
    q = np.maximum(dx * dx + dy * dy, 1e-12)
    r = np.sqrt(q)
    b = np.mod(np.arctan2(dy, dx) - sensor[..., 2] + np.pi, 2 * np.pi) - np.pi
    jac = np.stack([np.stack([dx / r, dy / r], axis=-1), np.stack([-dy / q, dx / q], axis=-1)], axis=-2)
    return np.stack([r, b], axis=-1), jac


def inverse(sensor: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Landmark positions (..., 2) from measurements z (..., 2) and d(landmark)/d(z) (..., 2, 2)."""
    a = sensor[..., 2] + z[..., 1]
    c, s = np.cos(a), np.sin(a)
    pos = np.stack([sensor[..., 0] + z[..., 0] * c, sensor[..., 1] + z[..., 0] * s], axis=-1)
    jac = np.stack([np.stack([c, -z[..., 0] * s], axis=-1), np.stack([s, z[..., 0] * c], axis=-1)], axis=-2)
    return pos, jac


def innovation(z: np.ndarray, zhat: np.ndarray) -> np.ndarray:
    """z - zhat with the bearing difference wrapped to (-pi, pi]."""
    d = z - zhat
    d[..., 1] = np.mod(d[..., 1] + np.pi, 2 * np.pi) - np.pi
    return d
