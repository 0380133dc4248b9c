"""A seeded camera-like detection-level simulator: the truth for detection-level calibration tests.

A robot drives a slow circle in a 10 m room with 15 landmarks; at every frame
each landmark in the field of view is detected with probability ``pd(range,
bearing)``; clutter detections (another robot's barcode) fall in the field of
view, ``clutter_counts(rng, n)`` of them per frame (Poisson by default), at
ranges drawn by ``clutter_range(rng, k)`` (uniform by default).
"""

from __future__ import annotations

import numpy as np

from detectors.sensor_log import Detections, Landmarks, ReferencePoses, SensorLog, SensorModel

PERIOD = 0.25
FOV = np.deg2rad(60)
RANGE_MAX = 6.0


def pd_range(r, b=None):
    return np.clip(0.9 - 0.12 * np.asarray(r), 0.0, 1.0)


def pd_edges(r, b):
    """P_D falling toward the edges of the field of view (a lens's vignetting) as well as with range."""
    return pd_range(r) * np.clip(1.0 - (np.abs(b) / (FOV / 2)) ** 4, 0.0, 1.0)


def camera_log(
    seed: int,
    n: int = 12000,
    clutter: float = 0.4,
    *,
    pd=pd_range,
    period: float = PERIOD,
    clutter_counts=None,
    clutter_range=None,
    swap: tuple[int, int] | None = None,
    robot: int | None = None,
    occluder: float | None = None,
) -> SensorLog:
    """A log of ``n`` frames. ``swap``: two landmark ids whose surveyed positions are exchanged in the truth.
    ``occluder``: landmarks are posts of this radius [m]: one whose centre lies behind a nearer post, within
    the angle that post subtends (asin(radius / its range)), is never detected."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * period
    stamp = np.rint(t * 1e9).astype(np.int64)
    th = 0.05 * t  # the same path in time whatever the frame period
    poses = np.column_stack([5 + 2.5 * np.cos(th), 5 + 2.5 * np.sin(th), th + np.pi / 2 + 0.3 * np.sin(0.7 * t)])
    lm = rng.uniform(0, 10, (15, 2))
    rel = lm[None] - poses[:, None, :2]
    rng_ = np.hypot(rel[..., 0], rel[..., 1])
    brg = np.mod(np.arctan2(rel[..., 1], rel[..., 0]) - poses[:, None, 2] + np.pi, 2 * np.pi) - np.pi
    seen = (np.abs(brg) <= FOV / 2) & (rng_ <= RANGE_MAX) & (rng.uniform(size=rng_.shape) < pd(rng_, brg))
    if occluder is not None:
        for a in range(lm.shape[0]):
            for c in range(lm.shape[0]):
                if c != a:
                    d = np.mod(brg[:, c] - brg[:, a] + np.pi, 2 * np.pi) - np.pi
                    half = np.arcsin(np.clip(occluder / rng_[:, c], 0.0, 1.0))
                    seen[:, a] &= ~((rng_[:, c] < rng_[:, a]) & (np.abs(d) < half))
    e, k = np.nonzero(seen)
    r = np.abs(rng_[e, k] + rng.normal(0, 0.05, e.size))
    b = brg[e, k] + rng.normal(0, 0.01, e.size)
    subj = 6 + k
    nc = clutter_counts(rng, n) if clutter_counts is not None else rng.poisson(clutter, n)
    ce = np.repeat(np.arange(n), nc)
    cr = clutter_range(rng, ce.size) if clutter_range is not None else rng.uniform(0.5, RANGE_MAX, ce.size)
    cb = rng.uniform(-FOV / 2, FOV / 2, ce.size)
    ee = np.concatenate([e, ce])
    order = np.argsort(ee, kind="stable")
    ee = ee[order]
    rr, bb = np.concatenate([r, cr])[order], np.concatenate([b, cb])[order]
    ss = np.concatenate([subj, np.full(ce.size, 2)])[order]
    frames, f = np.unique(ee, return_inverse=True)
    truth = lm.copy()
    if swap is not None:
        i, j = swap[0] - 6, swap[1] - 6
        truth[[i, j]] = truth[[j, i]]
    return SensorLog(
        f"cam{seed}",
        sensor=SensorModel(kind="camera"),
        reference={"ground_truth": ReferencePoses("ground_truth", stamp, poses)},
        landmarks=Landmarks(np.arange(6, 21), truth),
        detections=Detections(stamp[frames], f, rr, bb, {"subject": ss}),
        source={} if robot is None else {"robot": robot},
    )
