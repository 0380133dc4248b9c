"""Metrics of a SLAM run: OSPA and GOSPA between maps, trajectory RMSE.

* OSPA (Schuhmacher, Vo, Vo 2008) with cut-off c and order p:
  for |X| = m <= n = |Y|,
  d = ((min over assignments sum min(c, d(x, y))^p + c^p (n - m)) / n)^(1/p); 0 for two empty sets.
* GOSPA (Rahmathullah, Garcia-Fernandez, Svensson 2017) with alpha = 2:
  d^p = min over assignments of sum_assigned d(x, y)^p + c^p / 2 (unassigned points),
  where pairs farther than c are better left unassigned; reported with its
  localisation, missed and false parts.
* Trajectory RMSE of positions, optionally after the best rigid alignment
  (rotation + translation, no scale): say which when reporting.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

from detectors.geometry import rigid_align


def _points(a: np.ndarray, dim: int) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    return a.reshape(-1, dim) if a.size else np.zeros((0, dim))


def ospa(x: np.ndarray, y: np.ndarray, c: float = 1.0, p: float = 1.0, distance=None) -> float:
    """OSPA distance between point sets x (m, d) and y (n, d); ``distance(a, b) -> (m, n)`` replaces the
    Euclidean base distance (e.g. planes, where a point and its negation are the same plane)."""
    dim = max(np.asarray(x).shape[-1] if np.asarray(x).ndim > 1 else 2, np.asarray(y).shape[-1] if np.asarray(y).ndim > 1 else 2)
    x, y = _points(x, dim), _points(y, dim)
    m, n = x.shape[0], y.shape[0]
    if m == 0 and n == 0:
        return 0.0
    if m == 0 or n == 0:
        return float(c)
    if m > n:
        x, y, m, n = y, x, n, m
    cost = np.minimum(cdist(x, y) if distance is None else distance(x, y), c) ** p
    r, k = linear_sum_assignment(cost)
    return float(((cost[r, k].sum() + c**p * (n - m)) / n) ** (1.0 / p))


def gospa(x: np.ndarray, y: np.ndarray, c: float = 1.0, p: float = 1.0, distance=None) -> dict:
    """GOSPA (alpha = 2) between estimate x and truth y: total and its localisation / missed / false parts;
    ``distance`` as for :func:`ospa`."""
    dim = 2 if distance is None else max(np.asarray(x).shape[-1] if np.asarray(x).ndim > 1 else 2, np.asarray(y).shape[-1] if np.asarray(y).ndim > 1 else 2)
    x, y = _points(x, dim), _points(y, dim)
    m, n = x.shape[0], y.shape[0]
    loc = 0.0
    assigned = 0
    if m and n:
        d = cdist(x, y) if distance is None else distance(x, y)
        cost = np.minimum(d, c) ** p
        r, k = linear_sum_assignment(cost)
        keep = d[r, k] < c  # pairs at c or beyond cost as much left apart
        loc = float((d[r, k][keep] ** p).sum())
        assigned = int(keep.sum())
    missed = (n - assigned) * c**p / 2
    false = (m - assigned) * c**p / 2
    return {
        "gospa": float((loc + missed + false) ** (1.0 / p)),
        "localisation": loc,
        "missed": missed,
        "false": false,
        "n_missed": n - assigned,
        "n_false": m - assigned,
    }


def axis_rmse(est: np.ndarray, truth: np.ndarray) -> tuple[float, float, float]:
    """RMSE of x [m], y [m] and heading [rad] (wrapped differences) of est (N, 3) against truth (N, 3)."""
    e = np.asarray(est, dtype=np.float64)[:, :3] - np.asarray(truth, dtype=np.float64)[:, :3]
    e[:, 2] = (e[:, 2] + np.pi) % (2 * np.pi) - np.pi
    r = np.sqrt(np.mean(e * e, axis=0))
    return float(r[0]), float(r[1]), float(r[2])


def trajectory_rmse(est: np.ndarray, truth: np.ndarray, align: bool = False) -> float:
    """Position RMSE (m) of est (N, 3) against truth (N, 3); ``align`` applies the best rigid fit first."""
    e = rigid_align(est, truth) if align else np.asarray(est)
    return float(np.sqrt(np.mean(np.sum((e[:, :2] - truth[:, :2]) ** 2, axis=1))))
