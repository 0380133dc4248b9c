"""Ray tracing of unoccluded points n_p (Inostroza 2015, sec. 4.1, fig. 4.2; ch. 6).

For a sensor pose, circular landmarks and the measured scan: the beams that
would hit each landmark if nothing were in the way (expected range finite and
within the sensor's range), and which of them are occluded -- the measured
range is shorter than expected by more than ``k_sigma * sigma_r``. A missing
return (NaN) is not an occlusion: nothing was in front. n_p is the number of
expected hits that are not occluded; it is the covariate of P_D (eq. 4.1, 6.1).

Everything is vectorised over landmarks x beams (and chunked over scans); the
same code gives the P_D field over a grid of hypothetical landmarks (fig. 6.1)
and the buffer-zone rules of sec. 6.1.
"""

from __future__ import annotations

import numpy as np


#: Scans x beams x landmarks handled per numpy call (bounds memory at ~100 MB).
_CHUNK = 4_000_000


def count_unoccluded(
    sensor_poses: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    centres: np.ndarray,
    radii: np.ndarray,
    *,
    range_sigma: float,
    k_sigma: float = 3.0,
    range_max: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """n_p and the number of expected hits for every (scan, landmark) pair.

    sensor_poses (S, 3) world frame; angles (B,) sensor frame, or (S, B) one row
    per scan for a laser of several beam layouts (NaN past a scan's own beams:
    no beam there, see :meth:`detectors.sensor_log.SensorLog.scan_angles`);
    ranges (S, B) measured, NaN = no return (a (B,) scan is shared by all poses);
    centres (L, 2) world frame, shared by all poses, or (S, L, 2): one set per pose
    (the maps of a particle filter); radii (L,) or scalar.
    returns (n_p (S, L) int32, n_expected (S, L) int32)
    """
    poses = np.atleast_2d(np.asarray(sensor_poses, dtype=np.float64))
    angles = np.asarray(angles, dtype=np.float64)
    meas = np.asarray(ranges, dtype=np.float64)
    if meas.ndim == 1 or meas.shape[0] == 1:  # one scan shared by all poses
        meas = np.broadcast_to(meas.reshape(-1), (poses.shape[0], meas.shape[-1]))
    centres = np.asarray(centres, dtype=np.float64)
    per_pose = centres.ndim == 3
    centres = centres if per_pose else centres.reshape(-1, 2)
    l_ = centres.shape[-2]
    radii = np.broadcast_to(np.asarray(radii, dtype=np.float64), (l_,))
    s, b = poses.shape[0], angles.shape[-1]
    per_scan_angles = angles.ndim == 2
    n_p = np.zeros((s, l_), dtype=np.int32)
    n_exp = np.zeros((s, l_), dtype=np.int32)
    if s == 0 or l_ == 0:
        return n_p, n_exp
    rmax = np.inf if range_max is None else float(range_max)
    tol = k_sigma * range_sigma
    occludes = bool(np.isfinite(tol))  # an infinite tolerance: no return occludes (and exp - tol would be NaN)
    step = max(1, _CHUNK // max(1, b * l_))
    for a in range(0, s, step):  # chunks of scans; inside, all beams x landmarks at once
        sl = slice(a, min(s, a + step))
        exp = expected_ranges(poses[sl], angles[sl] if per_scan_angles else angles, centres[sl] if per_pose else centres, radii)  # (s', B, L)
        hit = np.isfinite(exp) & (exp <= rmax)
        n_exp[sl] = hit.sum(axis=1)
        # NaN compares False: a missing return does not occlude; with no occluding return every expected beam counts
        n_p[sl] = (hit & ~(meas[sl, :, None] < exp - tol)).sum(axis=1) if occludes else n_exp[sl]
    return n_p, n_exp


def expected_ranges(sensor_poses: np.ndarray, angles: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(S, B, L) range at which each beam would first cross each circle (inf where it misses).

    angles (B,) shared or (S, B) per pose (a NaN angle is no beam: inf);
    centres (L, 2) shared by all poses or (S, L, 2) one set per pose.
    """
    poses = np.atleast_2d(sensor_poses)
    angles = np.asarray(angles, dtype=np.float64)
    a = poses[:, 2:3] + (angles if angles.ndim == 2 else angles[None, :])  # (S, B) world beam angles
    dirs = np.stack([np.cos(a), np.sin(a)], axis=-1)  # (S, B, 2)
    m = (centres if centres.ndim == 3 else centres[None, :, :]) - poses[:, None, :2]  # (S, L, 2)
    proj = np.einsum("sbk,slk->sbl", dirs, m)  # along-beam distance of the closest approach
    d2 = np.einsum("slk,slk->sl", m, m)[:, None, :] - proj * proj
    r2 = (radii * radii)[None, None, :]
    t = proj - np.sqrt(np.maximum(r2 - d2, 0.0))
    return np.where((d2 <= r2) & (t > 0.0), t, np.inf)


def pd_grid(
    sensor_pose: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    xs: np.ndarray,
    ys: np.ndarray,
    radius: float,
    pd_of_np,
    *,
    range_sigma: float,
    k_sigma: float = 3.0,
    range_max: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """P_D field of hypothetical landmarks of ``radius`` on the grid xs x ys (world frame; fig. 6.1).

    returns (pd (len(ys), len(xs)), n_p (len(ys), len(xs)))
    """
    gx, gy = np.meshgrid(xs, ys)
    centres = np.column_stack([gx.ravel(), gy.ravel()])
    n_p, _ = count_unoccluded(
        np.asarray(sensor_pose)[None], angles, np.asarray(ranges)[None], centres, radius,
        range_sigma=range_sigma, k_sigma=k_sigma, range_max=range_max,
    )
    n_p = n_p[0].reshape(gx.shape)
    return pd_of_np(n_p), n_p


def buffer_zone(
    sensor_poses: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    centres: np.ndarray,
    radii: np.ndarray,
    lateral: np.ndarray,
    pd_of_np,
    *,
    samples: int = 5,
    range_sigma: float,
    k_sigma: float = 3.0,
    range_max: float | None = None,
    phase_average: bool = False,
    occlusion_radius: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """P_D with the buffer-zone rules of thesis sec. 6.1.

    One pose: sensor_poses (3,), centres (L, 2), lateral (L,) -> (L,) outputs.
    Many poses: sensor_poses (S, 3), centres (S, L, 2) (one set per pose, e.g. the
    maps of a particle filter), lateral (S, L), ranges (B,) or (S, B) -> (S, L).

    P_D is evaluated at ``samples`` (odd) positions spread over +-``lateral`` [m]
    perpendicular to the sensor-landmark line. A landmark is in the buffer zone
    when those values contain both zeros and non-zeros (then the largest is
    used) or when 0 < P_D < 0.5 at the landmark itself.
    phase_average: P_D from :func:`expected_unoccluded` / :func:`expected_pd`
    (a filter's choice) instead of the integer n_p; ``radii`` is then one number
    and ``occlusion_radius`` is passed on.
    returns (pd, in_buffer bool)
    """
    if samples < 1 or samples % 2 == 0:
        raise ValueError(f"samples: expected an odd number >= 1, got {samples}")
    single = np.asarray(sensor_poses).ndim == 1
    poses = np.atleast_2d(np.asarray(sensor_poses, dtype=np.float64))
    centres = np.asarray(centres, dtype=np.float64).reshape(poses.shape[0] if not single else 1, -1, 2)
    s_, n = centres.shape[:2]
    radii = np.broadcast_to(np.asarray(radii, dtype=np.float64), (n,))
    lateral = np.broadcast_to(np.asarray(lateral, dtype=np.float64), (s_, n))
    los = centres - poses[:, None, :2]
    perp = np.stack([-los[..., 1], los[..., 0]], axis=-1) / np.maximum(np.hypot(los[..., 0], los[..., 1]), 1e-12)[..., None]
    t = np.linspace(-1.0, 1.0, samples)
    pts = centres[:, :, None, :] + (t[None, None, :, None] * lateral[..., None, None]) * perp[:, :, None, :]  # (S, L, n, 2)
    meas = np.asarray(ranges)
    common = {"range_sigma": range_sigma, "k_sigma": k_sigma, "range_max": range_max}
    if phase_average:
        n_bar = expected_unoccluded(
            poses, angles, meas, pts.reshape(s_, n * samples, 2), float(radii[0]) if n else 0.0, occlusion_radius=occlusion_radius, **common
        )
        pd_s = expected_pd(n_bar, pd_of_np).reshape(s_, n, samples)
    else:
        n_p, _ = count_unoccluded(poses, angles, meas, pts.reshape(s_, n * samples, 2), np.repeat(radii, samples), **common)
        pd_s = np.asarray(pd_of_np(n_p), dtype=np.float64).reshape(s_, n, samples)
    pd_c = pd_s[..., samples // 2]  # samples is odd: the middle one is the landmark itself
    mixed = (pd_s == 0).any(axis=-1) & (pd_s > 0).any(axis=-1)
    low = (pd_c > 0) & (pd_c < 0.5)
    pd = np.where(mixed, pd_s.max(axis=-1), pd_c)
    buf = mixed | low
    return (pd[0], buf[0]) if single else (pd, buf)


def expected_unoccluded(
    sensor_poses: np.ndarray,
    angles: np.ndarray,
    ranges: np.ndarray,
    centres: np.ndarray,
    radius: float,
    *,
    range_sigma: float,
    k_sigma: float = 3.0,
    range_max: float | None = None,
    window: int = 8,
    occlusion_radius: float | None = None,
) -> np.ndarray:
    """n_p averaged over where the beams fall on the landmark (a real number), for a filter.

    The integer n_p of :func:`count_unoccluded` jumps by one as the sensor turns by
    a fraction of a beam: a landmark of angular width w / delta_theta = 2.4 beams is
    hit by 2 or 3 beams depending on the phase. A particle filter that evaluates
    P_D(n_p) at each particle's pose would then weight particles by that phase,
    which carries no information about the pose. This function returns instead
    the expected count over a uniform phase, f * w / delta_theta (clipped to the
    field of view and the range), where f is the unoccluded fraction of the beams
    within +-(w/2 + delta_theta/2) of the landmark's bearing (at most ``window``
    beams either side of the central one). With a table P_D(n), interpolating
    linearly between floor and ceil of this value gives E[P_D] over the phase
    exactly when nothing occludes (:func:`expected_pd`).

    occlusion_radius: a return occludes only when it is shorter than the surface
    of a landmark of this radius at the centre (default ``radius``). A map
    feature's radius is not known; a generous one keeps a large trunk's own
    surface from counting as its occluder.

    sensor_poses (S, 3); angles (B,) evenly spaced, sensor frame (trailing NaN angles,
    past the beams of a scan of a laser with several layouts, are dropped with
    their ranges); ranges (B,) shared or (S, B); centres (S, L, 2) -> (S, L) float.
    """
    angles = np.asarray(angles, dtype=np.float64)
    n_beams = int(np.isfinite(angles).sum())
    width = angles.size
    angles = angles[:n_beams]
    angle_min, angle_increment = float(angles[0]), float(angles[1] - angles[0]) if n_beams > 1 else 1.0
    poses = np.atleast_2d(np.asarray(sensor_poses, dtype=np.float64))
    centres = np.asarray(centres, dtype=np.float64).reshape(poses.shape[0], -1, 2)
    meas = np.asarray(ranges, dtype=np.float64).reshape(-1, width)[:, :n_beams]
    s, l_ = centres.shape[:2]
    if s == 0 or l_ == 0:
        return np.zeros((s, l_))
    step = float(angle_increment)
    if step < 0:  # beams in decreasing angle: mirror to increasing
        angle_min, step, meas = angle_min + step * (n_beams - 1), -step, meas[:, ::-1]
    rel = centres - poses[:, None, :2]
    d = np.hypot(rel[..., 0], rel[..., 1])
    bearing = np.mod(np.arctan2(rel[..., 1], rel[..., 0]) - poses[:, None, 2] + np.pi, 2 * np.pi) - np.pi
    half = np.arcsin(np.clip(radius / np.maximum(d, 1e-9), 0.0, 1.0))
    lo_fov, hi_fov = angle_min - step / 2, angle_min + step * (n_beams - 0.5)
    width = np.clip(np.minimum(bearing + half, hi_fov) - np.maximum(bearing - half, lo_fov), 0.0, None) / step
    inside = d > radius
    if range_max is not None:
        inside &= d - radius <= range_max
    # the beams around the bearing: which of them the scan shows occluded
    centre_i = np.rint((bearing - angle_min) / step).astype(np.int64)
    k = np.arange(-window, window + 1)
    idx = centre_i[..., None] + k  # (S, L, K)
    valid = (idx >= 0) & (idx < n_beams)
    idx_c = np.clip(idx, 0, n_beams - 1)
    off = angle_min + step * idx_c - bearing[..., None]
    valid &= np.abs(off) <= half[..., None] + step / 2
    proj = d[..., None] * np.cos(off)
    perp = d[..., None] * np.sin(off)
    ro = max(radius, occlusion_radius) if occlusion_radius is not None else radius
    exp = proj - np.sqrt(np.maximum(ro * ro - perp * perp, 0.0))
    rows = np.arange(s)[:, None, None] if meas.shape[0] == s else np.zeros((1, 1, 1), dtype=np.int64)
    got = meas[rows, idx_c]
    occl = got < exp - k_sigma * range_sigma  # NaN compares False: a missing return does not occlude
    n_valid = valid.sum(axis=-1)
    frac = np.where(n_valid > 0, (valid & ~occl).sum(axis=-1) / np.maximum(n_valid, 1), 0.0)
    return np.where(inside, frac * width, 0.0)


def expected_pd(n_bar: np.ndarray, pd_of_np) -> np.ndarray:
    """E[P_D] for a real-valued expected count: linear between the table at floor and ceil."""
    lo = np.floor(n_bar)
    t = n_bar - lo
    return (1.0 - t) * np.asarray(pd_of_np(lo), dtype=np.float64) + t * np.asarray(pd_of_np(lo + 1.0), dtype=np.float64)
