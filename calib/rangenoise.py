"""Range noise of a laser from its own registered scans (for logs that do not state sigma_r).

The n_p ray tracer calls a return an occluder when it is shorter than the
range predicted for a landmark by more than ``k_sigma * sigma_r`` (thesis
sec. 4.1, fig. 4.2). That prediction comes from the registered map and the
scan's pose, so the spread that matters is the one of a measured range about
the range the map predicts: sensor noise plus registration and map error.
This module measures exactly that on ICP-aligned scans:

1. the returns of map scans -- a scan wherever the sensor moved ``map_move``
   or turned ``map_turn`` since the previous one, so that a surface is seen
   from several viewpoints rather than many times from one -- go into the
   world frame with the scan poses (ground truth or ICP): the registered map;
2. for the returns of evenly sampled query scans, the nearest map returns of
   *other* scans within ``radius`` give a local surface: a line through
   their centroid along their principal direction (PCA of the 2x2 scatter),
   kept only when the points are thin across it (a wall, not a corner or
   clutter);
3. the range residual of the return is the distance along its own beam to
   that line: ``e = n . (p - c) / (n . d)`` with ``n`` the line's normal,
   ``c`` its centroid, ``p`` the return and ``d`` the beam direction (grazing
   beams, ``|n . d| < min_incidence``, are left out: there a small offset
   across the line is a large one along the beam);
4. per range band, the robust spread ``1.4826 * MAD`` and the median (bias)
   of the residuals; sigma_r for the ray tracer is the robust spread of all
   residuals together.

The thinness test matters: without it, a return whose neighbours form a blob
(a trunk, a table leg) is scored against their centroid, next to itself, and
the spread comes out far too small. With the defaults the estimate is slightly
high on simulated parks (curved trunks pass as lines over 0.5 m; docs/results.md),
which errs on the side of not calling noise an occlusion.

Everything is vectorised over the query returns (one k-d tree query, batched
2x2 eigen-decompositions).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from calib.progress import progress
from detectors.sensor_log import SensorLog
from profiles.errors import DataError
from profiles.parameters import RangeNoiseConfig

#: Consistency factor of the median absolute deviation for a Gaussian.
MAD_TO_SIGMA = 1.4826


@dataclass
class RangeNoise:
    """Per-band residual statistics and the sigma_r chosen for the ray tracer.

    edges (K+1,) band edges [m] (the last one is the largest range scored);
    sigma, bias (K,) [m] (NaN for a band with fewer than ``min_samples``);
    samples (K,) residuals per band; range_sigma: robust spread of all residuals [m].
    """

    edges: np.ndarray
    sigma: np.ndarray
    bias: np.ndarray
    samples: np.ndarray
    range_sigma: float
    residuals: int
    scans_scored: int
    table: list[dict] = field(default_factory=list)

    def summary(self) -> dict:
        return {
            "range_sigma_m": self.range_sigma,
            "residuals": self.residuals,
            "scans_scored": self.scans_scored,
            "bands": [
                {"from_m": float(a), "to_m": float(b), "sigma_m": _num(s), "bias_m": _num(m), "samples": int(n)}
                for a, b, s, m, n in zip(self.edges[:-1], self.edges[1:], self.sigma, self.bias, self.samples, strict=True)
            ],
        }


def _num(v: float) -> float | None:
    return None if not np.isfinite(v) else float(v)


def _robust(x: np.ndarray) -> tuple[float, float]:
    med = float(np.median(x))
    return MAD_TO_SIGMA * float(np.median(np.abs(x - med))), med


def range_residuals(log: SensorLog, sensor_poses: np.ndarray, cfg: RangeNoiseConfig) -> tuple[np.ndarray, np.ndarray, int]:
    """(ranges (M,), residuals (M,), scans scored) for the returns of the query scans; see the module docstring.

    sensor_poses (S, 3) world frame, one per scan of ``log``.
    """
    if log.scans is None or log.sensor is None:
        raise DataError(f"log {log.name!r} has no laser scans to measure range noise on")
    n = len(log.scans)
    ang = log.scan_angles()
    ang2 = np.broadcast_to(ang, log.scans.ranges.shape) if ang.ndim == 1 else ang
    r = log.scans.ranges.astype(np.float64)
    a = sensor_poses[:, 2:3] + ang2
    x = sensor_poses[:, 0:1] + r * np.cos(a)
    y = sensor_poses[:, 1:2] + r * np.sin(a)
    ok = np.isfinite(x)
    in_map = np.zeros(r.shape, dtype=bool)
    in_map[map_scans(sensor_poses, cfg.map_move, cfg.map_turn)] = True
    in_map &= ok
    scan_of = np.broadcast_to(np.arange(n)[:, None], r.shape)[in_map]
    cloud = np.column_stack([x[in_map], y[in_map]])
    if cloud.shape[0] < cfg.neighbours * 2:
        raise DataError(f"log {log.name!r}: too few returns to measure range noise")
    queries = np.unique(np.linspace(0, n - 1, min(cfg.query_scans, n)).round().astype(np.int64))
    qmask = np.zeros(r.shape, dtype=bool)
    qmask[queries] = True
    qmask &= ok
    qp = np.column_stack([x[qmask], y[qmask]])
    q_scan = np.broadcast_to(np.arange(n)[:, None], r.shape)[qmask]
    q_range = r[qmask]
    q_dir = np.column_stack([np.cos(a[qmask]), np.sin(a[qmask])])
    tree = cKDTree(cloud)
    ranges, resid = [], []
    chunks = range(0, qp.shape[0], _CHUNK)  # chunks of returns: memory stays flat on long logs
    for lo_ in progress(chunks, len(chunks), "measuring range noise"):
        sl = slice(lo_, lo_ + _CHUNK)
        r_, e_ = _residuals(tree, cloud, scan_of, qp[sl], q_scan[sl], q_dir[sl], q_range[sl], cfg)
        ranges.append(r_)
        resid.append(e_)
    return np.concatenate(ranges), np.concatenate(resid), int(queries.size)


#: Query returns per k-d tree call (bounds the neighbour arrays at ~100 MB).
_CHUNK = 40_000


def _residuals(tree, cloud, scan_of, qp, q_scan, q_dir, q_range, cfg: RangeNoiseConfig) -> tuple[np.ndarray, np.ndarray]:
    """(ranges, range residuals) of the query returns qp (Q, 2) that lie on a thin local surface of other scans."""
    k = cfg.neighbours + 8  # a few extra: the query scan's own returns (when it is a map scan) are dropped
    dist, idx = tree.query(qp, k=k, distance_upper_bound=cfg.radius)
    found = np.isfinite(dist)
    idx_c = np.where(found, idx, 0)
    use = found & (scan_of[idx_c] != q_scan[:, None])
    # keep the nearest `neighbours` of other scans
    use &= np.cumsum(use, axis=1) <= cfg.neighbours
    cnt = use.sum(axis=1)
    enough = cnt >= cfg.min_neighbours
    w = use[enough].astype(np.float64)
    pts = cloud[idx_c[enough]]  # (Q', k, 2)
    c = (w[..., None] * pts).sum(axis=1) / w.sum(axis=1)[:, None]
    dxy = (pts - c[:, None, :]) * w[..., None]
    sxx = np.einsum("qk,qk->q", dxy[..., 0], dxy[..., 0])
    syy = np.einsum("qk,qk->q", dxy[..., 1], dxy[..., 1])
    sxy = np.einsum("qk,qk->q", dxy[..., 0], dxy[..., 1])
    # eigenvalues of [[sxx, sxy], [sxy, syy]] and the normal (eigenvector of the smaller one)
    half_tr, det = (sxx + syy) / 2, sxx * syy - sxy * sxy
    disc = np.sqrt(np.maximum(half_tr * half_tr - det, 0.0))
    lo, hi = half_tr - disc, half_tr + disc
    theta = 0.5 * np.arctan2(2 * sxy, sxx - syy)  # direction of the larger spread
    normal = np.column_stack([-np.sin(theta), np.cos(theta)])
    thin = lo <= cfg.thinness * np.maximum(hi, 1e-18)
    cosi = np.einsum("qj,qj->q", normal, q_dir[enough])
    steep = np.abs(cosi) >= cfg.min_incidence
    keep = thin & steep
    e = np.einsum("qj,qj->q", normal[keep], qp[enough][keep] - c[keep]) / cosi[keep]
    return q_range[enough][keep], e


def map_scans(sensor_poses: np.ndarray, move: float, turn: float) -> np.ndarray:
    """Indices of the scans that make the map: the first, then each after ``move`` [m] or ``turn`` [rad] since the last."""
    keep = [0]
    last = sensor_poses[0]
    for i in range(1, sensor_poses.shape[0]):  # sequential by nature; a few microseconds per scan
        p = sensor_poses[i]
        dth = abs((p[2] - last[2] + np.pi) % (2 * np.pi) - np.pi)
        if np.hypot(p[0] - last[0], p[1] - last[1]) >= move or dth >= turn:
            keep.append(i)
            last = p
    return np.array(keep, dtype=np.int64)


def pool_range_noise(parts: list[tuple[np.ndarray, np.ndarray, int]], cfg: RangeNoiseConfig | None = None) -> RangeNoise:
    """Range noise from the :func:`range_residuals` of each log (computed where each log is), pooled."""
    cfg = cfg or RangeNoiseConfig()
    rng = np.concatenate([p[0] for p in parts])
    res = np.concatenate([p[1] for p in parts])
    scored = sum(p[2] for p in parts)
    if res.size < cfg.min_samples:
        raise DataError(
            f"only {res.size} returns lie on surfaces that other scans saw too; cannot estimate the range noise: pass --range-sigma"
        )
    top = float(rng.max())
    lows = [b for b in sorted(cfg.bands) if b < top]
    edges = np.array([*lows, np.nextafter(top, np.inf)])
    band = np.clip(np.searchsorted(edges, rng, side="right") - 1, 0, edges.size - 2)
    sigma, bias, samples = [], [], []
    for b in range(edges.size - 1):
        x = res[band == b]
        samples.append(x.size)
        s, m = _robust(x) if x.size >= cfg.min_samples else (np.nan, np.nan)
        sigma.append(s)
        bias.append(m)
    total, _ = _robust(res)
    if not total > 0:
        raise DataError("the range residuals have no spread (ranges quantised coarsely?); pass --range-sigma")
    return RangeNoise(edges, np.array(sigma), np.array(bias), np.array(samples, dtype=np.int64), total, int(res.size), scored)
