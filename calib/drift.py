"""Is this profile still right for this log? Drift tests judged against the log's own sampling floor.

A validation score (an ECE, a false-alarm error) means nothing until it is set
beside what it would be if the profile were right: a log of a few minutes
cannot pin a clutter rate to 5 %, and outcomes of one landmark go together.
This module asks, part by part, whether the held-out log could have come from
the process the profile describes, known as well as its calibration knew it:

* **P_D** -- a parametric bootstrap over the log's own informative
  opportunities (pairs with predicted P_D > 0, as they are: their n_p or range
  and bearing, their landmarks). Each replicate draws the profile's P_D of every
  bin from what its calibration knew (Beta with the bin's effective count,
  :attr:`profiles.schema.PdTable.effective_counts`), then every pair's outcome
  from it, the outcomes of one landmark correlated as much as the log's own
  are (the *common-uniform* model below). The statistic: per bin, the
  observed detections minus the predicted in units of the replicates'
  standard deviation; the part's p-value is the single-step max-T over the
  bins (Westfall & Young 1993), so the bins that drifted ("where") come with
  p-values adjusted for how many were looked at. The bins tested are the
  profile's own cells, all informative pairs together, and for a range or
  range x bearing table range and bearing bins (:func:`_bins` says why an n_p
  table's range bins are only shown).
* **clutter** -- false alarms per frame: the studentised difference of the
  log's mean count from the profile's rate, its standard error from batch means
  of the log plus the profile's own (:attr:`profiles.schema.ClutterParams.rate_se`).
  Replicates are count series with the profile's count model as their marginal
  (Poisson or negative binomial: the over-dispersion) and the log's own
  autocorrelation (a Gaussian AR(1) copula whose integrated autocorrelation
  time is the log's), the rate itself drawn from its standard error.
* **noise** -- laser: the mean log mean-square residual of the true detections'
  circle fits (``log_mse``, twice the log of the range noise) against the
  profile's Hotelling mean; detection-level sensors: the robust spread (1.4826
  MAD) and median bias of range and bearing residuals against the profile's
  :class:`profiles.schema.MeasurementNoise`. Two-sample z-tests whose variances
  take the landmarks' clustering (design effect) of the held-out log and the
  profile's sample size.
* **gate coverage** -- the share of true detections outside the Hotelling
  ellipsoid against the share the calibration itself saw (``coverage``), a
  two-sample test on proportions with the same design effect. The tolerance is
  absolute (a share of 0.0075 doubling to 0.015 moves the gated P_D by less
  than a filter notices; the P_D part sees it anyway).

**The common-uniform model** of correlated outcomes: a pair's outcome is
``U < q`` with U uniform; with probability rho all pairs of one landmark share
one U, otherwise each has its own. Every pair keeps its own marginal P_D
exactly; two pairs of a landmark covary by rho (min(q_i, q_j) - q_i q_j).
rho is the moment estimate (:func:`cluster_correlation`) from the residuals
about each bin's own observed rate (so a drift of a bin's level is not taken
for correlation). In calibration the same estimate gives every bin its
effective count n / (1 + rho (sum_L m_L^2 / n - 1)) (m_L: the landmark's pairs
in the bin).

**Verdicts.** Every part of every row (one row per log and one for them
together) is one test; Holm's step-down over all of them keeps the chance that
a profile right for every log is called drifted anywhere at most ``alpha``
(the overall verdict is the worst row's, so this is the rate the issue's
"roughly 5 %" is about). A part is *drifted* when its Holm-adjusted p-value is
at most alpha; otherwise *too little data* when the drift the data would
detect with ``power`` at the Bonferroni level alpha / tests exceeds the
part's tolerance (it says how many opportunities, frames or true detections
would do, or that the profile's own uncertainty is the limit); otherwise
*consistent*.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from pydantic import BaseModel, ConfigDict, Field
from scipy.signal import lfilter
from scipy.special import ndtr, ndtri
from scipy.stats import nbinom, poisson
from scipy.stats import t as student_t

from calib.clutter import batch_se
from calib.pdmodels import cell_index
from profiles.override import updated
from profiles.schema import ClutterParams, HotellingParams, MeasurementNoise, PdTable

PARTS = ("pd", "clutter", "noise", "coverage")
LABELS = {"pd": "P_D", "clutter": "clutter", "noise": "noise", "coverage": "gate coverage"}
VERDICTS = ("consistent", "too little data", "drifted")  # in order of severity
MAD_SIGMA = 1.4826  # sigma of a Gaussian over its median absolute deviation
VAR_MEDIAN = np.pi / 2  # n var(median) / sigma^2 of a Gaussian
VAR_LOG_MAD = 1.3605  # n var(log MAD) of a Gaussian (the MAD's efficiency is 37 %)
CHUNK = 4_000_000  # random draws per block of replicates (memory ~ 5 bytes each)


class DriftConfig(BaseModel):
    """How validation judges drift; the defaults suit a log of minutes to hours."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    alpha: float = Field(default=0.05, gt=0.0, lt=0.5, description="chance of calling a right profile drifted anywhere (Holm over every test)")
    replicates: int = Field(default=1999, ge=99, le=100_000, description="bootstrap replicates (p-values down to 1 / (replicates + 1))")
    seed: int = Field(default=0, ge=0, description="seed of the bootstrap: same inputs and seed, same bytes")
    power: float = Field(default=0.8, gt=0.5, lt=1.0, description="power at which the detectable drift is stated")
    pd_tolerance: float = Field(default=0.05, gt=0.0, lt=1.0, description="smallest drift of P_D worth detecting (absolute)")
    clutter_tolerance: float = Field(default=0.25, gt=0.0, description="smallest relative change of the clutter rate worth detecting")
    noise_tolerance: float = Field(default=0.25, gt=0.0, description="smallest relative change of the noise's spread worth detecting")
    coverage_tolerance: float = Field(
        default=0.01, gt=0.0, lt=1.0, description="smallest change of the share of true detections outside the gate worth detecting (absolute)"
    )
    range_bins: int = Field(default=8, ge=1, le=50, description="P_D bins over range (equal counts of the log's pairs)")
    bearing_bins: int = Field(default=8, ge=1, le=50, description="P_D bins over bearing (equal widths)")
    batches: int = Field(default=20, ge=4, le=200, description="contiguous batches for the standard error of a mean per frame")
    min_pairs: int = Field(
        default=30, ge=1, description="fewest pairs a P_D bin needs to be tested (a few pairs of one landmark's pass are one observation)"
    )
    min_landmarks: int = Field(
        default=12, ge=2, description="fewest landmarks with true detections the noise and coverage tests need (a cluster-robust "
        "variance from fewer is too small, and a few landmarks' geometry is not the profile's mix)",
    )
    batch_frames: int = Field(default=5, ge=1, description="fewest frames per batch the clutter test needs (the counts' correlation over time)")


# ------------------------------------------------------------------------------------------ results


@dataclass
class Part:
    """One part's test on one row.

    ``effect`` and its standard errors are on a scale where a drift is additive:
    P_D absolute, clutter relative, noise log sigma, coverage the share outside
    the gate (absolute); ``sd_held`` is what the log's own sampling gives,
    ``sd_profile`` what the profile's does (it does not shrink with more data).
    """

    part: str
    statistic: float
    p_value: float
    effect: float
    sd_held: float
    sd_profile: float
    tolerance: float  # on the effect's scale
    n: int
    unit: str  # what n counts
    text: str  # the effect in words
    notes: list[str] = field(default_factory=list)
    components: dict = field(default_factory=dict)
    p_adjusted: float = float("nan")
    detectable: float = float("nan")  # on the effect's scale
    needed: int | None = None  # n for detectable <= tolerance (None: enough; -1: the profile's own uncertainty is the limit)
    verdict: str = ""
    where: list[str] = field(default_factory=list)
    # the score a user reads (``score_name``, in its own units) and the 95 % of it a right profile would give on
    # this log's own opportunities (the sampling floor: the bootstrap's, or the test's null distribution). P_D: the
    # largest |signed-root deviance| of a tested bin in its null standard deviations (max-T); clutter: false alarms
    # per frame; noise: the laser's circle-fit residual relative to the profile's, or the largest |z| of the
    # detections' range and bearing bias and spread; coverage: the share of true detections outside the gate
    score_name: str = ""
    score: float = float("nan")
    floor: tuple[float, float] = (float("nan"), float("nan"))

    def to_dict(self) -> dict:
        return {
            "verdict": self.verdict,
            "score": {"name": self.score_name, "observed": self.score, "right_profile_95": list(self.floor)},
            "p_value": self.p_value,
            "p_adjusted": self.p_adjusted,
            "effect": self.text,
            "detectable": _natural(self.part, self.detectable),
            "tolerance": _natural(self.part, self.tolerance),
            self.unit: self.n,
            **({"needed_" + self.unit: self.needed} if self.needed is not None else {}),
            **({"where": self.where} if self.where else {}),
            **({"notes": self.notes} if self.notes else {}),
            **self.components,
        }


@dataclass
class RowDrift:
    """The drift tests of one row (a log, or several together)."""

    name: str
    parts: dict[str, Part]
    pd_bins: pd.DataFrame | None = None
    clutter_hist: pd.DataFrame | None = None
    missing: dict[str, str] = field(default_factory=dict)  # part -> why it was not tested
    verdict: str = ""

    @property
    def headline(self) -> str:
        """The verdict with the parts behind it, e.g. ``drifted: P_D (range 10-20 m -0.09), clutter (+96 %)``."""
        if self.verdict == "drifted":
            bits = []
            for p in self.parts.values():
                if p.verdict == "drifted":
                    bits.append(f"{LABELS[p.part]} ({p.text}{'; ' + ', '.join(p.where[:3]) if p.where else ''})")
            return "drifted: " + ", ".join(bits)
        if self.verdict == "too little data":
            bits = [f"{LABELS[p.part]} ({_needed_text(p)})" for p in self.parts.values() if p.verdict == "too little data"]
            return "too little data: " + ", ".join(bits)
        return self.verdict


@dataclass
class DriftReport:
    rows: list[RowDrift]
    config: DriftConfig
    tests: int
    verdict: str  # the worst row's

    def table(self) -> pd.DataFrame:
        """One row per log (and one for all): verdict and each part's raw and adjusted p-values."""
        out = []
        for r in self.rows:
            row = {"log": r.name, "verdict": r.verdict, "drift": r.headline}
            for k in PARTS:
                p = r.parts.get(k)
                row[f"{k}_verdict"] = p.verdict if p else "not tested"
                row[f"{k}_p"] = p.p_value if p else np.nan
                row[f"{k}_p_adjusted"] = p.p_adjusted if p else np.nan
                row[f"{k}_effect"] = p.text if p else ""
            out.append(row)
        return pd.DataFrame(out)

    def brief(self) -> pd.DataFrame:
        """One row per log (and one for all) for a terminal: the verdict and, per part, its verdict with the
        adjusted p-value and the change."""
        out = []
        for r in self.rows:
            row = {"log": r.name, "verdict": r.verdict}
            for k in PARTS:
                p = r.parts.get(k)
                row[LABELS[k]] = f"{p.verdict} (p {p.p_adjusted:.2g}): {p.text}" if p else "not tested"
            out.append(row)
        return pd.DataFrame(out)

    def headline_all(self) -> str:
        """The overall verdict and the rows and parts behind it, e.g. ``drifted: robot4 (P_D, clutter)``: the rows of
        single logs that have the overall verdict (or the pooled row when none of them has it)."""
        if len(self.rows) == 1:
            return self.rows[0].headline
        if self.verdict == "consistent":
            return "consistent"
        worst = [r for r in self.rows if r.name != "all" and r.verdict == self.verdict] or [r for r in self.rows if r.verdict == self.verdict]
        return f"{self.verdict}: " + ", ".join(
            f"{r.name} ({', '.join(LABELS[p.part] for p in r.parts.values() if p.verdict == self.verdict)})" for r in worst
        )

    def parts(self) -> pd.DataFrame:
        """One row per (row, part): the score a user reads beside the 95 % a right profile would give on the row's
        own opportunities (its sampling floor), the p-values, the verdict, where P_D changed and, with too little
        data, how much would do; untested parts with the reason."""
        out = []
        for r in self.rows:
            for k in PARTS:
                p = r.parts.get(k)
                if p is None:
                    out.append({"log": r.name, "part": LABELS[k], "verdict": "not tested", "score": "", "change": r.missing.get(k, ""), "where": "", "needed": ""})
                    continue
                out.append({
                    "log": r.name, "part": LABELS[k], "verdict": p.verdict, "score": p.score_name, "observed": p.score,
                    "right_low": p.floor[0], "right_high": p.floor[1], "p_value": p.p_value, "p_adjusted": p.p_adjusted,
                    "change": p.text, "where": "; ".join(p.where),
                    "needed": _needed_text(p) if p.verdict == "too little data" else "",
                })  # fmt: skip
        return pd.DataFrame(out, columns=["log", "part", "verdict", "score", "observed", "right_low", "right_high", "p_value", "p_adjusted", "change", "where", "needed"])

    def summary(self) -> dict:
        return {
            "verdict": self.verdict,
            "alpha": self.config.alpha,
            "tests": self.tests,
            "control": "Holm over every part of every row",
            "replicates": self.config.replicates,
            "seed": self.config.seed,
            "rows": {
                r.name: {"verdict": r.headline, **{k: p.to_dict() for k, p in r.parts.items()}, **({"not_tested": r.missing} if r.missing else {})}
                for r in self.rows
            },
        }


def _natural(part: str, x: float) -> float:
    """An effect-scale figure in the units a reader expects (noise: relative sigma)."""
    if part == "noise" and np.isfinite(x):
        return float(np.expm1(x))
    return float(x)


def _needed_text(p: Part) -> str:
    det = _natural(p.part, p.detectable)
    unit = {"pd": "", "clutter": " %", "noise": " %", "coverage": ""}[p.part]
    scale = 100 if p.part in ("clutter", "noise") else 1
    d = f"detects {scale * det:.3g}{unit}, tolerance {scale * _natural(p.part, p.tolerance):.3g}{unit}"
    if p.needed == -1:
        return f"{d}; the profile's own uncertainty is the limit: recalibrate on more data"
    return f"{d}; needs about {p.needed:,} {p.unit}, has {p.n:,}"


# ------------------------------------------------------------------------------------------ helpers


def cluster_correlation(y: np.ndarray, q: np.ndarray, cluster: np.ndarray) -> float:
    """rho of the common-uniform model: moment estimate from outcomes y (N,) bool, rates q (N,), clusters (N,).

    E sum_L R_L^2 = sum_i q_i (1 - q_i) + rho sum_L sum_{i != j in L} (min(q_i, q_j) - q_i q_j),
    with R_L the residual sum (y - q) of cluster L; rho is solved from the
    observed sum and clipped to [0, 1] (the model has no negative correlation).
    """
    y = np.asarray(y, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    if y.size < 2:
        return 0.0
    _, c = np.unique(np.asarray(cluster), return_inverse=True)
    r_l = np.bincount(c, weights=y - q)
    excess = float((r_l**2).sum() - (q * (1 - q)).sum())
    order = np.lexsort((q, c))
    cs, qs = c[order], q[order]
    m = np.bincount(c)
    rank = np.arange(cs.size) - np.concatenate([[0], np.cumsum(m)[:-1]])[cs]  # 0-based, ascending q within the cluster
    s_min = 2.0 * float((qs * (m[cs] - 1 - rank)).sum())  # sum over ordered pairs i != j of min(q_i, q_j)
    sq = np.bincount(c, weights=q)
    s_prod = float((sq**2 - np.bincount(c, weights=q * q)).sum())
    s2 = s_min - s_prod
    return float(np.clip(excess / s2, 0.0, 1.0)) if s2 > 1e-12 else 0.0


def cell_rates(y: np.ndarray, cell: np.ndarray) -> np.ndarray:
    """(N,) each pair's bin's own observed rate."""
    _, inv = np.unique(cell, return_inverse=True)
    return (np.bincount(inv, weights=y.astype(np.float64)) / np.bincount(inv))[inv]


def effective_counts(table: PdTable, cells: np.ndarray, y: np.ndarray, cluster: np.ndarray) -> list:
    """The table's counts over their design effect, in its layout: cells (N,) flat cell of each pair (-1 outside),
    y (N,) detected, cluster (N,) landmark (with the log) of each pair."""
    ok = cells >= 0
    cells, y, cluster = cells[ok], np.asarray(y, dtype=bool)[ok], np.asarray(cluster)[ok]
    size = int(np.asarray(table.pd).size)
    rho = cluster_correlation(y, cell_rates(y, cells), cluster)
    _, c = np.unique(cluster, return_inverse=True)
    key = cells.astype(np.int64) * (int(c.max()) + 1 if c.size else 1) + c
    _, k_inv, m = np.unique(key, return_inverse=True, return_counts=True)
    first = np.zeros(m.size, dtype=np.int64)
    first[k_inv] = cells
    n = np.bincount(cells, minlength=size).astype(np.float64)
    sum_m2 = np.bincount(first, weights=m.astype(np.float64) ** 2, minlength=size)
    deff = 1.0 + rho * np.where(n > 0, sum_m2 / np.maximum(n, 1) - 1.0, 0.0)
    return np.round(n / deff, 3).reshape(np.asarray(table.pd).shape).tolist()


def with_effective_counts(table: PdTable, pairs: pd.DataFrame, detected: np.ndarray, cluster: np.ndarray) -> PdTable:
    """``table`` with its effective counts measured on the pairs it was fitted to (validated anew).

    pairs: the table's covariate columns; detected (N,) bool; cluster (N,) the
    landmark of each pair, distinct across logs.
    """
    eff = effective_counts(table, cell_index(table, pairs), np.asarray(detected, dtype=bool), np.asarray(cluster))
    return updated(table, {"effective_counts": eff})


def landmark_clusters(pairs: pd.DataFrame) -> np.ndarray:
    """(N,) one integer per (log, landmark) of the pairs (columns log, when present, and landmark)."""
    if "log" not in pairs:
        return pd.factorize(pairs["landmark"])[0]
    return pd.MultiIndex.from_arrays([pairs["log"].astype(str), pairs["landmark"]]).factorize()[0]


def design_effect(x: np.ndarray, cluster: np.ndarray) -> float:
    """Variance of a mean of x (N,) with clusters (N,) over the independent-sample variance (at least 1)."""
    x = np.asarray(x, dtype=np.float64)
    if x.size < 2:
        return 1.0
    d = x - x.mean()
    ss = float((d * d).sum())
    if ss <= 0:
        return 1.0
    _, c = np.unique(np.asarray(cluster), return_inverse=True)
    return max(1.0, float((np.bincount(c, weights=d) ** 2).sum()) / ss)


def holm(p: np.ndarray) -> np.ndarray:
    """Holm's step-down adjusted p-values (FWER)."""
    p = np.asarray(p, dtype=np.float64)
    m = p.size
    if m == 0:
        return p
    order = np.argsort(p, kind="stable")
    adj = np.minimum(1.0, np.maximum.accumulate(p[order] * (m - np.arange(m))))
    out = np.empty(m)
    out[order] = adj
    return out


def _nice(x: float) -> float:
    """x rounded to two significant digits."""
    if x == 0 or not np.isfinite(x):
        return float(x)
    return float(np.round(x, 1 - int(np.floor(np.log10(abs(x))))))


def _fmt(x: float) -> str:
    return f"{x:.3g}"


# ------------------------------------------------------------------------------------------ P_D


def _bins(sub: pd.DataFrame, table: PdTable, cell: np.ndarray, cfg: DriftConfig) -> tuple[np.ndarray, pd.DataFrame]:
    """(bin of each pair per family (N, 5), bin table: family, label, low, high, tested).

    Families: the profile's own cells and all informative pairs together (tested:
    they are what the profile claims; the whole is where a drift of every cell at
    once shows best), range bins (equal counts of the log's pairs), bearing bins
    (equal widths) and predicted-P_D bins (0.1 wide). Range and bearing bins are
    tested for a range or range x bearing table (aggregates of its own cells);
    for an n_p table they are only shown: they hold its misfit too (P_D at one
    n_p need not be the same at every range), which a new log shares with the
    calibration.
    """
    rows = []
    cols = []
    uc, c_inv = np.unique(cell, return_inverse=True)
    e = np.asarray(table.edges)
    r = sub["range"].to_numpy(np.float64)
    for k, c in enumerate(uc):
        if table.two_d:
            nb = len(table.bearing_edges) - 1
            i, j = divmod(int(c), nb)
            be = np.degrees(table.bearing_edges)
            lab = f"{e[i]:g}-{e[i + 1]:g} m, {be[j]:.0f}..{be[j + 1]:.0f} deg"
            lo, hi = e[i], e[i + 1]
        else:
            last = int(c) >= len(table.pd) - 1
            c = min(int(c), len(table.pd) - 1)
            if table.covariate == "n_p":
                rr = np.quantile(r[c_inv == k], [0.1, 0.9])
                lab = f"n_p {'>=' if last else '='} {e[c]:g} ({_fmt(rr[0])}-{_fmt(rr[1])} m)"
            else:
                lab = f"{table.covariate} {e[c]:g}{'+' if last else '-' + format(e[c + 1], 'g')}{' m' if table.covariate == 'range' else ''}"
            lo, hi = e[c], (np.inf if last else e[c + 1])
        rows.append(("cell", lab, lo, hi, True))
    cols.append(c_inv)
    rows.append(("overall", "all informative pairs", 0.0, np.inf, True))
    cols.append(np.full(c_inv.size, len(uc)))
    own = table.covariate in ("range", "range_bearing")
    qe = np.unique([_nice(v) for v in np.quantile(r, np.linspace(0, 1, cfg.range_bins + 1))])
    qe[0], qe[-1] = min(qe[0], r.min()), max(qe[-1], r.max())
    nr = max(qe.size - 1, 1)
    ri = np.clip(np.searchsorted(qe, r, side="right") - 1, 0, nr - 1)
    for k in range(nr):
        lo, hi = qe[k], qe[min(k + 1, qe.size - 1)]
        rows.append(("range", f"range {_fmt(lo)}-{_fmt(hi)} m", lo, hi, own))
    cols.append(len(uc) + 1 + ri)
    b = sub["bearing"].to_numpy(np.float64)
    bmin, bmax = float(b.min()), float(b.max())
    be = np.linspace(bmin, bmax if bmax > bmin else bmin + 1e-9, cfg.bearing_bins + 1)
    bi = np.clip(np.searchsorted(be, b, side="right") - 1, 0, cfg.bearing_bins - 1)
    for k in range(cfg.bearing_bins):
        rows.append(("bearing", f"bearing {np.degrees(be[k]):.0f}..{np.degrees(be[k + 1]):.0f} deg", be[k], be[k + 1], table.two_d))
    cols.append(len(uc) + 1 + nr + bi)
    p = sub["predicted"].to_numpy(np.float64)
    pi = np.clip(np.ceil(p * 10).astype(np.int64), 1, 10) - 1
    for k in range(10):
        rows.append(("predicted", f"predicted {k / 10:.1f}-{(k + 1) / 10:.1f}", k / 10, (k + 1) / 10, False))
    cols.append(len(rows) - 10 + pi)
    return np.column_stack(cols), pd.DataFrame(rows, columns=["family", "label", "low", "high", "tested"])


def _root_deviance(o: np.ndarray, e: np.ndarray, n: np.ndarray) -> np.ndarray:
    """sign(o - e) sqrt(2 [o ln(o / e) + (n - o) ln((n - o) / (n - e))]): the binomial signed-root deviance of
    o detections where e were expected among n pairs (any shape broadcasting o, e and n; 0 ln 0 = 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(o > 0, o * np.log(o / e), 0.0)
        b = np.where(n - o > 0, (n - o) * np.log((n - o) / (n - e)), 0.0)
    return np.sign(o - e) * np.sqrt(np.maximum(2 * (a + b), 0.0))


def _band_all(exp: np.ndarray, n: np.ndarray, tested: np.ndarray, c: float, sd_r: np.ndarray, side: int) -> np.ndarray:
    """The detection rate at which a tested bin's root deviance reaches side * c * sd_r (NaN for untested bins):
    the edge of the band of all tested bins at once, found by bisection on the rate (monotone in it)."""
    out = np.full(exp.size, np.nan)
    idx = np.flatnonzero(tested)
    if idx.size == 0:
        return out
    e, nn, target = exp[idx], n[idx], side * c * sd_r[idx]
    lo, hi = (np.zeros(idx.size), e.copy()) if side < 0 else (e.copy(), nn.copy())
    for _ in range(50):  # bisection, vectorised over the bins
        mid = (lo + hi) / 2
        r = _root_deviance(mid, e, nn)
        beyond = r < target if side < 0 else r > target
        lo, hi = (np.where(beyond, mid, lo), np.where(beyond, hi, mid)) if side < 0 else (np.where(beyond, lo, mid), np.where(beyond, mid, hi))
    out[idx] = (lo + hi) / 2 / nn
    return out


def pd_drift(pairs: pd.DataFrame, table: PdTable, rng: np.random.Generator, cfg: DriftConfig) -> tuple[Part | None, pd.DataFrame | None, str]:
    """(part, bin table with the bootstrap band, why not tested) of P_D over the pairs with predicted P_D > 0.

    pairs: columns predicted, observed (bool), range [m], bearing [rad], landmark,
    log, and the table's covariate columns (n_p, or range and bearing).
    """
    pr = pairs["predicted"].to_numpy(np.float64)
    sub = pairs[pr > 0].reset_index(drop=True)
    n = len(sub)
    if n == 0:
        return None, None, "no pair with P_D > 0"
    p = sub["predicted"].to_numpy(np.float64)
    y = sub["observed"].to_numpy(bool)
    cell = cell_index(table, sub)
    if (cell < 0).any():  # a prediction > 0 outside the table cannot be (lookup and cells agree); keep it honest
        cell = np.where(cell < 0, int(np.asarray(table.pd).size), cell)
    clusters = landmark_clusters(sub)
    n_cl = int(clusters.max()) + 1
    notes = []
    uc, c_inv = np.unique(cell, return_inverse=True)
    pdc = np.append(np.asarray(table.pd, dtype=np.float64).ravel(), 0.0)[uc]
    src = table.effective_counts if table.effective_counts is not None else table.counts
    if src is None:
        a = b = None
        mu = p
        notes.append("the profile states no counts: its P_D taken as exact")
    else:
        if table.effective_counts is None:
            notes.append("the profile states no effective counts: its bins' pairs taken as independent")
        ne = np.append(np.asarray(src, dtype=np.float64).ravel(), 0.0)[uc]
        a, b = pdc * ne + 0.5, (1 - pdc) * ne + 0.5
        mu = (a / (a + b))[c_inv]
    rho = cluster_correlation(y, cell_rates(y, cell), clusters)
    fam, bins = _bins(sub, table, cell, cfg)
    k_bins = len(bins)
    member = np.zeros((n, k_bins), dtype=np.float32)
    for f in range(fam.shape[1]):
        member[np.arange(n), fam[:, f]] = 1.0
    obs = member.T @ y.astype(np.float32)
    exp = member.T.astype(np.float64) @ mu
    n_b = member.sum(axis=0)
    pred = member.T.astype(np.float64) @ p
    reps = cfg.replicates
    sims = np.empty((reps, k_bins), dtype=np.float32)
    chunk = max(1, min(reps, CHUNK // n))
    for s in range(0, reps, chunk):  # blocks of replicates, each vectorised over replicates x pairs
        m = min(chunk, reps - s)
        q = np.broadcast_to(p, (m, n)) if a is None else rng.beta(a, b, size=(m, uc.size))[:, c_inv]
        u = rng.random((m, n), dtype=np.float32)
        if rho > 0:
            share = rng.random((m, n_cl)) < rho
            u_cl = rng.random((m, n_cl), dtype=np.float32)
            u = np.where(share[:, clusters], u_cl[:, clusters], u)
        sims[s : s + m] = (u < q).astype(np.float32) @ member
    sd = sims.std(axis=0, ddof=1).astype(np.float64)
    tested = bins["tested"].to_numpy() & (sd > 0) & (n_b >= cfg.min_pairs)
    # max-T (Westfall & Young's single step) over the bins' signed-root deviances, each in its own null standard
    # deviations: the largest over the bins against the largest of every replicate. The root deviance is near
    # normal even for a bin of a few expected misses, where (O - E) / sd has one long tail that would set the
    # family's threshold; unlike ranks, max-T resolves p-values down to 1 / (replicates + 1) whatever the bins.
    r_obs = _root_deviance(obs[tested].astype(np.float64), exp[tested], n_b[tested])
    r_sim = _root_deviance(sims[:, tested].astype(np.float64), exp[tested], n_b[tested])
    sd_r = r_sim.std(axis=0, ddof=1)
    sd_r = np.where(sd_r > 0, sd_r, np.inf)
    z_obs = np.abs(r_obs) / sd_r
    t_star = (np.abs(r_sim) / sd_r).max(axis=1) if tested.any() else np.zeros(reps)
    t_obs = float(z_obs.max()) if z_obs.size else 0.0
    p_part = float((1 + (t_star >= t_obs - 1e-9).sum()) / (reps + 1))
    c95 = float(np.quantile(t_star, 0.95))
    sd_all = np.zeros(k_bins)
    sd_all[tested] = sd_r
    p_bin = np.full(k_bins, np.nan)
    ts = np.sort(t_star)
    p_bin[tested] = (1 + reps - np.searchsorted(ts, z_obs - 1e-9, side="left")) / (reps + 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        bins = bins.assign(
            pairs=n_b.astype(np.int64),
            detected=obs.astype(np.int64),
            observed=obs / n_b,
            predicted=pred / n_b,
            expected=exp / n_b,
            band_low=np.quantile(sims, 0.025, axis=0) / n_b,
            band_high=np.quantile(sims, 0.975, axis=0) / n_b,
            # the band of all tested bins at once: a bin outside it is one the max-T test names at 0.05
            band_all_low=_band_all(exp, n_b, tested, c95, sd_all, -1),
            band_all_high=_band_all(exp, n_b, tested, c95, sd_all, 1),
            z=(obs - exp) / sd,
            p_adjusted_in_part=p_bin,
        )
    tot = sims[:, bins["family"].to_numpy() == "cell"].sum(axis=1, dtype=np.float64)  # every pair is in one cell
    sd_tot = float(tot.std(ddof=1)) / n
    if a is None:
        var_prof = 0.0
    else:
        var_q = a * b / ((a + b) ** 2 * (a + b + 1))
        var_prof = float((np.bincount(c_inv, minlength=uc.size) ** 2 * var_q).sum()) / n**2
    effect = float(y.sum() - mu.sum()) / n
    part = Part(
        "pd", t_obs, p_part, effect, float(np.sqrt(max(sd_tot**2 - var_prof, 0.0))), float(np.sqrt(var_prof)),
        cfg.pd_tolerance, n, "pairs", f"{effect:+.3f} overall ({y.mean():.3f} observed, {mu.mean():.3f} predicted)", notes,
        {"pairs_predicted_zero": int((pr <= 0).sum()), "detections_where_zero_predicted": int(pairs["observed"].to_numpy(bool)[pr <= 0].sum()),
         "landmark_correlation": round(rho, 4)},
        score_name="largest bin |z|", score=t_obs, floor=(0.0, c95),
    )
    return part, bins, ""


# ------------------------------------------------------------------------------------------ clutter


def _count_cdf(clutter: ClutterParams, lam: np.ndarray, kmax: int) -> np.ndarray:
    """(R, kmax + 1) CDF of the count model at rates lam (R,) (the profile's shape kept)."""
    k = np.arange(kmax + 1)[None, :]
    lam = np.maximum(lam, 1e-12)[:, None]
    if clutter.count_model == "poisson":
        return poisson.cdf(k, lam)
    r = float(clutter.size)
    return nbinom.cdf(k, r, r / (r + lam))


def clutter_drift(counts: np.ndarray, clutter: ClutterParams, rng: np.random.Generator, cfg: DriftConfig) -> tuple[Part | None, pd.DataFrame | None, str]:
    """(part, count histogram with the model's bootstrap band, why not tested) of false alarms per frame (F,)."""
    c = np.asarray(counts, dtype=np.int64)
    f = c.size
    if f < cfg.batches * cfg.batch_frames:
        return None, None, f"{f} frames: too few to measure the counts' correlation over time (needs {cfg.batches * cfg.batch_frames})"
    lam = float(clutter.rate)
    se_p = float(clutter.rate_se) if clutter.rate_se is not None else 0.0
    notes = [] if clutter.rate_se is not None else ["the profile states no standard error of its rate: taken as exact"]
    m = float(c.mean())
    s2 = float(c.var(ddof=1))
    se_h = float(batch_se(c.astype(np.float64), cfg.batches))
    tau = max(1.0, f * se_h**2 / s2) if s2 > 0 else 1.0  # integrated autocorrelation time [frames]
    phi = (tau - 1.0) / (tau + 1.0)
    reps = cfg.replicates
    k_hist = int(max(c.max(), np.ceil(lam + 6 * np.sqrt(clutter.count_variance + 1e-12)))) + 2
    hist = np.empty((reps, k_hist), dtype=np.int32)
    t_star = np.empty(reps)
    means = np.full(reps, 0.0)
    denom = lambda se: np.sqrt(se**2 + se_p**2)  # noqa: E731
    stat = (m - lam) / denom(se_h) if denom(se_h) > 0 else (0.0 if m == lam else np.inf)
    if lam > 0:
        kmax = int(nbinom.ppf(1 - 1e-12, float(clutter.size), float(clutter.size) / (float(clutter.size) + lam + 8 * se_p)) if clutter.count_model == "negative_binomial" else poisson.ppf(1 - 1e-12, lam + 8 * se_p)) + 1
        chunk = max(1, min(reps, CHUNK // f))
        for s in range(0, reps, chunk):  # blocks of replicates, vectorised over replicates x frames
            n = min(chunk, reps - s)
            lam_r = np.abs(lam + se_p * rng.standard_normal(n))
            e = rng.standard_normal((n, f))
            x = e * np.sqrt(1 - phi**2)
            x[:, 0] = e[:, 0]
            z = lfilter([1.0], [1.0, -phi], x, axis=1)  # stationary AR(1), unit variance
            u = ndtr(z)
            cdf = _count_cdf(clutter, lam_r, kmax)
            cdf[:, -1] = 1.0
            flat = (cdf + np.arange(n)[:, None] * 2.0).ravel()
            sim = np.searchsorted(flat, (u + np.arange(n)[:, None] * 2.0).ravel(), side="right").reshape(n, f) - np.arange(n)[:, None] * (kmax + 1)
            sim = np.minimum(sim, kmax)
            se_r = batch_se(sim.astype(np.float64), cfg.batches)
            means[s : s + n] = sim.mean(axis=1)
            t_star[s : s + n] = (means[s : s + n] - lam) / denom(se_r)
            capped = np.minimum(sim, k_hist - 1) + np.arange(n)[:, None] * k_hist
            hist[s : s + n] = np.bincount(capped.ravel(), minlength=n * k_hist).reshape(n, k_hist)
        p_value = float((1 + (np.abs(t_star) >= abs(stat) - 1e-12).sum()) / (reps + 1))
    else:  # the profile says no clutter: any false alarm contradicts it
        hist[:] = 0
        hist[:, 0] = f
        p_value = 1.0 if m == 0 else 1.0 / (reps + 1)
    obs_hist = np.bincount(np.minimum(c, k_hist - 1), minlength=k_hist)
    ks = np.arange(k_hist)
    pmf = clutter.count_pmf(ks) if lam > 0 else (ks == 0).astype(np.float64)
    pmf[-1] = 1.0 - pmf[:-1].sum()
    table = pd.DataFrame(
        {"count": ks, "frames": obs_hist, "expected": f * pmf, "band_low": np.quantile(hist, 0.025, axis=0), "band_high": np.quantile(hist, 0.975, axis=0)}
    )
    rel = (m - lam) / lam if lam > 0 else (0.0 if m == 0 else np.inf)
    part = Part(
        "clutter", float(stat), p_value, float(rel), se_h / lam if lam > 0 else 0.0, se_p / lam if lam > 0 else 0.0, cfg.clutter_tolerance,
        f, "frames", f"{100 * rel:+.0f} % ({m:.3g} per frame observed, {lam:.3g} predicted)", notes,
        {"observed_per_frame": m, "predicted_per_frame": lam, "se_log": se_h, "se_profile": se_p, "autocorrelation_time_frames": round(tau, 2)},
        score_name="false alarms per frame", score=m, floor=(float(np.quantile(means, 0.025)), float(np.quantile(means, 0.975))),
    )
    return part, table, ""


# ------------------------------------------------------------------------------------------ noise and coverage


def _two_sided(z: float, clusters: int) -> float:
    """Two-sided p of z against Student's t with (clusters - 1) degrees of freedom (the cluster-robust variance's)."""
    if not np.isfinite(z):
        return 0.0 if np.isinf(z) else 1.0
    return float(2 * student_t.sf(abs(z), max(clusters - 1, 1)))


def _t95(clusters: int, tests: int = 1) -> float:
    """|z| a right profile stays under with probability 0.95 (two-sided; Bonferroni over ``tests``), against
    Student's t with (clusters - 1) degrees of freedom."""
    return float(student_t.ppf(1 - 0.025 / tests, max(clusters - 1, 1)))


def noise_drift_laser(log_mse: np.ndarray, cluster: np.ndarray, hot: HotellingParams | None, samples: int | None, cfg: DriftConfig) -> tuple[Part | None, str]:
    """The true detections' mean log mean-square residual (N,) against the profile's Hotelling mean of ``log_mse``."""
    if hot is None or "log_mse" not in hot.names:
        return None, "the profile's gate has no log_mse descriptor"
    x = np.asarray(log_mse, dtype=np.float64)
    ok = np.isfinite(x)
    x, cluster = x[ok], np.asarray(cluster)[ok]
    if x.size < 10:
        return None, f"{x.size} true detections: too few"
    if (k := np.unique(cluster).size) < cfg.min_landmarks:
        return None, f"true detections of {k} landmarks: too few (needs {cfg.min_landmarks})"
    j = hot.names.index("log_mse")
    mu_p, v_p = float(hot.mean[j]), float(hot.covariance[j][j])
    d = design_effect(x, cluster)
    var_h = d * float(x.var(ddof=1)) / x.size
    var_p = d * v_p / samples if samples else 0.0  # the profile's clustering taken as the log's (both from one process under the null)
    notes = [] if samples else ["the profile states no sample size of its gate: its mean taken as exact"]
    diff = float(x.mean()) - mu_p
    z = diff / np.sqrt(var_h + var_p)
    # log_mse is 2 log sigma plus a geometry term: half the difference is the change of log sigma
    eff = diff / 2
    return Part(
        "noise", float(z), _two_sided(z, k), eff, float(np.sqrt(var_h)) / 2, float(np.sqrt(var_p)) / 2, float(np.log1p(cfg.noise_tolerance)),
        int(x.size), "true detections", f"circle-fit residual {100 * np.expm1(eff):+.0f} %", notes,
        {"log_mse_observed": float(x.mean()), "log_mse_profile": mu_p, "design_effect": round(d, 3)},
        score_name="fit residual change", score=float(np.expm1(eff)),
        floor=tuple(float(np.expm1(sg * _t95(k) * np.sqrt(var_h + var_p) / 2)) for sg in (-1, 1)),
    ), ""


def noise_drift_detections(res: pd.DataFrame, noise: MeasurementNoise | None, cfg: DriftConfig) -> tuple[Part | None, str]:
    """Range and bearing residuals of true detections (columns range_residual, bearing_residual, cluster)
    against the profile's robust spreads and biases; the part's p-value is Bonferroni over the four."""
    if noise is None:
        return None, "the profile states no measurement noise"
    if len(res) < 10:
        return None, f"{len(res)} true detections: too few"
    cl = res["cluster"].to_numpy()
    k = np.unique(cl).size
    if k < cfg.min_landmarks:
        return None, f"true detections of {k} landmarks: too few (needs {cfg.min_landmarks})"
    n = len(res)
    n_p = noise.samples or None
    zs, comp, worst = {}, {}, None
    eff_s, sd_h_s, sd_p_s = [], [], []
    for key, unit, scale in (("range", "m", 1.0), ("bearing", "deg", 180 / np.pi)):
        e = res[f"{key}_residual"].to_numpy(np.float64)
        med = float(np.median(e))
        sig = max(MAD_SIGMA * float(np.median(np.abs(e - med))), 1e-12)
        sig_p, bias_p = getattr(noise, f"{key}_sigma"), getattr(noise, f"{key}_bias")
        d_b, d_s = design_effect(e, cl), design_effect(np.abs(e - med), cl)
        inv = 1 / n + (1 / n_p if n_p else 0.0)
        zb = (med - bias_p) / np.sqrt(VAR_MEDIAN * d_b * (sig**2 / n + (sig_p**2 / n_p if n_p else 0.0)))
        ls = float(np.log(sig / sig_p))
        zsig = ls / np.sqrt(VAR_LOG_MAD * d_s * inv)
        zs[f"{key}_bias"], zs[f"{key}_sigma"] = zb, zsig
        comp[f"{key}_sigma"] = f"{scale * sig:.3g} {unit} vs {scale * sig_p:.3g}"
        comp[f"{key}_bias"] = f"{scale * med:+.3g} {unit} vs {scale * bias_p:+.3g}"
        eff_s.append(ls)
        sd_h_s.append(np.sqrt(VAR_LOG_MAD * d_s / n))
        sd_p_s.append(np.sqrt(VAR_LOG_MAD * d_s / n_p) if n_p else 0.0)
    ps = {kk: _two_sided(z, k) for kk, z in zs.items()}
    worst = min(ps, key=ps.get)
    i = int(np.argmax(np.abs(eff_s)))
    txt = ", ".join(f"{kk.replace('_', ' ')} {v}" for kk, v in comp.items() if ps[kk] * 4 <= cfg.alpha) or f"{('range', 'bearing')[i]} sigma {100 * np.expm1(eff_s[i]):+.0f} %"
    notes = [] if n_p else ["the profile states no sample count of its noise: taken as exact"]
    return Part(
        "noise", float(zs[worst]), min(1.0, 4 * ps[worst]), float(eff_s[i]), float(max(sd_h_s)), float(max(sd_p_s)), float(np.log1p(cfg.noise_tolerance)),
        n, "true detections", txt, notes, {**comp, **{f"p_{kk}": v for kk, v in ps.items()}},
        score_name="largest residual |z|", score=abs(float(zs[worst])), floor=(0.0, _t95(k, 4)),
    ), ""


def coverage_drift(inside: np.ndarray, cluster: np.ndarray, hot: HotellingParams | None, coverage: float | None, samples: int | None, cfg: DriftConfig) -> tuple[Part | None, str]:
    """Share of true detections (N,) outside the Hotelling ellipsoid against the calibration's own share
    (or the nominal 1 - confidence, exact, when the profile states no coverage)."""
    if hot is None:
        return None, "the profile has no gate"
    inside = np.asarray(inside, dtype=bool)
    n = inside.size
    if n < 10:
        return None, f"{n} true detections: too few"
    if (k := np.unique(np.asarray(cluster)).size) < cfg.min_landmarks:
        return None, f"true detections of {k} landmarks: too few (needs {cfg.min_landmarks})"
    miss_p = 1.0 - (coverage if coverage is not None else hot.confidence)
    n_p = samples if coverage is not None and samples else None
    notes = [] if n_p else ["against the nominal confidence (the profile states no measured coverage)"]
    miss = 1.0 - float(inside.mean())
    pooled = (miss * n + miss_p * n_p) / (n + n_p) if n_p else miss_p
    d = design_effect((~inside).astype(np.float64), cluster)
    v_unit = max(pooled * (1 - pooled), 0.25 / n**2) * d  # never 0: one miss in n is no certainty
    var = v_unit * (1 / n + (1 / n_p if n_p else 0.0))
    z = (miss - miss_p) / np.sqrt(var)
    return Part(
        "coverage", float(z), _two_sided(z, k), miss - miss_p, float(np.sqrt(v_unit / n)), float(np.sqrt(v_unit / n_p)) if n_p else 0.0,
        cfg.coverage_tolerance, n, "true detections", f"outside the gate {miss:.4f} vs {miss_p:.4f}",
        notes, {"outside_observed": miss, "outside_profile": miss_p, "design_effect": round(d, 3)},
        score_name="share outside the gate", score=miss,
        floor=(max(0.0, miss_p - _t95(k) * float(np.sqrt(var))), miss_p + _t95(k) * float(np.sqrt(var))),
    ), ""


# ------------------------------------------------------------------------------------------ rows and verdicts


def row_drift(profile, pairs: pd.DataFrame, counts: np.ndarray, truth: pd.DataFrame | None, name: str, key: int, cfg: DriftConfig) -> RowDrift:
    """The raw tests of one row; ``key`` picks its random stream (same key and seed, same bytes).

    pairs: see :func:`pd_drift`; counts (F,) false alarms per frame; truth: one row
    per true detection with ``cluster`` (its landmark, with the log) and, for a
    laser, ``log_mse`` and ``inside`` (the Hotelling gate), for a detection-level
    sensor ``range_residual`` [m] and ``bearing_residual`` [rad].
    """
    g_pd, g_cl = (np.random.default_rng(s) for s in np.random.SeedSequence([cfg.seed, key]).spawn(2))
    parts, missing = {}, {}
    col = profile.pd.covariate if not profile.pd.two_d else "bearing"
    if profile.planes is not None and profile.planes.pd_grid is not None:
        pdp, bins, why = None, None, "P_D over points x incidence (a plane profile's grid) is not tested"
    elif col not in pairs:
        pdp, bins, why = None, None, f"the pairs carry no {col} for the profile's P_D table"
    else:
        pdp, bins, why = pd_drift(pairs, profile.pd, g_pd, cfg)
    if pdp is None:
        missing["pd"] = why
    else:
        parts["pd"] = pdp
    clp, hist, why = clutter_drift(counts, profile.clutter, g_cl, cfg)
    if clp is None:
        missing["clutter"] = why
    else:
        parts["clutter"] = clp
    hot = profile.hotelling
    if truth is None or len(truth) == 0:
        missing["noise"] = "no true detections"
    elif "log_mse" in truth:
        nz, why = noise_drift_laser(truth["log_mse"].to_numpy(), truth["cluster"].to_numpy(), hot, hot.samples if hot else None, cfg)
        parts["noise"] = nz if nz else None
        missing.update({} if nz else {"noise": why})
        cv, why = coverage_drift(truth["inside"].to_numpy(bool), truth["cluster"].to_numpy(), hot, hot.coverage if hot else None, hot.samples if hot else None, cfg)
        parts["coverage"] = cv if cv else None
        missing.update({} if cv else {"coverage": why})
    else:
        nz, why = noise_drift_detections(truth, profile.noise, cfg)
        parts["noise"] = nz if nz else None
        missing.update({} if nz else {"noise": why})
    if "coverage" not in parts and "coverage" not in missing:
        missing["coverage"] = "the profile has no gate" if hot is None else "no true detections"
    return RowDrift(name, {k: v for k, v in parts.items() if v is not None}, bins, hist, missing)


def decide(rows: list[RowDrift], cfg: DriftConfig) -> DriftReport:
    """Holm over every part of every row, then each part's, row's and the overall verdict."""
    tests = [(r, p) for r in rows for p in r.parts.values()]
    adj = holm(np.array([p.p_value for _, p in tests]))
    m = max(len(tests), 1)
    z = float(ndtri(1 - cfg.alpha / (2 * m)) + ndtri(cfg.power))
    for (_, p), pa in zip(tests, adj, strict=True):
        p.p_adjusted = float(pa)
        p.detectable = z * float(np.hypot(p.sd_held, p.sd_profile))
        room = (p.tolerance / z) ** 2 - p.sd_profile**2
        if p.detectable <= p.tolerance:
            p.needed = None
        elif room <= 0:
            p.needed = -1
        else:
            p.needed = int(np.ceil(p.n * p.sd_held**2 / room))
        p.verdict = "drifted" if pa <= cfg.alpha else ("too little data" if p.detectable > p.tolerance else "consistent")
    for r in rows:
        pd_part = r.parts.get("pd")
        if pd_part is not None and pd_part.verdict == "drifted" and r.pd_bins is not None:
            # a bin is named when its own (min-p adjusted) p-value passes the level the part passed at
            level = cfg.alpha * pd_part.p_value / pd_part.p_adjusted if pd_part.p_adjusted > 0 else cfg.alpha
            b = r.pd_bins
            hit = b[(b["p_adjusted_in_part"] <= level) & (b["family"] != "overall")]
            hit = hit.assign(gap=(hit["observed"] - hit["expected"]).abs()).sort_values("gap", ascending=False)
            pd_part.where = [f"{x.label} {x.observed - x.expected:+.2f}" for x in hit.itertuples()]
        r.verdict = max((p.verdict for p in r.parts.values()), key=VERDICTS.index, default="too little data")
    overall = max((r.verdict for r in rows), key=VERDICTS.index, default="too little data")
    return DriftReport(rows, cfg, len(tests), overall)
