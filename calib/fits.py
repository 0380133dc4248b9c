"""The fits of a calibration (Inostroza 2015, sec. 4.2, ch. 5-6).

* :func:`fit_hotelling` -- mean and covariance of true detections' descriptors,
  gamma from the chi-square quantile at the chosen confidence (eq. 5.4);
* :func:`roc_curves` -- ROC of the Hotelling score beside Fisher's linear
  discriminant, with both AUCs (fig. 5.5);
* :func:`fit_pd_table` -- P_D per covariate bin (eq. 6.2) with counts, 95 %
  Wilson intervals and the thesis's clamping (ch. 6);
* :func:`fit_clutter` -- Poisson rate of false alarms per scan (maximum
  likelihood: the mean), Pearson chi-square goodness of fit, p-value and
  dispersion index (sec. 6.1, fig. 6.4); the negative binomial and its
  dispersion test when the counts are over-dispersed (:mod:`calib.clutter`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2, poisson, rankdata

from calib.clutter import dispersion_test, fit_negative_binomial, nb_pmf_sf, pearson, rate_standard_error
from detectors.circle import mahalanobis2 as maha2
from profiles.errors import DataError
from profiles.parameters import PdFitConfig
from profiles.schema import PD_COVARIATES, ClutterDensity, ClutterParams, CountTest, PdTable

Z95 = 1.959963984540054


def wilson(k: np.ndarray, n: np.ndarray, z: float = Z95) -> tuple[np.ndarray, np.ndarray]:
    """95 % Wilson score interval for k successes in n trials (NaN where n = 0)."""
    k = np.asarray(k, dtype=np.float64)
    n = np.asarray(n, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        p = k / n
        den = 1 + z * z / n
        centre = (p + z * z / (2 * n)) / den
        half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return centre - half, centre + half


def fit_pd_table(values: np.ndarray, detected: np.ndarray, covariate: str, cfg: PdFitConfig, runs: int = 1) -> PdTable:
    """P_D against ``n_p`` (integer bins) or ``range`` (bins of ``cfg.range_bin``), eq. 6.2.

    values (M,) covariate of each (landmark, scan) pair; detected (M,) bool: C(m, j).
    ``runs``: the pairs are ``runs`` measurements of the same detections pooled (a self-calibration's
    averaged runs, each against its own map): P_D is the pooled rate, but ``min_count`` applies per run
    and the counts, detections and Wilson intervals are those of one run (pooled / runs), since the runs
    add no detections; a bin with any pairs keeps a count of at least 1.
    """
    if runs < 1:
        raise ValueError(f"runs must be at least 1, got {runs}")
    values = np.asarray(values, dtype=np.float64)
    detected = np.asarray(detected, dtype=bool)
    if values.size == 0:
        raise DataError("no (landmark, scan) pairs to fit P_D to: are the landmarks ever in view?")
    if PD_COVARIATES.get(covariate).integer:  # one bin per count
        edges = np.arange(0, int(values.max()) + 2, dtype=np.float64)
    else:
        edges = np.arange(0.0, values.max() + cfg.range_bin, cfg.range_bin)
        if edges.size < 2:
            edges = np.array([0.0, cfg.range_bin])
    idx = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, edges.size - 2)
    n = np.bincount(idx, minlength=edges.size - 1)
    k = np.bincount(idx, weights=detected, minlength=edges.size - 1).astype(np.int64)
    per_run = " per run" if runs > 1 else ""
    well = np.flatnonzero(n >= cfg.min_count * runs)
    if well.size == 0:
        raise DataError(f"no P_D bin holds {cfg.min_count} pairs{per_run}; lower pd.min_count in the --config file or calibrate on more data")
    last = int(well[-1])
    if cfg.tail == "pool":
        n[last] = n[last:].sum()
        k[last] = k[last:].sum()
    n, k = n[: last + 1], k[: last + 1]
    edges = edges[: last + 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        raw = np.where(n > 0, k / n, 0.0)
    pd = np.where(raw < cfg.zero_below, 0.0, raw)
    lo, hi = wilson(k / runs, n / runs)  # one run's sample size, centred on the pooled rate
    n_run = np.where(n > 0, np.maximum(np.rint(n / runs), 1), 0).astype(np.int64)
    k_run = np.minimum(np.rint(k / runs), n_run).astype(np.int64)
    unit = covariate if PD_COVARIATES.get(covariate).integer else "range"
    pooled = f"{runs} runs of the same detections pooled, counts per run; " if runs > 1 else ""
    return PdTable(
        covariate=covariate,
        edges=edges.tolist(),
        pd=pd.tolist(),
        counts=n_run.tolist(),
        detections=k_run.tolist(),
        wilson_low=np.nan_to_num(lo, nan=0.0).tolist(),
        wilson_high=np.nan_to_num(hi, nan=1.0).tolist(),
        clamping=(
            f"{pooled}{unit} >= {edges[last]:g} uses the last well-populated bin (>= {cfg.min_count} pairs{per_run}, "
            f"tail={cfg.tail}); P_D < {cfg.zero_below:g} set to 0"
        ),
    )


@dataclass(frozen=True)
class HotellingFit:
    names: tuple[str, ...]
    mean: np.ndarray
    cov: np.ndarray
    gamma: float
    confidence: float
    samples: int


def fit_hotelling(desc: np.ndarray, names: tuple[str, ...], confidence: float) -> HotellingFit:
    """Eq. 5.4: the ellipsoid of true detections' descriptors (D, d) at ``confidence``."""
    desc = np.asarray(desc, dtype=np.float64)
    d = len(names)
    if desc.shape[0] <= d + 1:
        raise DataError(f"only {desc.shape[0]} true detections: too few to fit a {d}-D Hotelling ellipsoid")
    mean = desc.mean(axis=0)
    cov = np.cov(desc, rowvar=False).reshape(d, d)
    if np.linalg.eigvalsh(cov).min() <= 1e-18 * max(1.0, np.abs(cov).max()):
        raise DataError("the true detections' descriptors are degenerate (a descriptor does not vary)")
    return HotellingFit(tuple(names), mean, cov, float(chi2.ppf(confidence, d)), confidence, int(desc.shape[0]))


def auc(score_true: np.ndarray, score_false: np.ndarray) -> float:
    """Area under the ROC curve = P(score of a true > score of a false), ties counted half (Mann-Whitney)."""
    nt, nf = score_true.size, score_false.size
    if nt == 0 or nf == 0:
        return float("nan")
    r = rankdata(np.concatenate([score_true, score_false]))
    return float((r[:nt].sum() - nt * (nt + 1) / 2) / (nt * nf))


def roc(score_true: np.ndarray, score_false: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(false-positive rate, true-positive rate) over every threshold, from the strictest down."""
    s = np.concatenate([score_true, score_false])
    lab = np.concatenate([np.ones(score_true.size), np.zeros(score_false.size)])
    order = np.argsort(-s, kind="stable")
    tp = np.concatenate([[0], np.cumsum(lab[order])])
    fp = np.concatenate([[0], np.cumsum(1 - lab[order])])
    return fp / max(1, score_false.size), tp / max(1, score_true.size)


def fisher_direction(desc_true: np.ndarray, desc_false: np.ndarray) -> np.ndarray:
    """Fisher's linear discriminant w = (S_t + S_f)^-1 (mu_t - mu_f)."""
    sw = np.cov(desc_true, rowvar=False) + np.cov(desc_false, rowvar=False)
    sw = np.atleast_2d(sw)
    return np.linalg.lstsq(sw, desc_true.mean(axis=0) - desc_false.mean(axis=0), rcond=None)[0]


def roc_curves(desc_true: np.ndarray, desc_false: np.ndarray, fit: HotellingFit) -> dict:
    """ROC curves and AUCs of the Hotelling score (-Mahalanobis^2) and Fisher's discriminant.

    Both are measured on the calibration data itself (in-sample), as in the thesis's fig. 5.5.
    """
    h_t, h_f = -maha2(desc_true, fit.mean, fit.cov), -maha2(desc_false, fit.mean, fit.cov)
    if desc_false.shape[0] > desc_false.shape[1]:
        w = fisher_direction(desc_true, desc_false)
        f_t, f_f = desc_true @ w, desc_false @ w
    else:
        f_t, f_f = np.zeros(desc_true.shape[0]), np.zeros(desc_false.shape[0])
    return {
        "hotelling": roc(h_t, h_f),
        "fisher": roc(f_t, f_f),
        "auc_hotelling": auc(h_t, h_f),
        "auc_fisher": auc(f_t, f_f),
    }


@dataclass(frozen=True)
class ClutterFit:
    rate: float
    counts: np.ndarray
    chi2: float
    dof: int
    p_value: float
    dispersion: float
    observed: np.ndarray  # per merged bin
    expected: np.ndarray
    bin_low: np.ndarray  # smallest count of each merged bin (the last is open-ended)
    size: float | None = None  # negative binomial shape r (None: no over-dispersion)
    dispersion_test: CountTest | None = None
    nb_gof: CountTest | None = None
    count_model: str = "poisson"


def fit_clutter(counts: np.ndarray, level: float = 0.05) -> ClutterFit:
    """Count model of false alarms per frame with its tests (sec. 4.2, fig. 6.4).

    The Poisson rate (the mean) with Pearson's chi-square test, as in the thesis
    (tail pooled into the last bin, neighbouring bins merged until every expected
    count is at least 5, dof = bins - 1 - 1); then the negative binomial
    (Poisson-gamma) by maximum likelihood and the likelihood-ratio dispersion
    test (:mod:`calib.clutter`). The count model is the negative binomial when
    that test rejects the Poisson at ``level``, else the Poisson.
    """
    counts = np.asarray(counts, dtype=np.int64)
    n = counts.size
    if n == 0:
        raise DataError("no scans to fit the clutter to")
    lam = float(counts.mean())
    var = float(counts.var(ddof=1)) if n > 1 else 0.0
    pois = pearson(counts, lambda k: poisson.pmf(k, lam), lambda k: poisson.sf(k, lam), fitted=1)
    nb = fit_negative_binomial(counts)
    test = dispersion_test(nb)
    gof = None
    model = "poisson"
    if nb.size is not None and test.p_value < level:
        model = "negative_binomial"
        pmf, sf = nb_pmf_sf(lam, nb.size)
        g = pearson(counts, pmf, sf, fitted=2)
        if np.isfinite(g.chi2):
            gof = CountTest(test="Pearson chi-square, negative binomial", statistic=g.chi2, dof=g.dof, p_value=g.p_value)
    return ClutterFit(
        lam, counts, pois.chi2, pois.dof, pois.p_value, var / lam if lam > 0 else float("nan"), pois.observed, pois.expected, pois.bin_low,
        size=nb.size if model == "negative_binomial" else None, dispersion_test=test, nb_gof=gof, count_model=model,
    )


def clutter_params(fit: ClutterFit, space: str, volume: float, density: ClutterDensity | None = None) -> ClutterParams:
    """The profile's clutter section, with the frames the rate was measured on and its batch-means standard error."""
    finite = np.isfinite(fit.chi2)
    return ClutterParams(
        rate=fit.rate,
        space=space,
        volume=volume,
        chi2=fit.chi2 if finite else None,
        dof=fit.dof if finite else None,
        p_value=fit.p_value if finite else None,
        dispersion=fit.dispersion if np.isfinite(fit.dispersion) else None,
        count_model=fit.count_model,
        size=fit.size,
        dispersion_test=fit.dispersion_test,
        nb_gof=fit.nb_gof,
        density=density,
        frames=int(fit.counts.size),
        rate_se=rate_standard_error(fit.counts),
    )
