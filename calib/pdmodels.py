"""P_D models richer than one table, chosen by held-out likelihood, and pooled across sensors.

The thesis estimates P_D per bin of one covariate (eq. 6.2: n_p for the laser;
range for a detection-level sensor here). A camera's P_D also falls off at the
edges of its field of view, so detection-level profiles may use a grid over
range x bearing. Candidates (each a :class:`profiles.schema.PdTable`):

* ``range`` -- eq. 6.2 against range alone (:func:`calib.fits.fit_pd_table`);
* ``additive_logit`` -- logit P_D = a_i + c_j over range bins i and bearing
  bins j: a logistic regression on the cell counts (Newton's method, a weak
  ridge penalty keeps empty cells finite), R + B parameters for R x B cells;
* ``cells_shrunk`` -- each cell's own rate shrunk toward the additive model by
  ``shrinkage`` pseudo-pairs: (k + s p_add) / (n + s), for interactions the
  additive model misses.

:func:`choose_pd_model` fits every candidate on all folds but one (folds: the
sensors when there are several, which asks for a model that transfers to a new
sensor; contiguous time blocks otherwise) and keeps the one with the highest
mean Bernoulli log-likelihood per held-out pair.

Several sensors (robots, logs): :func:`pool_sensors` states how far they differ
and gives each its own partially pooled table (empirical Bayes in two levels: a
logit offset per sensor shrunk by the offsets' spread, then each cell shrunk by
a beta prior fitted with the beta-binomial likelihood): a sensor with little
data stays near the pooled table, one with much data follows its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.optimize import minimize_scalar
from scipy.special import betaln, expit

from calib.fits import fit_pd_table, wilson
from profiles.errors import DataError
from profiles.override import updated
from profiles.parameters import PdModelConfig
from profiles.schema import PdTable, Selection

LOGLIK_CLIP = 1e-3  # P_D clipped to [c, 1 - c] in log-likelihoods: one impossible outcome costs log(1e-3), not -inf
# ------------------------------------------------------------------------------------------ cells


def cell_index(table: PdTable, pairs: pd.DataFrame) -> np.ndarray:
    """(N,) flat cell of each pair in the table's layout (rows x columns for a grid), -1 outside it.

    A covariate beyond the last edge falls in the last bin (as :meth:`PdTable.lookup`).
    """
    e = np.asarray(table.edges)
    nr = e.size - 1
    v = pairs[table.covariate if not table.two_d else "range"].to_numpy(np.float64)
    i = np.clip(np.searchsorted(e, v, side="right") - 1, 0, nr - 1)
    out = np.where(v < e[0], -1, i)
    if not table.two_d:
        return out
    be = np.asarray(table.bearing_edges)
    b = pairs["bearing"].to_numpy(np.float64)
    nb = be.size - 1
    j = np.clip(np.searchsorted(be, b, side="right") - 1, 0, nb - 1)
    return np.where((out < 0) | (b < be[0]) | (b > be[-1]), -1, out * nb + j)


def n_cells(table: PdTable) -> int:
    return int(np.asarray(table.pd).size)


def predict(table: PdTable, pairs: pd.DataFrame) -> np.ndarray:
    """P_D (N,) the table gives each pair (columns n_p, or range and bearing)."""
    if not table.two_d:
        return table.lookup(pairs[table.covariate].to_numpy())
    return table.lookup_rb(pairs["range"].to_numpy(np.float64), pairs["bearing"].to_numpy(np.float64))


def bernoulli_loglik(p: np.ndarray, y: np.ndarray) -> np.ndarray:
    """log P(y | p) per pair, p clipped to [LOGLIK_CLIP, 1 - LOGLIK_CLIP]."""
    p = np.clip(np.asarray(p, dtype=np.float64), LOGLIK_CLIP, 1 - LOGLIK_CLIP)
    return np.where(np.asarray(y, dtype=bool), np.log(p), np.log1p(-p))


def _counts(cells: np.ndarray, det: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    ok = cells >= 0
    n = np.bincount(cells[ok], minlength=size)
    k = np.bincount(cells[ok], weights=det[ok].astype(np.float64), minlength=size).astype(np.int64)
    return n, k


# ------------------------------------------------------------------------------------------ grids


def grid_edges(ranges: np.ndarray, fov: float, cfg: PdModelConfig) -> tuple[np.ndarray, np.ndarray]:
    """Range edges (rows with at least ``table.min_count`` pairs; the rest pooled into the last) and bearing edges."""
    r = np.asarray(ranges, dtype=np.float64)
    if r.size == 0:
        raise DataError("no (landmark, frame) pairs to fit P_D to: are the landmarks ever in view?")
    e = np.arange(0.0, r.max() + cfg.grid_range_bin, cfg.grid_range_bin)
    if e.size < 2:
        e = np.array([0.0, cfg.grid_range_bin])
    n = np.bincount(np.clip(np.searchsorted(e, r, side="right") - 1, 0, e.size - 2), minlength=e.size - 1)
    well = np.flatnonzero(n >= cfg.table.min_count)
    if well.size == 0:
        raise DataError(f"no range bin holds {cfg.table.min_count} pairs; calibrate on more data")
    e = e[: int(well[-1]) + 2]
    return e, np.linspace(-fov / 2, fov / 2, cfg.bearing_bins + 1)


def fit_additive_logit(k: np.ndarray, n: np.ndarray, ridge: float, iterations: int = 50) -> np.ndarray:
    """P_D (R, B) of logit p_ij = a_i + c_j fitted to cell counts k, n (R, B) by penalised Newton steps.

    Penalty: ridge / 2 * sum c_j^2 (bearing terms pulled toward no bearing effect)
    plus 1e-3 / 2 * sum a_i^2 (keeps rows without detections finite).
    """
    k, n = np.asarray(k, dtype=np.float64), np.asarray(n, dtype=np.float64)
    nr, nb = n.shape
    row = np.clip((k.sum(1) + 0.5) / (n.sum(1) + 1.0), 1e-4, 1 - 1e-4)
    theta = np.concatenate([np.log(row / (1 - row)), np.zeros(nb)])
    pen = np.concatenate([np.full(nr, 1e-3), np.full(nb, ridge)])

    def objective(th: np.ndarray) -> float:
        eta = th[:nr, None] + th[None, nr:]
        return float((k * eta - n * np.logaddexp(0.0, eta)).sum() - 0.5 * (pen * th * th).sum())

    f = objective(theta)
    for _ in range(iterations):  # Newton on R + B parameters: converges in a few steps
        eta = theta[:nr, None] + theta[None, nr:]
        p = expit(eta)
        res = k - n * p
        w = n * p * (1 - p)
        g = np.concatenate([res.sum(1), res.sum(0)]) - pen * theta
        h = np.zeros((nr + nb, nr + nb))
        h[:nr, :nr] = np.diag(w.sum(1))
        h[nr:, nr:] = np.diag(w.sum(0))
        h[:nr, nr:] = w
        h[nr:, :nr] = w.T
        h += np.diag(pen)
        step = np.linalg.solve(h, g)
        t = 1.0
        while t > 1e-4:
            cand = theta + t * step
            fc = objective(cand)
            if fc >= f - 1e-12:
                break
            t /= 2
        theta, f_old, f = cand, f, fc
        if abs(f - f_old) < 1e-10 * max(1.0, abs(f)):
            break
    return expit(theta[:nr, None] + theta[None, nr:])


def fit_grid(pairs: pd.DataFrame, re_: np.ndarray, be: np.ndarray, kind: str, cfg: PdModelConfig) -> PdTable:
    """A range x bearing table (``additive_logit`` or ``cells_shrunk``) fitted to pairs (range, bearing, detected)."""
    skeleton = PdTable(covariate="range_bearing", edges=re_.tolist(), bearing_edges=be.tolist(), pd=np.zeros((re_.size - 1, be.size - 1)).tolist())
    cells = cell_index(skeleton, pairs)
    n, k = _counts(cells, pairs["detected"].to_numpy(bool), n_cells(skeleton))
    shape = (re_.size - 1, be.size - 1)
    n2, k2 = n.reshape(shape), k.reshape(shape)
    p_add = fit_additive_logit(k2, n2, cfg.ridge)
    if kind == "additive_logit":
        p, extra = p_add, {}
    elif kind == "cells_shrunk":
        p, extra = (k2 + cfg.shrinkage * p_add) / (n2 + cfg.shrinkage), {"shrinkage": cfg.shrinkage}
    else:
        raise ValueError(f"unknown grid model {kind!r}")
    lo, hi = wilson(k2, n2)
    return PdTable(
        covariate="range_bearing",
        edges=re_.tolist(),
        bearing_edges=be.tolist(),
        pd=p.tolist(),
        counts=n2.tolist(),
        detections=k2.tolist(),
        wilson_low=np.nan_to_num(lo, nan=0.0).tolist(),
        wilson_high=np.nan_to_num(hi, nan=1.0).tolist(),
        clamping=f"range >= {re_[-2]:g} m uses the last row (>= {cfg.table.min_count} pairs); bearing outside the edges: P_D = 0",
        model=kind,
        **extra,
    )


def fit_candidate(kind: str, pairs: pd.DataFrame, re_: np.ndarray, be: np.ndarray, cfg: PdModelConfig) -> PdTable:
    if kind == "range":
        return fit_pd_table(pairs["range"].to_numpy(), pairs["detected"].to_numpy(bool), "range", cfg.table)
    return fit_grid(pairs, re_, be, kind, cfg)


def choose_pd_model(pairs: pd.DataFrame, fold: np.ndarray, folds_label: str, fov: float, cfg: PdModelConfig) -> PdTable:
    """The candidate with the best mean held-out Bernoulli log-likelihood, refitted on all pairs.

    pairs: columns range [m], bearing [rad, sensor frame], detected (bool); fold (N,)
    the fold of each pair. With a single fold the first candidate is fitted without
    a choice. The returned table carries the :class:`Selection` record.
    """
    fold = np.asarray(fold)
    re_, be = grid_edges(pairs["range"].to_numpy(), fov, cfg)
    ids = np.unique(fold)
    cands = list(dict.fromkeys(cfg.candidates))
    if ids.size < 2 or len(cands) == 1:
        return fit_candidate(cands[0], pairs, re_, be, cfg)
    ll = np.zeros(len(cands))
    y = pairs["detected"].to_numpy(bool)
    for f in ids:  # folds: a handful
        test = fold == f
        train = pairs[~test]
        if not train["detected"].any():
            continue
        for c, kind in enumerate(cands):
            try:
                t = fit_candidate(kind, train, re_, be, cfg)
            except DataError:  # too little data in this fold for the candidate: it loses the fold
                ll[c] += np.log(LOGLIK_CLIP) * test.sum()
                continue
            ll[c] += bernoulli_loglik(predict(t, pairs[test]), y[test]).sum()
    ll /= len(pairs)
    best = int(np.argmax(ll))
    table = fit_candidate(cands[best], pairs, re_, be, cfg)
    sel = Selection(folds=folds_label, candidates=cands, loglik=ll.tolist(), items=len(pairs), chosen=cands[best])
    return updated(table, {"selection": sel})


# ------------------------------------------------------------------------------------------ pooling


def beta_binomial_concentration(k: np.ndarray, n: np.ndarray, p: np.ndarray, bounds: tuple[float, float] = (0.1, 1e6)) -> float | None:
    """m of Beta(m p_c, m (1 - p_c)) maximising the beta-binomial likelihood of k, n (S, C) around p (C,) or (S, C).

    None when the likelihood keeps rising to the upper bound: the sensors agree
    within binomial noise (complete pooling).
    """
    k, n = np.asarray(k, dtype=np.float64), np.asarray(n, dtype=np.float64)
    p = np.clip(np.asarray(p, dtype=np.float64), LOGLIK_CLIP, 1 - LOGLIK_CLIP)
    p = p[None, :] if p.ndim == 1 else p
    use = n > 0
    if not use.any():
        return None
    kk, nn = k[use], n[use]
    pp = np.broadcast_to(p, n.shape)[use]

    def nll(log_m: float) -> float:
        m = float(np.exp(log_m))
        a, b = m * pp, m * (1 - pp)
        return -float((betaln(kk + a, nn - kk + b) - betaln(a, b)).sum())

    lo, hi = np.log(bounds[0]), np.log(bounds[1])
    res = minimize_scalar(nll, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
    if res.x > hi - 0.05 or nll(hi) <= res.fun:
        return None
    return float(np.exp(res.x))


def design_effect(y: np.ndarray, p: np.ndarray, cluster: np.ndarray | None) -> float:
    """How much correlated outcomes inflate the variance of a mean detection rate (>= 1).

    The cluster-robust variance of the mean residual (y - p), residuals centred,
    over the binomial variance sum p (1 - p) / N^2. Clusters group pairs whose
    outcomes go together (one landmark over a few seconds: a landmark that was
    detected tends to be detected again). 1 without clusters.
    """
    if cluster is None or y.size < 2:
        return 1.0
    res = y.astype(np.float64) - p
    res = res - res.mean()
    _, c = np.unique(cluster, return_inverse=True)
    sums = np.bincount(c, weights=res)
    v_binom = float((p * (1 - p)).sum())
    if v_binom <= 0:
        return 1.0
    return max(1.0, float((sums**2).sum()) / v_binom)


def sensor_offset(k: np.ndarray, n: np.ndarray, p: np.ndarray, iterations: int = 30) -> tuple[float, float]:
    """(u, s.e.) of the logit offset u maximising sum_c binomial(k_c | n_c, sigmoid(logit p_c + u)).

    k, n (C,) a sensor's (possibly deflated) counts per cell; p (C,) the pooled P_D.
    Newton's method on one parameter; u is clipped to [-6, 6] (a sensor that never
    or always detects).
    """
    eta = np.log(np.clip(p, LOGLIK_CLIP, 1 - LOGLIK_CLIP) / (1 - np.clip(p, LOGLIK_CLIP, 1 - LOGLIK_CLIP)))
    u = 0.0
    info = 0.0
    for _ in range(iterations):
        q = expit(eta + u)
        g = float((k - n * q).sum())
        info = float((n * q * (1 - q)).sum())
        if info <= 0:
            return 0.0, float("inf")
        step = g / info
        u = float(np.clip(u + step, -6.0, 6.0))
        if abs(step) < 1e-10:
            break
    return u, float(1 / np.sqrt(info)) if info > 0 else float("inf")


@dataclass
class Pooling:
    """Per-sensor figures and partially pooled tables (see :func:`pool_sensors`)."""

    names: list[str]
    pairs: list[int]
    pd_observed: list[float]
    pd_predicted: list[float]
    offsets: list[float]  # each sensor's logit offset, shrunk
    offset_sd: float  # tau: the spread of the sensors' logit offsets beyond their sampling error
    concentration: float | None
    between_sd: float
    tables: list[PdTable]
    design_effects: list[float]


def pool_sensors(pooled: PdTable, pairs: pd.DataFrame, sensor: np.ndarray, names: list[str], cluster: np.ndarray | None = None) -> Pooling:
    """Partial pooling of the pooled table toward each sensor, in two levels.

    pairs: the pooled table's covariate columns and ``detected``; sensor (N,) index
    into ``names``; cluster (N,) optional groups of correlated pairs.

    1. Each sensor's counts are divided by its design effect (:func:`design_effect`):
       its pairs carry that much less information than as many independent trials.
    2. A sensor is more or less sensitive everywhere (a camera's gain, focus):
       logit P_D_s = logit p_c + u_s. Each u_s is fitted (:func:`sensor_offset`)
       with its standard error se_s; the offsets' spread beyond sampling error is
       tau^2 = max(0, var(u) - mean(se^2)) (method of moments) and each offset is
       shrunk by tau^2 / (tau^2 + se_s^2) -- a sensor with little data keeps little
       of its own offset.
    3. What the offset leaves, cell by cell: a beta prior centred on the shifted
       table q_sc, its concentration m from the beta-binomial likelihood
       (:func:`beta_binomial_concentration`); the member's value is
       (k' + m q_sc) / (n' + m) with k', n' the deflated counts, or q_sc itself when
       the cells agree within their noise.

    Each member table keeps the pooled layout (``model: partial_pooling``,
    ``shrinkage`` = m, None when the cells are pooled completely).
    """
    sensor = np.asarray(sensor)
    y = pairs["detected"].to_numpy(bool)
    cells = cell_index(pooled, pairs)
    size = n_cells(pooled)
    shape = np.asarray(pooled.pd).shape
    p = np.asarray(pooled.pd, dtype=np.float64).ravel()
    pred = predict(pooled, pairs)
    ks, ns, deffs = [], [], []
    for s in range(len(names)):
        w = sensor == s
        n, k = _counts(np.where(w, cells, -1), y, size)
        ns.append(n)
        ks.append(k)
        deffs.append(design_effect(y[w], pred[w], None if cluster is None else np.asarray(cluster)[w]))
    k_all, n_all = np.array(ks, dtype=np.float64), np.array(ns, dtype=np.float64)
    d = np.array(deffs)[:, None]
    kd, nd = k_all / d, n_all / d
    fits = [sensor_offset(kd[s], nd[s], p) for s in range(len(names))]
    u, se = np.array([f[0] for f in fits]), np.array([f[1] for f in fits])
    finite = np.isfinite(se)
    tau2 = max(0.0, float(u[finite].var(ddof=1)) - float(np.mean(se[finite] ** 2))) if finite.sum() > 1 else 0.0
    shrunk = np.where(finite, u * tau2 / (tau2 + np.where(finite, se, 1.0) ** 2), 0.0) if tau2 > 0 else np.zeros_like(u)
    eta = np.log(np.clip(p, LOGLIK_CLIP, 1 - LOGLIK_CLIP) / (1 - np.clip(p, LOGLIK_CLIP, 1 - LOGLIK_CLIP)))
    q = expit(eta[None, :] + u[:, None])  # each sensor's own offset, to measure what is left cell by cell
    m = beta_binomial_concentration(kd, nd, q)
    overall = float(y.mean()) if y.size else 0.0
    cell_var = 0.0 if m is None else overall * (1 - overall) / (m + 1)
    between = float(np.sqrt((overall * (1 - overall)) ** 2 * tau2 + cell_var))
    tables = []
    for s in range(len(names)):
        n, k = n_all[s], k_all[s]
        lo, hi = wilson(k, n)
        qs = expit(eta + shrunk[s])
        vals = qs if m is None else (kd[s] + m * qs) / (nd[s] + m)
        upd = {
            "pd": vals.reshape(shape).tolist(),
            "counts": n.astype(np.int64).reshape(shape).tolist(),
            "detections": k.astype(np.int64).reshape(shape).tolist(),
            "wilson_low": np.nan_to_num(lo, nan=0.0).reshape(shape).tolist(),
            "wilson_high": np.nan_to_num(hi, nan=1.0).reshape(shape).tolist(),
            "between_sensor_sd": None,
            "selection": None,
            "model": "partial_pooling",
            "shrinkage": m,
            "clamping": f"{pooled.clamping}; partially pooled: logit offset {shrunk[s]:+.3g} (own {u[s]:+.3g}, tau {np.sqrt(tau2):.3g}), "
            f"cells with m = {m if m is None else round(m, 4)}, counts / design effect {deffs[s]:.3g}",
        }
        tables.append(PdTable.model_validate({**pooled.model_dump(), **upd}))
    sel = [sensor == s for s in range(len(names))]
    return Pooling(
        names=list(names),
        pairs=[int(w.sum()) for w in sel],
        pd_observed=[float(y[w].mean()) if w.any() else float("nan") for w in sel],
        pd_predicted=[float(pred[w].mean()) if w.any() else float("nan") for w in sel],
        offsets=shrunk.tolist(),
        offset_sd=float(np.sqrt(tau2)),
        concentration=m,
        between_sd=between,
        tables=tables,
        design_effects=deffs,
    )


def between_sensor_sd(pooled: PdTable, pool: Pooling) -> list:
    """Per bin the spread of the sensors' P_D the two-level prior implies:
    sqrt((p (1 - p) tau)^2 + p (1 - p) / (m + 1)) (the offset by the delta method, then the cells)."""
    p = np.asarray(pooled.pd, dtype=np.float64)
    v = (p * (1 - p) * pool.offset_sd) ** 2
    if pool.concentration is not None:
        v = v + p * (1 - p) / (pool.concentration + 1)
    return np.sqrt(v).tolist()


def shrink_rates(counts: list[np.ndarray], n_batches: int = 20) -> tuple[float, float, list[float], list[float]]:
    """Clutter rates of several sensors pooled partially (a random-effects mean, method of moments).

    counts: per sensor, false alarms per frame (F_s,). Each sensor's rate r_s has a
    sampling variance v_s from batch means (frames are correlated); the spread of
    the rates beyond it is tau^2 = max(0, var(r_s) - mean(v_s)). A sensor's own
    weight is w_s = tau^2 / (tau^2 + v_s). Returns (pooled rate over all frames, tau,
    weights, member rates w_s r_s + (1 - w_s) pooled).
    """
    from calib.clutter import batch_means_ci

    rates, var = [], []
    for c in counts:
        m, lo, hi = batch_means_ci(c, n_batches)
        rates.append(m)
        var.append(((hi - lo) / 2 / 1.96) ** 2 if np.isfinite(lo) else np.inf)
    total = float(np.concatenate(counts).mean())
    r, v = np.array(rates), np.array(var)
    tau2 = max(0.0, float(r.var(ddof=1)) - float(np.mean(v[np.isfinite(v)]))) if r.size > 1 and np.isfinite(v).any() else 0.0
    w = np.where(np.isfinite(v), tau2 / (tau2 + v), 0.0) if tau2 > 0 else np.zeros(r.size)
    return total, float(np.sqrt(tau2)), w.tolist(), (w * r + (1 - w) * total).tolist()
