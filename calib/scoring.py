"""Scores of a profile on held-out data: P_D reliability, false alarms per frame, Hotelling coverage.

* :func:`score_pd` -- predictions against 0/1 outcomes per (frame, landmark)
  pair. Pairs predicted exactly 0 (out of view, occluded, below the clamp) are
  kept apart in their own row: they say nothing about calibration unless they
  were detected, and on a laser log they are ~90 % of the pairs, so counting
  them in the expected calibration error only shrinks it. The ECE runs over
  the informative pairs (prediction > 0) in 10 equal-width bins of (0, 1]:
  ECE = sum_b (n_b / N) |observed_b - predicted_b|, shown with the bin counts
  and with the ECE a perfectly calibrated model would still show with these
  counts (binomial noise: sum_b (n_b / N) sqrt(2 p_b (1 - p_b) / (pi n_b))).
  Over all pairs: the Brier score mean (p - y)^2 beside that of the constant
  held-out rate, and the mean Bernoulli log-likelihood (p clipped to
  [1e-3, 1 - 1e-3]).
* :func:`score_counts` -- false alarms per frame: the observed mean with a 95 %
  batch-means interval (frames are correlated), the relative error against the
  profile's rate with that interval, Pearson's chi-square of the held-out counts
  against the profile's count model (nothing refitted: dof = bins - 1), the
  held-out dispersion index and its likelihood-ratio test.
* :func:`score_coverage` -- the share of true detections inside the Hotelling
  ellipsoid with a Wilson interval, against the nominal confidence, and how
  many more misses than stated that means.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from calib.clutter import batch_means_ci, dispersion_test, fit_negative_binomial, pearson
from calib.fits import wilson
from calib.pdmodels import bernoulli_loglik
from profiles.schema import ClutterParams

N_BINS = 10


def reliability_table(pred: np.ndarray, obs: np.ndarray, n_bins: int = N_BINS) -> pd.DataFrame:
    """One row for pairs predicted exactly 0, then ``n_bins`` equal bins of (0, 1]; counts, mean prediction, observed rate."""
    pred = np.asarray(pred, dtype=np.float64)
    obs = np.asarray(obs, dtype=np.float64)
    zero = pred <= 0.0
    b = np.where(zero, 0, np.clip(np.ceil(pred * n_bins).astype(np.int64), 1, n_bins))
    n = np.bincount(b, minlength=n_bins + 1)
    sp = np.bincount(b, weights=pred, minlength=n_bins + 1)
    k = np.bincount(b, weights=obs, minlength=n_bins + 1).astype(np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):
        lo, hi = wilson(k, n)
        return pd.DataFrame(
            {
                "low": np.concatenate([[0.0], np.arange(n_bins) / n_bins]),
                "high": np.concatenate([[0.0], np.arange(1, n_bins + 1) / n_bins]),
                "pairs": n,
                "detected": k,
                "predicted": np.where(n > 0, sp / np.maximum(n, 1), np.nan),
                "observed": np.where(n > 0, k / np.maximum(n, 1), np.nan),
                "observed_low": lo,
                "observed_high": hi,
            }
        )


def ece_noise_blocks(pred: np.ndarray, y: np.ndarray, cluster: np.ndarray, n_bins: int = N_BINS) -> float:
    """The ECE a calibrated model would show on these pairs when outcomes are correlated within clusters.

    Per informative bin b the mean residual (y - p) has the cluster-robust
    variance V_b = C / (C - 1) sum_c (r_cb - n_cb d_b)^2 / n_b^2 (r_cb the residual
    sum of cluster c in bin b, d_b the bin's mean residual, C its clusters); a
    calibrated model's |mean residual| then averages sqrt(2 V_b / pi).
    """
    inf = pred > 0
    b = np.clip(np.ceil(pred[inf] * n_bins).astype(np.int64), 1, n_bins) - 1
    res = y[inf].astype(np.float64) - pred[inf]
    _, c = np.unique(np.asarray(cluster)[inf], return_inverse=True)
    key = b * (c.max() + 1 if c.size else 1) + c
    uk, inv = np.unique(key, return_inverse=True)
    r_cb = np.bincount(inv, weights=res)
    n_cb = np.bincount(inv).astype(np.float64)
    kb = uk // (c.max() + 1 if c.size else 1)
    n_b = np.bincount(kb, weights=n_cb, minlength=n_bins)
    d_b = np.bincount(kb, weights=r_cb, minlength=n_bins) / np.maximum(n_b, 1)
    dev = (r_cb - n_cb * d_b[kb]) ** 2
    c_b = np.bincount(kb, minlength=n_bins).astype(np.float64)
    v_b = np.bincount(kb, weights=dev, minlength=n_bins) / np.maximum(n_b, 1) ** 2 * c_b / np.maximum(c_b - 1, 1)
    w = n_b / max(float(n_b.sum()), 1.0)
    return float((w * np.sqrt(2 * v_b / np.pi)).sum())


def score_pd(pred: np.ndarray, obs: np.ndarray, cluster: np.ndarray | None = None, n_bins: int = N_BINS) -> tuple[dict, pd.DataFrame]:
    """(summary, reliability table) of P_D predictions (N,) against detections (N,) bool.

    cluster (N,): optional groups of pairs whose outcomes go together (a landmark
    over a few seconds); with it the summary also gives the block-robust ECE
    floor (:func:`ece_noise_blocks`).
    """
    pred = np.asarray(pred, dtype=np.float64)
    y = np.asarray(obs, dtype=bool)
    table = reliability_table(pred, y, n_bins)
    inf = table.iloc[1:]
    used = inf["pairs"].to_numpy() > 0
    n_inf = int(inf["pairs"].sum())
    w = inf["pairs"].to_numpy()[used] / max(n_inf, 1)
    gap = np.abs(inf["observed"].to_numpy()[used] - inf["predicted"].to_numpy()[used])
    pb = inf["predicted"].to_numpy()[used]
    floor = float((w * np.sqrt(2 * pb * (1 - pb) / (np.pi * inf["pairs"].to_numpy()[used]))).sum()) if used.any() else float("nan")
    floor_blocks = ece_noise_blocks(pred, y, cluster, n_bins) if cluster is not None and used.any() else float("nan")
    base = float(y.mean()) if y.size else float("nan")
    zero = table.iloc[0]
    summary = {
        "pairs": int(y.size),
        "pairs_informative": n_inf,
        "ece": float((w * gap).sum()) if used.any() else float("nan"),
        "ece_if_calibrated": floor,
        "ece_if_calibrated_blocks": floor_blocks,
        "pairs_predicted_zero": int(zero["pairs"]),
        "detections_where_zero_predicted": int(zero["detected"]),
        "brier": float(np.mean((pred - y) ** 2)) if y.size else float("nan"),
        "brier_constant_rate": base * (1 - base),
        "loglik_per_pair": float(bernoulli_loglik(pred, y).mean()) if y.size else float("nan"),
        "detections_observed": int(y.sum()),
        "detections_predicted": float(pred.sum()),
    }
    return summary, table


def score_counts(counts: np.ndarray, clutter: ClutterParams, n_batches: int = 20) -> dict:
    """False alarms per frame (F,) of held-out frames against the profile's clutter model."""
    c = np.asarray(counts, dtype=np.int64)
    m, lo, hi = batch_means_ci(c, n_batches)
    rate = clutter.rate
    rel = (lambda x: (x - rate) / rate) if rate > 0 else (lambda x: float("nan"))
    g = pearson(c, clutter.count_pmf, clutter.count_sf, fitted=0) if c.size else None
    nb = fit_negative_binomial(c) if c.size else None
    return {
        "frames": int(c.size),
        "false_alarms": int(c.sum()),
        "false_alarms_per_frame_observed": m,
        "false_alarms_per_frame_ci95": [lo, hi],
        "false_alarms_per_frame_predicted": rate,
        "false_alarm_relative_error": rel(m),
        "false_alarm_relative_error_ci95": [rel(lo), rel(hi)],
        # what the count model alone says the mean of these frames would scatter by (independent frames)
        "false_alarms_per_frame_model_sd": float(np.sqrt(clutter.count_variance / max(c.size, 1))),
        "clutter_count_model": clutter.count_model,
        "clutter_chi2": g.chi2 if g is not None else float("nan"),
        "clutter_chi2_dof": g.dof if g is not None else 0,
        "clutter_chi2_p_value": g.p_value if g is not None else float("nan"),
        "clutter_dispersion": float(c.var(ddof=1) / c.mean()) if c.size > 1 and c.mean() > 0 else float("nan"),
        "clutter_dispersion_profile": clutter.count_variance / rate if rate > 0 else float("nan"),
        "clutter_dispersion_p_value": dispersion_test(nb).p_value if nb is not None else float("nan"),
    }


def score_coverage(inside: np.ndarray, nominal: float | None) -> dict:
    """Share of true detections inside the ellipsoid (N,) bool, against the nominal confidence."""
    inside = np.asarray(inside, dtype=bool)
    n = inside.size
    if n == 0 or nominal is None:
        return {"true_detections": int(n)}
    k = int(inside.sum())
    lo, hi = wilson(np.array([k]), np.array([n]))
    share = k / n
    return {
        "true_detections": int(n),
        "hotelling_coverage": share,
        "hotelling_coverage_ci95": [float(lo[0]), float(hi[0])],
        "hotelling_nominal": nominal,
        "hotelling_misses_vs_stated": (1 - share) / (1 - nominal),
    }
