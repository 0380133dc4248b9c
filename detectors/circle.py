"""The 2D circle (tree trunk) detector of Inostroza (2015), ch. 5.

Three steps, all batched over the clusters of many scans at once:

1. **Clustering** (sec. 5.3.1): consecutive returns of a scan belong to one
   cluster while the Euclidean distance between neighbours is at most
   ``jump``; a missing return (NaN) also breaks a cluster. Clusters with fewer
   than ``min_points`` (or more than ``max_points``) returns are dropped.
2. **Circle fit** (sec. 5.3.2): minimise eq. 5.1,
   ``sum_i (|p_i - c| - r)^2``, with Levenberg-Marquardt. Every cluster's
   normal equations are sums over its points, so one ``numpy.bincount`` per
   entry builds them for all clusters together and a batched 3x3 solve does
   the step: no Python loop over clusters.

   Start: the algebraic Kasa fit (``x^2 + y^2 = 2 a x + 2 b y + c``, one
   linear 3x3 solve per cluster, again from point sums). It is exact for
   noise-free points, so LM starts next to the optimum; the thesis's start
   (mean point as centre, half chord as radius) puts the centre on the arc
   itself, a full radius from the optimum, and costs more iterations. Kasa
   is biased towards small radii on short noisy arcs and undefined for
   collinear points; LM removes the bias, and where Kasa is singular we fall
   back to the thesis's start pushed one half-chord away from the sensor. The
   start is never forced to the far side: a concave arc must be free to fit a
   centre on the sensor's side, which is what convexity detects.
3. **Descriptors** (sec. 5.3.3): fit error FE (eq. 5.2, the *sum* of squared
   residuals), radius, convexity (eq. 5.3: distance sensor-centre minus
   distance sensor-mean point; positive for a trunk, negative for a concave
   arc such as a corner seen from inside), number of points. Optional gating
   by a Hotelling model keeps detections with squared Mahalanobis distance at
   most gamma (eq. 5.4).

The centre is reported in the sensor frame and as range/bearing with a
measurement covariance from the fit: ``s^2 (J^T J)^-1`` on (x_c, y_c, r)
with ``s^2`` the residual variance (floored at the sensor's sigma_r^2),
propagated to (range, bearing).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from detectors.kinds import Detector, Measurements, register
from profiles.errors import DataError
from profiles.schema import CircleDetectorParams, HotellingParams

DESCRIPTORS = ("fit_error", "radius", "convexity")  # the thesis's three (sec. 5.3.3)

#: Floor of the mean-square residual in ``log_mse`` [m^2], (3.2 mm)^2: below any
#: laser's range noise, it keeps exact 3-point fits (FE = 0) finite.
MSE_FLOOR = 1e-5

#: Every descriptor a Hotelling model may use. The derived ones are closer to
#: Gaussian than the thesis's raw three: FE is exactly 0 for every 3-point
#: cluster, trunk radii are log-normal and convexity grows with the radius.
DESCRIPTOR_NAMES = ("fit_error", "radius", "convexity", "points", "mse", "log_mse", "log_radius", "rel_convexity")


def descriptor_matrix(fit_error, radius, convexity, points, names) -> np.ndarray:
    """(D, len(names)) descriptors from the per-detection arrays, base or derived."""
    fe, r = np.asarray(fit_error, dtype=np.float64), np.asarray(radius, dtype=np.float64)
    c, n = np.asarray(convexity, dtype=np.float64), np.asarray(points, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        table = {
            "fit_error": lambda: fe,
            "radius": lambda: r,
            "convexity": lambda: c,
            "points": lambda: n,
            "mse": lambda: fe / n,
            "log_mse": lambda: np.log(fe / n + MSE_FLOOR),
            "log_radius": lambda: np.log(r),
            "rel_convexity": lambda: c / r,
        }
        cols = []
        for name in names:
            if name not in table:
                raise DataError(f"unknown descriptor {name!r}; choose from {', '.join(DESCRIPTOR_NAMES)}")
            cols.append(table[name]())
    return np.column_stack(cols) if cols else np.zeros((fe.size, 0))


@dataclass(frozen=True, eq=False)
class CircleDetections:
    """Detections of a batch of scans, struct-of-arrays, sensor frame.

    scan (D,) int64      index of the scan in the batch
    x, y (D,)            centre [m], sensor frame
    range, bearing (D,)  centre in polar form [m], [rad]
    radius (D,)          [m]
    fit_error (D,)       eq. 5.2 [m^2]
    convexity (D,)       eq. 5.3 [m]
    n_points (D,) int64  returns in the cluster
    first, last (D,)     beam indices of the cluster's first and last return
    cov (D, 2, 2)        covariance of (range, bearing)
    radius_var (D,)      variance of the radius
    maha2 (D,)           squared Mahalanobis distance to the Hotelling mean (NaN without a model)
    """

    scan: np.ndarray
    x: np.ndarray
    y: np.ndarray
    range: np.ndarray
    bearing: np.ndarray
    radius: np.ndarray
    fit_error: np.ndarray
    convexity: np.ndarray
    n_points: np.ndarray
    first: np.ndarray
    last: np.ndarray
    cov: np.ndarray
    radius_var: np.ndarray
    maha2: np.ndarray

    def __len__(self) -> int:
        return int(self.scan.size)

    def descriptors(self, names: tuple[str, ...] = DESCRIPTORS) -> np.ndarray:
        """(D, len(names)) descriptor matrix in the given order (see :data:`DESCRIPTOR_NAMES`)."""
        return descriptor_matrix(self.fit_error, self.radius, self.convexity, self.n_points, names)

    def select(self, keep: np.ndarray) -> CircleDetections:
        return CircleDetections(**{f: getattr(self, f)[keep] for f in self.__dataclass_fields__})

    def replace(self, **fields) -> CircleDetections:
        return CircleDetections(**{**{f: getattr(self, f) for f in self.__dataclass_fields__}, **fields})

    def offset(self, k: int) -> CircleDetections:
        """The same detections with scan indices moved by k (a batch that starts at scan k)."""
        return self.replace(scan=self.scan + k)

    @staticmethod
    def concat(parts: list[CircleDetections]) -> CircleDetections:
        return CircleDetections(**{f: np.concatenate([getattr(p, f) for p in parts]) for f in CircleDetections.__dataclass_fields__})


def segment(ranges: np.ndarray, angles: np.ndarray, jump: float, min_points: int, max_points: int | None = None):
    """Cluster consecutive returns of each scan.

    ranges (N, B) float, NaN = no return; angles (B,) sensor frame, shared by all
    scans, or (N, B) one row per scan (NaN past a scan's own beams: no return).
    returns (scan (P,), beam (P,), label (P,), x (P,), y (P,)) for the P returns that
    belong to kept clusters, with ``label`` in 0..K-1 numbering clusters in scan/beam order.
    """
    ranges = np.asarray(ranges, dtype=np.float64)
    if ranges.ndim == 1:
        ranges = ranges[None]
    n, b = ranges.shape
    c, s = np.cos(angles), np.sin(angles)
    x, y = ranges * c, ranges * s
    ok = np.isfinite(x)  # a NaN range or a NaN angle (past a scan's own beams) is no return
    # a break before beam j when j or j-1 is missing or they are more than `jump` apart
    gap = np.hypot(np.diff(x, axis=1), np.diff(y, axis=1))
    brk = np.ones((n, b), dtype=bool)
    brk[:, 1:] = ~(ok[:, 1:] & ok[:, :-1] & (gap <= jump))
    flat_ok = ok.ravel()
    start = brk.ravel()[flat_ok]
    cid = np.cumsum(start) - 1  # cluster id of every return
    size = np.bincount(cid)
    keep_c = size >= min_points
    if max_points is not None:
        keep_c &= size <= max_points
    keep_p = keep_c[cid]
    label = (np.cumsum(keep_c) - 1)[cid[keep_p]]
    idx = np.flatnonzero(flat_ok)[keep_p]
    return idx // b, idx % b, label, x.ravel()[idx], y.ravel()[idx]


def _sums(label: np.ndarray, k: int, *w: np.ndarray) -> np.ndarray:
    """Per-cluster sums of several per-point weights in one bincount: (len(w), K)."""
    m = len(w)
    idx = (label[None, :] + k * np.arange(m)[:, None]).ravel()
    return np.bincount(idx, weights=np.concatenate(w), minlength=m * k).reshape(m, k)


def _kasa(label, k, x, y, cnt):
    """Algebraic circle fit per cluster; returns (K, 3) (xc, yc, r) and a validity mask."""
    z = x * x + y * y
    sx, sy, sxx, syy, sxy, sz, sxz, syz = _sums(label, k, x, y, x * x, y * y, x * y, z, x * z, y * z)
    sol = _solve_sym3(sxx, sxy, sx, syy, sy, cnt, sxz, syz, sz)
    # exactly collinear points make the system singular: no start from Kasa then
    good = np.isfinite(sol).all(axis=1)
    sol = np.where(good[:, None], sol, 0.0)
    xc, yc = sol[:, 0] / 2, sol[:, 1] / 2
    r2 = sol[:, 2] + xc * xc + yc * yc
    good &= r2 > 0
    return np.column_stack([xc, yc, np.sqrt(np.maximum(r2, 0))]), good


def fit_circles(
    label: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    k: int,
    first_xy: np.ndarray,
    last_xy: np.ndarray,
    iterations: int = 30,
    line_radius: float = np.inf,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Batched Levenberg-Marquardt fit of eq. 5.1 for K clusters.

    label (P,) cluster of each point; x, y (P,) sensor frame; first_xy/last_xy (K, 2)
    end points of each cluster (for the half-chord start). A cluster stops being
    refined once its radius exceeds ``line_radius`` (its cost keeps falling as the
    circle flattens towards the line it really is).
    returns params (K, 3) (xc, yc, r), fit error (K,) (eq. 5.2) and J^T J (K, 3, 3).
    """
    cnt = np.bincount(label, minlength=k).astype(np.float64)
    mx, my = _sums(label, k, x, y)
    mean = np.column_stack([mx, my]) / cnt[:, None]
    p, good = _kasa(label, k, x, y, cnt)
    half = 0.5 * np.hypot(*(last_xy - first_xy).T)
    u = mean / np.maximum(np.hypot(mean[:, 0], mean[:, 1]), 1e-12)[:, None]
    fallback = np.column_stack([mean + half[:, None] * u, half])
    p = np.where(good[:, None], p, fallback)

    def cost(params):
        d = np.hypot(x - params[label, 0], y - params[label, 1])
        res = d - params[label, 2]
        return np.bincount(label, weights=res * res, minlength=k), d, res

    lam = np.full(k, 1e-3)
    f, d, res = cost(p)
    active = np.ones(k, dtype=bool)
    for _ in range(iterations):  # a few batched steps for all clusters, not a loop over clusters
        dd = np.maximum(d, 1e-12)
        jx, jy = -(x - p[label, 0]) / dd, -(y - p[label, 1]) / dd  # d res / d (xc, yc); d res / d r = -1
        sxx, sxy, syy, sx, sy, gx, gy, gr = _sums(label, k, jx * jx, jx * jy, jy * jy, jx, jy, jx * res, jy * res, res)
        # Marquardt's damping scales the diagonal; the symmetric 3x3 is solved in closed form
        damp = 1.0 + lam
        step = _solve_sym3(sxx * damp, sxy, -sx, syy * damp, -sy, cnt * damp, gx, gy, -gr)
        step = np.where((np.isfinite(step).all(axis=1) & active)[:, None], -step, 0.0)
        trial = p + step
        f_new, d_new, res_new = cost(trial)
        better = (f_new < f) & active
        p = np.where(better[:, None], trial, p)
        d = np.where(better[label], d_new, d)
        res = np.where(better[label], res_new, res)
        # converged: the cost no longer changes (to rounding) or the step is negligible
        flat = np.abs(f - f_new) <= 1e-12 * np.maximum(f, 1e-300) + 1e-300
        tiny = np.abs(step).max(axis=1) <= 1e-7  # metres: far below any range noise
        f = np.where(better, f_new, f)
        lam = np.where(better, lam * 0.3, lam * 10.0)
        active &= ~(flat | tiny | (lam > 1e8) | (np.abs(p[:, 2]) > line_radius))
        if not active.any():
            break
    p[:, 2] = np.abs(p[:, 2])
    # J^T J at the solution, for the covariance
    d = np.maximum(np.hypot(x - p[label, 0], y - p[label, 1]), 1e-12)
    jx, jy = -(x - p[label, 0]) / d, -(y - p[label, 1]) / d
    sxx, sxy, syy, sx, sy = _sums(label, k, jx * jx, jx * jy, jy * jy, jx, jy)
    jtj = np.empty((k, 3, 3))
    jtj[:, 0, 0], jtj[:, 0, 1], jtj[:, 0, 2] = sxx, sxy, -sx
    jtj[:, 1, 0], jtj[:, 1, 1], jtj[:, 1, 2] = sxy, syy, -sy
    jtj[:, 2, 0], jtj[:, 2, 1], jtj[:, 2, 2] = -sx, -sy, cnt
    return p, f, jtj


def _solve_sym3(a00, a01, a02, a11, a12, a22, g0, g1, g2) -> np.ndarray:
    """Batched solve of symmetric 3x3 systems given by their six entries (each (K,)) -> (K, 3)."""
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        return _solve_sym3_raw(a00, a01, a02, a11, a12, a22, g0, g1, g2)


def _solve_sym3_raw(a00, a01, a02, a11, a12, a22, g0, g1, g2) -> np.ndarray:
    c00 = a11 * a22 - a12 * a12
    c01 = a12 * a02 - a01 * a22
    c02 = a01 * a12 - a11 * a02
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    out = np.empty((a00.size, 3))
    out[:, 0] = (c00 * g0 + c01 * g1 + c02 * g2) / det
    out[:, 1] = (c01 * g0 + c11 * g1 + c12 * g2) / det
    out[:, 2] = (c02 * g0 + c12 * g1 + c22 * g2) / det
    return out


def _fit_covariance(label, x, y, p, fe, cnt, jtj, range_sigma):
    """Covariance of (xc, yc, r) under range noise along each beam (sandwich form).

    A return p_i = r_i u_i has noise sigma_r along its beam u_i, so its residual
    to the circle has variance sigma_r^2 (u_i . n_i)^2, n_i the circle's normal
    at p_i. Cov = A^-1 B A^-1 with A = J^T J and B = sum_i w_i J_i J_i^T,
    w_i = sigma^2 (u_i . n_i)^2. Without a known sigma_r, sigma^2 is estimated
    from the fit error.
    """
    k = cnt.size
    d = np.maximum(np.hypot(x - p[label, 0], y - p[label, 1]), 1e-12)
    nx, ny = (x - p[label, 0]) / d, (y - p[label, 1]) / d
    rr = np.maximum(np.hypot(x, y), 1e-12)
    w = ((x * nx + y * ny) / rr) ** 2
    if range_sigma is None:
        sw = np.bincount(label, weights=w, minlength=k)
        s2 = fe / np.maximum(sw - 3 * sw / cnt, 1e-12)
    else:
        s2 = np.full(k, float(range_sigma) ** 2)
    jx, jy = -nx, -ny
    bxx, bxy, byy, bx, by, b1 = _sums(label, k, w * jx * jx, w * jx * jy, w * jy * jy, w * jx, w * jy, w)
    b = np.empty((k, 3, 3))
    b[:, 0] = np.stack([bxx, bxy, -bx], axis=1)
    b[:, 1] = np.stack([bxy, byy, -by], axis=1)
    b[:, 2] = np.stack([-bx, -by, b1], axis=1)
    ainv = np.linalg.pinv(jtj)
    return s2[:, None, None] * (ainv @ b @ ainv)


def mahalanobis2(desc: np.ndarray, mean, cov) -> np.ndarray:
    """Squared Mahalanobis distance (eq. 5.4) of (D, d) descriptors; inf where a descriptor is not finite."""
    desc = np.asarray(desc, dtype=np.float64)
    out = np.full(desc.shape[0], np.inf)
    fin = np.isfinite(desc).all(axis=1)
    diff = desc[fin] - np.asarray(mean, dtype=np.float64)
    out[fin] = np.einsum("ij,ij->i", diff, np.linalg.solve(np.asarray(cov, dtype=np.float64), diff.T).T)
    return out


def hotelling_maha2(desc: np.ndarray, model: HotellingParams) -> np.ndarray:
    """Squared Mahalanobis distance of (D, d) descriptors to a Hotelling model (inf where not finite)."""
    return mahalanobis2(desc, model.mean, model.covariance)


def detect_circles(
    ranges: np.ndarray,
    angles: np.ndarray,
    params: CircleDetectorParams,
    hotelling: HotellingParams | None = None,
    range_sigma: float | None = None,
) -> CircleDetections:
    """Run the detector on a batch of scans.

    ranges (N, B) or (B,) float, NaN = no return; angles (B,) sensor frame, or
    (N, B) per scan for a laser of several beam layouts
    (:meth:`detectors.sensor_log.SensorLog.scan_angles`; NaN past a scan's beams).
    With ``hotelling`` the detections outside its ellipsoid are dropped; the
    squared Mahalanobis distance is reported either way when a model is given.

    >>> import numpy as np
    >>> from profiles.schema import CircleDetectorParams
    >>> ang = np.linspace(-np.pi / 2, np.pi / 2, 361)
    >>> # a trunk of radius 0.3 m whose centre is 5 m straight ahead
    >>> dx, r = np.cos(ang), 0.3
    >>> b = 5 * dx
    >>> disc = b * b - (25 - r * r)
    >>> rng = np.where(disc >= 0, b - np.sqrt(np.maximum(disc, 0)), np.nan)
    >>> det = detect_circles(rng, ang, CircleDetectorParams())
    >>> round(float(det.range[0]), 3), round(float(det.radius[0]), 3)
    (5.0, 0.3)
    """
    ranges = np.asarray(ranges, dtype=np.float64)
    if ranges.ndim == 1:
        ranges = ranges[None]
    angles = np.asarray(angles, dtype=np.float64)
    if angles.shape not in ((ranges.shape[1],), ranges.shape):
        raise DataError(f"ranges: shape {ranges.shape} but beam angles of shape {angles.shape} (expected ({ranges.shape[1]},) or {ranges.shape})")
    scan, beam, label, x, y = segment(ranges, angles, params.jump, params.min_points, params.max_points)
    k = int(label.max()) + 1 if label.size else 0
    if k == 0:
        return _empty(hotelling is not None)
    starts = np.flatnonzero(np.r_[True, label[1:] != label[:-1]])
    ends = np.r_[starts[1:], label.size] - 1
    first_xy = np.column_stack([x[starts], y[starts]])
    last_xy = np.column_stack([x[ends], y[ends]])
    p, fe, jtj = fit_circles(label, x, y, k, first_xy, last_xy, params.lm_iterations, params.line_radius)
    cnt = np.bincount(label, minlength=k)
    mean = np.column_stack(_sums(label, k, x, y)) / cnt[:, None]
    rng_c = np.hypot(p[:, 0], p[:, 1])
    convexity = rng_c - np.hypot(mean[:, 0], mean[:, 1])
    cov3 = _fit_covariance(label, x, y, p, fe, cnt, jtj, range_sigma)
    jac = np.zeros((k, 2, 3))  # d(range, bearing)/d(xc, yc, r)
    rr = np.maximum(rng_c, 1e-12)
    jac[:, 0, 0], jac[:, 0, 1] = p[:, 0] / rr, p[:, 1] / rr
    jac[:, 1, 0], jac[:, 1, 1] = -p[:, 1] / rr**2, p[:, 0] / rr**2
    cov = jac @ cov3 @ jac.transpose(0, 2, 1)
    det = CircleDetections(
        scan=scan[starts].astype(np.int64),
        x=p[:, 0],
        y=p[:, 1],
        range=rng_c,
        bearing=np.arctan2(p[:, 1], p[:, 0]),
        radius=p[:, 2],
        fit_error=fe,
        convexity=convexity,
        n_points=cnt.astype(np.int64),
        first=beam[starts].astype(np.int64),
        last=beam[ends].astype(np.int64),
        cov=cov,
        radius_var=cov3[:, 2, 2],
        maha2=np.full(k, np.nan),
    )
    if params.max_radius is not None:
        det = det.select(det.radius <= params.max_radius)
    if hotelling is not None:
        m2 = hotelling_maha2(det.descriptors(tuple(hotelling.names)), hotelling)
        det = det.replace(maha2=m2)
        det = det.select(m2 <= hotelling.gamma)
    return det


def _empty(with_model: bool) -> CircleDetections:
    z = np.zeros(0)
    zi = np.zeros(0, dtype=np.int64)
    return CircleDetections(zi, z, z, z, z, z, z, z, zi, zi, zi, np.zeros((0, 2, 2)), z, z)


# ---------------------------------------------------------------------------- the kind at run time


class ScanCircles:
    """The profile's circle detector on every scan (with its Hotelling gate and the scan's own beam layout): each
    detection's own fit covariance, the descriptor likelihood ratio (eq. 5.6), and the scan with its beam angles for
    ray-traced P_D."""

    def __init__(self, log, profile, detection, *, descriptor_likelihood: bool = True) -> None:
        self.log = log
        self.params = profile.detector.circle
        self.detection = detection
        sensor = log.sensor if log.sensor is not None else profile.sensor
        self.range_sigma = sensor.range_sigma
        self.hot = None
        if profile.hotelling is not None:
            self.hot = HotellingParams.model_validate(profile.hotelling.model_dump(include=set(HotellingParams.model_fields)))
        self.ratio = descriptor_likelihood and self.hot is not None

    def __call__(self, frame) -> Measurements:
        scan = self.log.scans.ranges[frame.rows]
        angles = self.log.scan_angles(frame.rows)  # this scan's own beam layout (NaN past its beams)
        det = detect_circles(scan, angles, self.params, self.hot, self.range_sigma)
        z = np.column_stack([det.range, det.bearing])
        ratio = None
        if self.ratio:
            desc = det.descriptors(tuple(self.hot.names))
            ratio = self.detection.g_true(desc) / np.maximum(self.detection.g_false(desc), 1e-300)
        return Measurements(z, det.cov, ratio, scan, angles)


class CircleDetector(Detector):
    """``circle2d``: the thesis's laser circle detector, run on every scan of the log."""

    stream = "scans"
    needs = "detects circles in laser scans"

    def source(self, log, profile, detection, options):
        return ScanCircles(log, profile, detection, descriptor_likelihood=options.descriptor_likelihood)


register("circle2d", CircleDetector())
