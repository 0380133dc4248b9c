"""Clutter beyond the Poisson rate: counts per frame and where false alarms fall.

The thesis (sec. 4.2, ch. 6, fig. 6.4) fits a Poisson rate to the false alarms
per scan and reports Pearson's chi-square test, which rejects it (p = 2e-240 on
its park data); the PHD filter needs only the mean. This module goes further:

* :func:`fit_negative_binomial` -- the Poisson-gamma mixture (negative binomial
  with mean mu and shape r, variance mu + mu^2 / r) by maximum likelihood: mu is
  the sample mean, r maximises the profile likelihood;
* :func:`dispersion_test` -- the likelihood ratio of the negative binomial
  against the Poisson; r = infinity lies on the boundary of the parameter space,
  so the statistic is a 50:50 mixture of 0 and chi-square(1) under the Poisson
  (Self & Liang 1987) and p = 0.5 P(chi2_1 > LR);
* :func:`pearson` -- Pearson's chi-square of counts against any count model,
  bins merged until every expected count is at least 5;
* :func:`fit_density` -- the density of false alarms over (range, bearing): a
  histogram smoothed toward the uniform density by Dirichlet pseudo-counts, the
  amount chosen by held-out log-likelihood (the uniform density of the thesis is
  one of the candidates). Where clutter falls depends on the environment as
  much as on the sensor (bushes near the path, other robots in one room), so
  by default the choice is made across logs: a density is adopted only when it
  predicts a log it was not fitted to. Time blocks of one log share one
  environment and would adopt a density that may not transfer (on request);
* :func:`batch_means_ci` -- a confidence interval for a mean per frame that
  survives the frames' correlation (clutter sources stay in view for many
  frames), from the means of contiguous batches.

Frames are not independent (a bush or another robot stays in view), so the
tests on counts over-reject for correlated data; the batch-means interval is
the honest measure of how well a rate is known.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.special import gammaln
from scipy.stats import chi2, nbinom, poisson
from scipy.stats import t as student_t

from profiles.errors import DataError
from profiles.parameters import ClutterModelConfig
from profiles.schema import ClutterDensity, CountTest, Selection


def _loglik_poisson(values: np.ndarray, weights: np.ndarray, mu: float) -> float:
    return float((weights * poisson.logpmf(values, mu)).sum())


def _loglik_nb(values: np.ndarray, weights: np.ndarray, mu: float, r: float) -> float:
    ll = gammaln(values + r) - gammaln(r) - gammaln(values + 1) + r * np.log(r / (r + mu)) + values * np.log(mu / (r + mu))
    return float((weights * ll).sum())


@dataclass(frozen=True)
class NegBinFit:
    mean: float
    size: float | None  # None: no over-dispersion (the Poisson limit r -> infinity)
    loglik: float
    loglik_poisson: float


def fit_negative_binomial(counts: np.ndarray) -> NegBinFit:
    """Maximum-likelihood negative binomial for counts per frame (N,) non-negative integers.

    The mean is the sample mean; the shape r maximises the profile likelihood
    over log r in [-7, 14]. Under-dispersed or Poisson-like data give ``size=None``.
    """
    counts = np.asarray(counts, dtype=np.int64)
    if counts.size == 0:
        raise DataError("no frames to fit clutter counts to")
    values, weights = np.unique(counts, return_counts=True)
    values, weights = values.astype(np.float64), weights.astype(np.float64)
    mu = float(counts.mean())
    llp = _loglik_poisson(values, weights, mu) if mu > 0 else 0.0
    if mu == 0 or counts.var() <= mu:
        return NegBinFit(mu, None, llp, llp)
    res = minimize_scalar(lambda lr: -_loglik_nb(values, weights, mu, float(np.exp(lr))), bounds=(-7.0, 14.0), method="bounded", options={"xatol": 1e-6})
    r = float(np.exp(res.x))
    ll = -float(res.fun)
    if ll <= llp or res.x > 13.9:
        return NegBinFit(mu, None, llp, llp)
    return NegBinFit(mu, r, ll, llp)


def dispersion_test(fit: NegBinFit) -> CountTest:
    """Likelihood ratio of the negative binomial against the Poisson (boundary-corrected, 1 parameter)."""
    lr = max(0.0, 2.0 * (fit.loglik - fit.loglik_poisson))
    p = 1.0 if lr <= 0.0 else float(0.5 * chi2.sf(lr, 1))
    return CountTest(test="likelihood ratio, negative binomial vs Poisson", statistic=lr, dof=1, p_value=p)


def merge_bins(observed: np.ndarray, expected: np.ndarray, min_expected: float = 5.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Neighbouring count bins merged until each expects at least ``min_expected``; (low, observed, expected)."""
    lows, o_m, e_m = [], [], []
    cur_o = cur_e = 0.0
    start = 0
    for k in range(observed.size):  # at most max(count) + 1 bins
        cur_o += observed[k]
        cur_e += expected[k]
        if cur_e >= min_expected:
            lows.append(start), o_m.append(cur_o), e_m.append(cur_e)
            cur_o = cur_e = 0.0
            start = k + 1
    if cur_e > 0 or cur_o > 0:
        if e_m:
            o_m[-1] += cur_o
            e_m[-1] += cur_e
        else:
            lows.append(start), o_m.append(cur_o), e_m.append(cur_e)
    return np.array(lows, dtype=np.int64), np.array(o_m), np.array(e_m)


@dataclass(frozen=True)
class PearsonResult:
    chi2: float
    dof: int
    p_value: float
    bin_low: np.ndarray
    observed: np.ndarray
    expected: np.ndarray


def pearson(counts: np.ndarray, pmf, sf, fitted: int) -> PearsonResult:
    """Pearson's chi-square of counts per frame against a count model.

    pmf(k), sf(k) = P(X > k) of the model; the upper tail is pooled into the last
    bin; ``fitted`` parameters estimated from these counts reduce the degrees of
    freedom (bins - 1 - fitted). NaN statistic when fewer than 1 dof remain.
    """
    counts = np.asarray(counts, dtype=np.int64)
    n = counts.size
    kmax = int(counts.max()) if n else 0
    obs = np.bincount(counts, minlength=kmax + 1).astype(np.float64)
    pk = np.asarray(pmf(np.arange(kmax + 1)), dtype=np.float64)
    pk[-1] = float(sf(kmax - 1)) if kmax > 0 else 1.0  # P(X >= kmax)
    lows, o_m, e_m = merge_bins(obs, n * pk)
    dof = int(o_m.size - 1 - fitted)
    if dof < 1:
        return PearsonResult(float("nan"), dof, float("nan"), lows, o_m, e_m)
    stat = float(((o_m - e_m) ** 2 / e_m).sum())
    return PearsonResult(stat, dof, float(chi2.sf(stat, dof)), lows, o_m, e_m)


def nb_pmf_sf(mu: float, r: float):
    p = r / (r + mu)
    return (lambda k: nbinom.pmf(k, r, p)), (lambda k: nbinom.sf(k, r, p))


def batch_means_ci(values: np.ndarray, n_batches: int = 20, level: float = 0.95) -> tuple[float, float, float]:
    """(mean, low, high): a t interval from the means of ``n_batches`` contiguous batches.

    Batches of consecutive frames absorb the correlation between neighbouring
    frames that a naive interval (s / sqrt(N)) ignores. Fewer than 2 batches of
    at least 2 frames: (mean, NaN, NaN).
    """
    v = np.asarray(values, dtype=np.float64)
    m = float(v.mean()) if v.size else float("nan")
    b = min(n_batches, v.size // 2)
    if b < 2:
        return m, float("nan"), float("nan")
    size = v.size // b
    means = v[: b * size].reshape(b, size).mean(axis=1)
    half = float(student_t.ppf(0.5 + level / 2, b - 1) * means.std(ddof=1) / np.sqrt(b))
    return m, m - half, m + half


def batch_se(x: np.ndarray, batches: int = 20) -> np.ndarray:
    """Standard error of the mean of x (..., F) along its last axis from ``batches`` contiguous batches (NaN under 2)."""
    f = x.shape[-1]
    b = min(batches, f // 2)
    if b < 2:
        return np.full(x.shape[:-1], np.nan)
    size = f // b
    means = x[..., : b * size].reshape(*x.shape[:-1], b, size).mean(axis=-1)
    return means.std(axis=-1, ddof=1) / np.sqrt(b)


def rate_standard_error(counts: np.ndarray, batches: int = 20) -> float | None:
    """Standard error of a clutter rate measured on counts per frame (F,) (batch means); None when too few frames."""
    se = float(batch_se(np.asarray(counts, dtype=np.float64), batches))
    return se if np.isfinite(se) else None


# ---------------------------------------------------------------------------------------------- density


def grid_edges(lo_r: float, hi_r: float, lo_b: float, hi_b: float, nr: int, nb: int) -> tuple[np.ndarray, np.ndarray]:
    return np.linspace(lo_r, hi_r, nr + 1), np.linspace(lo_b, hi_b, nb + 1)


def _cell_counts(r: np.ndarray, b: np.ndarray, re_: np.ndarray, be: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(counts (nr, nb), inside (N,)) of points in the grid."""
    inside = (r >= re_[0]) & (r <= re_[-1]) & (b >= be[0]) & (b <= be[-1])
    i = np.clip(np.searchsorted(re_, r[inside], side="right") - 1, 0, re_.size - 2)
    j = np.clip(np.searchsorted(be, b[inside], side="right") - 1, 0, be.size - 2)
    c = np.bincount(i * (be.size - 1) + j, minlength=(re_.size - 1) * (be.size - 1)).reshape(re_.size - 1, be.size - 1)
    return c, inside


def smoothed_density(counts: np.ndarray, re_: np.ndarray, be: np.ndarray, a: float) -> np.ndarray:
    """Density [1 / (m rad)] per cell: (n_c + a_tot u_c) / (N + a_tot) / area_c, with a_tot = a x cells.

    u_c = area_c / area is the uniform share; ``a`` pseudo-counts per cell on
    average, spread by area (a Dirichlet prior centred on the uniform density).
    """
    area = np.diff(re_)[:, None] * np.diff(be)[None, :]
    total_area = float(area.sum())
    a_tot = a * counts.size
    share = (counts + a_tot * area / total_area) / (counts.sum() + a_tot)
    return share / area


def fit_density(
    r: np.ndarray, b: np.ndarray, fold: np.ndarray, re_: np.ndarray, be: np.ndarray, cfg: ClutterModelConfig, folds_label: str
) -> ClutterDensity:
    """The clutter density over the grid, its smoothing chosen by held-out log-likelihood.

    r, b (N,) range [m] and bearing [rad] of the false alarms (sensor frame);
    fold (N,) fold of each (sensor or time block). Candidates: the uniform
    density and the histogram with each of ``cfg.smoothing`` pseudo-counts per
    cell; each is fitted on all folds but one and scored on the one left out
    (mean log density per held-out false alarm). With one fold (or none of the
    false alarms inside the grid) the uniform density is kept without a choice.
    The uniform choice is written as a one-cell grid, so the record of the
    choice stays in the profile.
    """
    r, b, fold = np.asarray(r, dtype=np.float64), np.asarray(b, dtype=np.float64), np.asarray(fold)
    counts, inside = _cell_counts(r, b, re_, be)
    r, b, fold = r[inside], b[inside], fold[inside]
    ids = np.unique(fold)
    uniform = np.full((1, 1), 1.0 / float((re_[-1] - re_[0]) * (be[-1] - be[0])))
    one = ([float(re_[0]), float(re_[-1])], [float(be[0]), float(be[-1])])
    if ids.size < 2 or r.size == 0:
        return ClutterDensity(range_edges=one[0], bearing_edges=one[1], density=uniform.tolist(), counts=[[int(r.size)]], smoothing=0.0)
    names = ["uniform", *(f"histogram a={a:g}" for a in cfg.smoothing)]
    ll = np.zeros(len(names))
    for f in ids:  # folds: a handful
        test = fold == f
        c_train, _ = _cell_counts(r[~test], b[~test], re_, be)
        i = np.clip(np.searchsorted(re_, r[test], side="right") - 1, 0, re_.size - 2)
        j = np.clip(np.searchsorted(be, b[test], side="right") - 1, 0, be.size - 2)
        ll[0] += test.sum() * np.log(uniform[0, 0])
        for k, a in enumerate(cfg.smoothing, start=1):
            d = smoothed_density(c_train, re_, be, a)
            ll[k] += np.log(d[i, j]).sum()
    ll /= r.size
    best = int(np.argmax(ll))
    sel = Selection(folds=folds_label, candidates=names, loglik=ll.tolist(), items=int(r.size), chosen=names[best])
    if best == 0:
        return ClutterDensity(range_edges=one[0], bearing_edges=one[1], density=uniform.tolist(), counts=[[int(r.size)]], smoothing=0.0, selection=sel)
    a = cfg.smoothing[best - 1]
    d = smoothed_density(counts, re_, be, a)
    d = d / float((d * np.diff(re_)[:, None] * np.diff(be)[None, :]).sum())  # exact unit mass after rounding
    return ClutterDensity(range_edges=re_.tolist(), bearing_edges=be.tolist(), density=d.tolist(), counts=counts.tolist(), smoothing=float(a), selection=sel)


def density_summary(density: ClutterDensity | None) -> str:
    """One line for a summary: what the clutter density is and how it was chosen."""
    if density is None:
        return "uniform (not tried: one log; clutter.density: always tries time blocks)"
    if density.selection is None:
        return "uniform (one fold: no held-out choice)"
    return f"{density.selection.chosen} (held out over {density.selection.folds})"


def density_loglik(density: ClutterDensity, r: np.ndarray, b: np.ndarray) -> tuple[float, int]:
    """(mean log density [log 1/(m rad)] of points inside the density's grid, how many were inside)."""
    d = density.at(np.asarray(r), np.asarray(b))
    ok = d > 0
    return (float(np.log(d[ok]).mean()) if ok.any() else float("nan")), int(ok.sum())


def time_folds(n: int, k: int) -> np.ndarray:
    """(n,) fold of each of n time-ordered items: k contiguous blocks of (nearly) equal size."""
    return np.minimum((np.arange(n) * k) // max(n, 1), k - 1)
