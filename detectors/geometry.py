"""Vectorised 2D geometry: rigid transforms, ray-circle and ray-segment intersection.

All functions work on batches (beams x shapes) without Python loops; they are
the ray caster of the park simulator and the base of the n_p ray tracer.
"""

from __future__ import annotations

import numpy as np


def compose(a: np.ndarray, b: np.ndarray, *, cos=np.cos, sin=np.sin) -> np.ndarray:
    """Pose composition a (+) b for (..., 3) arrays (x, y, theta); b is expressed in a's frame. ``cos``, ``sin``: the
    trigonometry to use (the park simulator hands in libm's, the same on every CPU)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c, s = cos(a[..., 2]), sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    th = np.mod(a[..., 2] + b[..., 2] + np.pi, 2 * np.pi) - np.pi
    return np.stack([x, y, th], axis=-1)


def relative(a: np.ndarray, b: np.ndarray, *, cos=np.cos, sin=np.sin) -> np.ndarray:
    """Pose of b in the frame of a, (-)a (+) b, for (..., 3) arrays; ``cos``, ``sin`` as in :func:`compose`."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c, s = cos(a[..., 2]), sin(a[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    th = np.mod(b[..., 2] - a[..., 2] + np.pi, 2 * np.pi) - np.pi
    return np.stack([c * dx + s * dy, -s * dx + c * dy, th], axis=-1)


def increment_poses(inc: np.ndarray) -> np.ndarray:
    """(N, 3) running poses (x, y, theta) after each of N odometry increments (dx, dy, dtheta), each in the vehicle
    frame of the row before it, starting at the origin: all at once, the heading their running sum and each
    translation rotated by the heading before it (theta wrapped to [-pi, pi))."""
    th = np.cumsum(inc[:, 2])
    before = np.concatenate([[0.0], th[:-1]])
    c, s = np.cos(before), np.sin(before)
    x = np.cumsum(c * inc[:, 0] - s * inc[:, 1])
    y = np.cumsum(s * inc[:, 0] + c * inc[:, 1])
    return np.column_stack([x, y, np.mod(th + np.pi, 2 * np.pi) - np.pi])


def ray_circles(origin: np.ndarray, directions: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Distance along each ray to the first crossing of each circle.

    origin:     (2,) ray origin, world frame
    directions: (B, 2) unit directions
    centres:    (C, 2), radii: (C,)
    returns     (B, C) float64, ``inf`` where the ray misses (or the circle is behind)
    """
    m = np.asarray(centres, dtype=np.float64) - np.asarray(origin, dtype=np.float64)  # (C, 2)
    proj = directions @ m.T  # (B, C): distance of closest approach point along the ray
    d2 = np.einsum("ij,ij->i", m, m)[None, :] - proj * proj  # squared miss distance
    r2 = np.asarray(radii, dtype=np.float64)[None, :] ** 2
    h = np.sqrt(np.maximum(r2 - d2, 0.0))
    t = proj - h
    hit = (d2 <= r2) & (t > 0.0)
    return np.where(hit, t, np.inf)


def ray_segments(origin: np.ndarray, directions: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """Distance along each ray to each segment p0-p1.

    origin: (2,), directions: (B, 2) unit, p0/p1: (S, 2)
    returns (B, S) float64, ``inf`` where the ray misses
    """
    o = np.asarray(origin, dtype=np.float64)
    e = np.asarray(p1, dtype=np.float64) - p0  # (S, 2)
    w = np.asarray(p0, dtype=np.float64) - o  # (S, 2)
    dx, dy = directions[:, 0:1], directions[:, 1:2]  # (B, 1)
    denom = dx * e[None, :, 1] - dy * e[None, :, 0]  # cross(d, e)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[None, :, 0] * e[None, :, 1] - w[None, :, 1] * e[None, :, 0]) / denom  # cross(w, e)/cross(d, e)
        u = (w[None, :, 0] * dy - w[None, :, 1] * dx) / denom  # cross(w, d)/cross(d, e)
    hit = (np.abs(denom) > 1e-12) & (t > 0.0) & (u >= 0.0) & (u <= 1.0)
    return np.where(hit, t, np.inf)


def cast(
    pose: np.ndarray,
    angles: np.ndarray,
    centres: np.ndarray,
    radii: np.ndarray,
    p0: np.ndarray,
    p1: np.ndarray,
    max_range: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free 2D laser: nearest hit per beam among circles and segments.

    pose:   (3,) sensor pose, world frame
    angles: (B,) beam angles, sensor frame
    returns (ranges (B,) float64 with ``inf`` for no hit within ``max_range``,
             hit_id (B,) int64: index into circles, C + index into segments, or -1)
    """
    pose = np.asarray(pose, dtype=np.float64)
    a = pose[2] + np.asarray(angles, dtype=np.float64)
    dirs = np.column_stack([np.cos(a), np.sin(a)])
    origin = pose[:2]
    centres = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    radii = np.asarray(radii, dtype=np.float64).reshape(-1)
    # only shapes that can be reached matter: prune by distance first
    near_c = np.flatnonzero(np.hypot(*(centres - origin).T) - radii < max_range)
    p0 = np.asarray(p0, dtype=np.float64).reshape(-1, 2)
    p1 = np.asarray(p1, dtype=np.float64).reshape(-1, 2)
    near_s = np.flatnonzero(np.minimum(np.hypot(*(p0 - origin).T), np.hypot(*(p1 - origin).T)) < max_range + np.hypot(*(p1 - p0).T))
    d = np.concatenate(
        [ray_circles(origin, dirs, centres[near_c], radii[near_c]), ray_segments(origin, dirs, p0[near_s], p1[near_s])], axis=1
    )
    ids = np.concatenate([near_c, centres.shape[0] + near_s])
    if d.shape[1] == 0:
        return np.full(a.size, np.inf), np.full(a.size, -1, dtype=np.int64)
    k = np.argmin(d, axis=1)
    r = d[np.arange(a.size), k]
    hit = r <= max_range
    return np.where(hit, r, np.inf), np.where(hit, ids[k], -1)


def interpolate_poses(stamp_ref: np.ndarray, poses_ref: np.ndarray, stamps: np.ndarray) -> np.ndarray:
    """Poses (M, 3) at ``stamps`` by linear interpolation of x, y and the unwrapped heading.

    stamp_ref (K,) int64 ns sorted; poses_ref (K, 3); stamps outside the range are clamped to the ends.
    """
    t = np.asarray(stamp_ref, dtype=np.float64)
    q = np.asarray(stamps, dtype=np.float64)
    th = np.unwrap(poses_ref[:, 2])
    out = np.column_stack([np.interp(q, t, poses_ref[:, 0]), np.interp(q, t, poses_ref[:, 1]), np.interp(q, t, th)])
    out[:, 2] = np.mod(out[:, 2] + np.pi, 2 * np.pi) - np.pi
    return out


def rigid_transform(est: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """(3,) pose T of the best-fit rotation + translation (Umeyama, no scale): compose(T, est) ~ ref.

    est, ref (N, 2+): only the positions are used.
    """
    a, b = est[:, :2], ref[:, :2]
    ma, mb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((b - mb).T @ (a - ma))
    r = u @ np.diag([1.0, np.linalg.det(u @ vt)]) @ vt
    ang = np.arctan2(r[1, 0], r[0, 0])
    return np.array([*(mb - r @ ma), ang])


def rigid_align(est: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """est's poses (N, 3) moved by the best rigid fit onto ref (:func:`rigid_transform`)."""
    return compose(rigid_transform(est, ref), est)
