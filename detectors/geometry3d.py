"""Planes in 3D: Hesse form, the azimuth-elevation chart, pose matrices and frame changes.

Source: Gostar et al., *State Transition for Statistical SLAM Using Planar
Features in 3D Point Clouds*, Sensors 2019 (seeds 000/001).

* A plane is ``n . p = d`` with a unit normal n (3,) and an offset d [m]
  (Hesse form). The paper writes it ``beta^T r = 0`` with ``beta = (a, b, c, d')``
  and ``r = (x, y, z, 1)`` (eqs. 23-24); here ``beta = (n, -d)``.
* The chart used by the filters is ``x = (theta, phi, d)``: the normal's
  azimuth theta (wrapped to (-pi, pi]) and elevation phi (radians),
  ``n = (cos phi cos theta, cos phi sin theta, sin phi)``, and the offset d.
  It is singular only for horizontal planes (|phi| = pi / 2), which carry no
  information about a planar pose anyway (the ground stays the ground).
* A planar vehicle pose (x, y, yaw) is the 4 x 4 matrix R of eq. 28, mapping
  vehicle coordinates to world coordinates, ``r_P = R r`` (eq. 25-27); a sensor
  mounted at (mx, my, mtheta) and height h has ``R_s = R_vehicle T_mount``.
* A plane seen from a frame of pose matrix R has ``beta_frame^T = beta_world^T R``
  (from ``beta_world^T r_P = 0`` and ``r_P = R r``); between two frames this
  is the plane transition of eq. 35, ``beta_{k+1}^T = beta_k^T R_k^{-1} R_{k+1}``.
* In the sensor frame a measured plane's normal points away from the sensor,
  so its offset is positive: the distance from the sensor to the plane.

Everything is vectorised over leading axes.
"""

from __future__ import annotations

import numpy as np


def wrap(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to (-pi, pi]."""
    w = np.mod(np.asarray(a, dtype=np.float64) + np.pi, 2.0 * np.pi) - np.pi
    return np.where(w == -np.pi, np.pi, w)


def pose_matrix(poses: np.ndarray, z: float | np.ndarray = 0.0) -> np.ndarray:
    """Eq. 28: (..., 4, 4) homogeneous transforms of planar poses (..., 3) (x, y, yaw) at height z.

    Maps coordinates in the posed frame to the world frame: ``r_world = R @ r_frame``.
    """
    p = np.asarray(poses, dtype=np.float64)
    c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
    out = np.zeros(p.shape[:-1] + (4, 4))
    out[..., 0, 0], out[..., 0, 1], out[..., 0, 3] = c, -s, p[..., 0]
    out[..., 1, 0], out[..., 1, 1], out[..., 1, 3] = s, c, p[..., 1]
    out[..., 2, 2] = 1.0
    out[..., 2, 3] = z
    out[..., 3, 3] = 1.0
    return out


def pose_matrix_inverse(poses: np.ndarray, z: float | np.ndarray = 0.0) -> np.ndarray:
    """(..., 4, 4) the inverse of :func:`pose_matrix` in closed form (R^T, -R^T t)."""
    p = np.asarray(poses, dtype=np.float64)
    c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
    out = np.zeros(p.shape[:-1] + (4, 4))
    out[..., 0, 0], out[..., 0, 1] = c, s
    out[..., 1, 0], out[..., 1, 1] = -s, c
    out[..., 0, 3] = -(c * p[..., 0] + s * p[..., 1])
    out[..., 1, 3] = s * p[..., 0] - c * p[..., 1]
    out[..., 2, 2] = 1.0
    out[..., 2, 3] = -np.asarray(z, dtype=np.float64)
    out[..., 3, 3] = 1.0
    return out


def beta_from_hesse(n: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(..., 4) the paper's beta = (a, b, c, d') (eq. 24) of planes n . p = d."""
    return np.concatenate([np.asarray(n, dtype=np.float64), -np.asarray(d, dtype=np.float64)[..., None]], axis=-1)


def hesse_from_beta(beta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n (..., 3), d (...)) of planes beta (..., 4), the normal scaled to unit length."""
    beta = np.asarray(beta, dtype=np.float64)
    norm = np.linalg.norm(beta[..., :3], axis=-1)
    norm = np.where(norm > 0, norm, 1.0)
    return beta[..., :3] / norm[..., None], -beta[..., 3] / norm


def transform_beta(beta: np.ndarray, m: np.ndarray) -> np.ndarray:
    """beta'^T = beta^T M for planes (..., 4) and matrices (..., 4, 4) (eq. 35 with M = R_k^-1 R_{k+1})."""
    return np.einsum("...i,...ij->...j", beta, m)


def normal_from_chart(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n (..., 3), d (...)) of chart points x (..., 3) = (theta, phi, d)."""
    x = np.asarray(x, dtype=np.float64)
    th, ph = x[..., 0], x[..., 1]
    cp = np.cos(ph)
    return np.stack([cp * np.cos(th), cp * np.sin(th), np.sin(ph)], axis=-1), x[..., 2]


def chart_from_normal(n: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(..., 3) chart (theta, phi, d) of planes n . p = d (n need not be unit)."""
    n = np.asarray(n, dtype=np.float64)
    norm = np.linalg.norm(n, axis=-1)
    norm = np.where(norm > 0, norm, 1.0)
    u = n / norm[..., None]
    th = np.arctan2(u[..., 1], u[..., 0])
    ph = np.arcsin(np.clip(u[..., 2], -1.0, 1.0))
    return np.stack([th, ph, np.asarray(d, dtype=np.float64) / norm], axis=-1)


def normal_jacobian(x: np.ndarray) -> np.ndarray:
    """(..., 3, 2) dn / d(theta, phi) at chart points x (..., 3)."""
    x = np.asarray(x, dtype=np.float64)
    th, ph = x[..., 0], x[..., 1]
    ct, st, cp, sp = np.cos(th), np.sin(th), np.cos(ph), np.sin(ph)
    j = np.zeros(x.shape[:-1] + (3, 2))
    j[..., 0, 0], j[..., 1, 0] = -cp * st, cp * ct
    j[..., 0, 1], j[..., 1, 1], j[..., 2, 1] = -sp * ct, -sp * st, cp
    return j


def orient_away(n: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Planes (n, d) flipped where needed so that d >= 0 (normal pointing away from the frame's origin)."""
    n = np.asarray(n, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    sgn = np.where(d < 0, -1.0, 1.0)
    return n * sgn[..., None], d * sgn


def world_to_sensor(x: np.ndarray, sensor: np.ndarray, height: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Planes in the world chart x (..., 3) seen from planar sensor poses (..., 3) at ``height``.

    Returns z (..., 3): the sensor-frame chart (theta - yaw, phi, d - n . t) with
    t = (x_s, y_s, height) the sensor's position, and H (..., 3, 3) = dz/dx.
    This is ``beta_sensor^T = beta_world^T R_s`` (eqs. 28, 35) written in the chart.
    """
    x = np.asarray(x, dtype=np.float64)
    s = np.asarray(sensor, dtype=np.float64)
    shape = np.broadcast_shapes(x.shape[:-1], s.shape[:-1]) + (3,)
    x, s = np.broadcast_to(x, shape), np.broadcast_to(s, shape)
    n, d = normal_from_chart(x)
    t0, t1 = s[..., 0], s[..., 1]
    off = d - (n[..., 0] * t0 + n[..., 1] * t1 + n[..., 2] * height)
    z = np.stack([wrap(x[..., 0] - s[..., 2]), x[..., 1], off], axis=-1)
    jn = normal_jacobian(x)  # (..., 3, 2)
    h = np.zeros(z.shape + (3,))
    h[..., 0, 0] = 1.0
    h[..., 1, 1] = 1.0
    h[..., 2, 0] = -(jn[..., 0, 0] * t0 + jn[..., 1, 0] * t1 + jn[..., 2, 0] * height)
    h[..., 2, 1] = -(jn[..., 0, 1] * t0 + jn[..., 1, 1] * t1 + jn[..., 2, 1] * height)
    h[..., 2, 2] = 1.0
    return z, h


def sensor_to_world(z: np.ndarray, sensor: np.ndarray, height: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`world_to_sensor`: world chart x (..., 3) of sensor-frame planes z and G = dx/dz (..., 3, 3)."""
    z = np.asarray(z, dtype=np.float64)
    s = np.asarray(sensor, dtype=np.float64)
    shape = np.broadcast_shapes(z.shape[:-1], s.shape[:-1]) + (3,)
    z, s = np.broadcast_to(z, shape), np.broadcast_to(s, shape)
    x_ang = np.stack([wrap(z[..., 0] + s[..., 2]), z[..., 1]], axis=-1)
    xa = np.concatenate([x_ang, np.zeros(z.shape[:-1] + (1,))], axis=-1)
    n, _ = normal_from_chart(xa)
    t0, t1 = s[..., 0], s[..., 1]
    d = z[..., 2] + n[..., 0] * t0 + n[..., 1] * t1 + n[..., 2] * height
    x = np.concatenate([x_ang, d[..., None]], axis=-1)
    jn = normal_jacobian(x)
    g = np.zeros(z.shape + (3,))
    g[..., 0, 0] = 1.0
    g[..., 1, 1] = 1.0
    g[..., 2, 0] = jn[..., 0, 0] * t0 + jn[..., 1, 0] * t1 + jn[..., 2, 0] * height
    g[..., 2, 1] = jn[..., 0, 1] * t0 + jn[..., 1, 1] * t1 + jn[..., 2, 1] * height
    g[..., 2, 2] = 1.0
    return x, g


def normal_angle(n1: np.ndarray, n2: np.ndarray, *, unsigned: bool = True) -> np.ndarray:
    """Angle [rad] between normals (..., 3); ``unsigned``: a plane's two normals count as one (in [0, pi/2])."""
    n1 = np.asarray(n1, dtype=np.float64)
    n2 = np.asarray(n2, dtype=np.float64)
    c = (n1 * n2).sum(axis=-1) / np.maximum(np.linalg.norm(n1, axis=-1) * np.linalg.norm(n2, axis=-1), 1e-300)
    if unsigned:
        c = np.abs(c)
    return np.arccos(np.clip(c, -1.0, 1.0))


def plane_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (..., 3) spanning each plane: u horizontal (n x z, or x for horizontal planes), v = n x u."""
    n = np.asarray(n, dtype=np.float64)
    u = np.stack([-n[..., 1], n[..., 0], np.zeros(n.shape[:-1])], axis=-1)
    norm = np.linalg.norm(u, axis=-1)
    flat = norm < 1e-9
    u = np.where(flat[..., None], np.array([1.0, 0.0, 0.0]), u / np.where(flat, 1.0, norm)[..., None])
    v = np.cross(n, u)
    return u, v


def transform_points(points: np.ndarray, m: np.ndarray) -> np.ndarray:
    """(..., N, 3) points mapped by homogeneous matrices (..., 4, 4)."""
    p = np.asarray(points, dtype=np.float64)
    return p @ np.swapaxes(m[..., :3, :3], -1, -2) + m[..., None, :3, 3]


def min_area_rectangle(v2: np.ndarray) -> np.ndarray:
    """(4, 2) corners of the smallest rectangle enclosing a convex polygon (V, 2), counter-clockwise.

    Rotating calipers over the hull's edge directions (one of them is a side of
    the optimum), all edges at once.
    """
    v2 = np.asarray(v2, dtype=np.float64)
    if v2.shape[0] < 3:
        lo, hi = v2.min(axis=0), v2.max(axis=0)
        return np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    e = np.roll(v2, -1, axis=0) - v2
    ang = np.arctan2(e[:, 1], e[:, 0])
    c, s = np.cos(ang), np.sin(ang)
    # coordinates of every vertex in every edge's frame: (E, V)
    a = c[:, None] * v2[None, :, 0] + s[:, None] * v2[None, :, 1]
    b = -s[:, None] * v2[None, :, 0] + c[:, None] * v2[None, :, 1]
    area = (a.max(1) - a.min(1)) * (b.max(1) - b.min(1))
    k = int(np.argmin(area))
    a0, a1, b0, b1 = a[k].min(), a[k].max(), b[k].min(), b[k].max()
    loc = np.array([[a0, b0], [a1, b0], [a1, b1], [a0, b1]])
    return np.column_stack([c[k] * loc[:, 0] - s[k] * loc[:, 1], s[k] * loc[:, 0] + c[k] * loc[:, 1]])
