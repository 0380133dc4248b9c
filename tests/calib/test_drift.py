"""Drift tests (calib.drift): calibrated under the null, powerful against the changes they name.

Truth comes from seeded simulations: synthetic opportunities and count series
whose process is known (training and held-out drawn from one process, or the
held-out one changed), and simulated parks for the whole chain.
"""

import functools

import numpy as np
import pandas as pd
import pytest
from scipy.special import expit, logit
from scipy.stats import binom, kstest

from calib.drift import (
    DriftConfig,
    Part,
    RowDrift,
    clutter_drift,
    cluster_correlation,
    coverage_drift,
    decide,
    holm,
    noise_drift_detections,
    noise_drift_laser,
    pd_drift,
    with_effective_counts,
)
from calib.fits import PdFitConfig, clutter_params, fit_clutter, fit_pd_table
from profiles.schema import HotellingParams, MeasurementNoise

FAST = DriftConfig(replicates=199)

# 200 trials of a test at level 0.05: the number rejected is Binomial(200, 0.05) when the test is right;
# at most 19 holds with probability 0.997, so a count of 20 or more says the test over-rejects
TRIALS = 200
MAX_REJECTED = int(binom.ppf(0.997, TRIALS, 0.05))


def _assert_level(trial) -> None:
    """TRIALS p-values of ``trial()`` under the null: rejections at 0.05 within Binomial(TRIALS, 0.05), and uniform."""
    p_values = np.array([trial() for _ in range(TRIALS)])
    assert (p_values <= 0.05).sum() <= MAX_REJECTED, (p_values <= 0.05).sum()
    assert kstest(p_values, "uniform").pvalue > 0.001


def test_holm_by_hand():
    # sorted 0.01, 0.02, 0.04 times 3, 2, 1 -> 0.03, 0.04, 0.04 (monotone)
    assert holm(np.array([0.04, 0.01, 0.02])) == pytest.approx([0.04, 0.03, 0.04])
    assert holm(np.array([0.5, 0.9])) == pytest.approx([1.0, 1.0])


def _common_uniform(rng, q, cluster, rho):
    """Outcomes of the common-uniform model: with probability rho a cluster's pairs share one uniform."""
    n_cl = cluster.max() + 1
    share = rng.random(n_cl) < rho
    u = np.where(share[cluster], rng.random(n_cl)[cluster], rng.random(q.size))
    return u < q


def test_cluster_correlation_recovers_rho():
    rng = np.random.default_rng(0)
    cluster = np.repeat(np.arange(800), 25)
    q = rng.uniform(0.3, 0.95, cluster.size)
    for rho in (0.0, 0.1, 0.3):
        est = [cluster_correlation(_common_uniform(rng, q, cluster, rho), q, cluster) for _ in range(5)]
        # 800 clusters of 25: the moment estimate's spread is about 0.01 (measured over seeds)
        assert np.mean(est) == pytest.approx(rho, abs=0.02)


# ------------------------------------------------------------------------------------------ P_D


def _park_like_pairs(rng, n_landmarks: int, shift: float = 0.0, log: str = "a") -> pd.DataFrame:
    """Pairs of a laser-like log: P_D rises with n_p, and every landmark has its own logit offset
    (sd 0.6: its size and surface), which is not the model the test assumes for correlation."""
    m = rng.integers(5, 40, n_landmarks)
    lm = np.repeat(np.arange(n_landmarks), m)
    n_p = rng.integers(3, 12, lm.size)
    base = expit(-1.0 + 0.45 * n_p)
    p = np.clip(expit(logit(base) + rng.normal(0, 0.6, n_landmarks)[lm]) + shift * (n_p < 6), 0, 1)
    rng_m = 5.0 + 60.0 / n_p + rng.normal(0, 2, lm.size)
    return pd.DataFrame(
        {"n_p": n_p, "range": rng_m, "bearing": rng.uniform(-1.5, 1.5, lm.size), "landmark": lm, "log": log, "observed": rng.random(lm.size) < p}
    )


def _table(train: pd.DataFrame):
    t = fit_pd_table(train["n_p"].to_numpy(), train["observed"].to_numpy(), "n_p", PdFitConfig(min_count=50, zero_below=0.0))
    return with_effective_counts(t, train, train["observed"].to_numpy(), train["landmark"].to_numpy())


@pytest.mark.slow  # many simulated logs for a uniformity test
def test_pd_p_values_are_uniform_when_the_log_comes_from_the_calibration_process():
    rng = np.random.default_rng(1)

    def trial():
        table = _table(_park_like_pairs(rng, 100))
        held = _park_like_pairs(rng, 100, log="b")
        held["predicted"] = table.lookup(held["n_p"].to_numpy())
        return pd_drift(held, table, rng, FAST)[0].p_value

    _assert_level(trial)


def test_pd_drift_is_found_where_it_happened():
    rng = np.random.default_rng(2)
    table = _table(_park_like_pairs(rng, 300))
    held = _park_like_pairs(rng, 300, shift=-0.1, log="b")  # P_D lower by 0.1 at n_p < 6 only
    held["predicted"] = table.lookup(held["n_p"].to_numpy())
    part, bins, _ = pd_drift(held, table, rng, FAST)
    assert part.p_value <= 0.01
    cells = bins[bins["family"] == "cell"].set_index("low")
    low = cells.loc[[3.0, 4.0, 5.0], "p_adjusted_in_part"]
    high = cells.loc[[6.0, 7.0, 8.0], "p_adjusted_in_part"]
    assert (low <= 0.05).all() and (high > 0.05).all()
    # the band holds the profile's expectation; the drifted cells fall below it
    assert ((cells["band_low"] <= cells["expected"]) & (cells["expected"] <= cells["band_high"])).all()
    assert (cells.loc[[3.0, 4.0, 5.0], "observed"] < cells.loc[[3.0, 4.0, 5.0], "band_low"]).all()


# ------------------------------------------------------------------------------------------ clutter


def _bursty_counts(rng, frames: int, rate: float) -> np.ndarray:
    """False alarms of clutter sources that stay in view: a gamma rate level held over runs of 5-60 frames."""
    out = np.empty(frames, dtype=np.int64)
    i = 0
    while i < frames:
        run = int(rng.integers(5, 60))
        out[i : i + run] = rng.poisson(rate * rng.gamma(4.0, 0.25), min(run, frames - i))
        i += run
    return out


def test_clutter_p_values_are_uniform_with_correlated_frames_and_the_profiles_own_error():
    rng = np.random.default_rng(3)

    def trial():
        prof = clutter_params(fit_clutter(_bursty_counts(rng, 1500, 3.0)), "range_bearing", 10.0)
        return clutter_drift(_bursty_counts(rng, 1500, 3.0), prof, rng, FAST)[0].p_value

    _assert_level(trial)


def test_clutter_doubled_is_drift_and_the_band_holds_the_model():
    rng = np.random.default_rng(4)
    prof = clutter_params(fit_clutter(_bursty_counts(rng, 1500, 3.0)), "range_bearing", 10.0)
    part, hist, _ = clutter_drift(_bursty_counts(rng, 1500, 6.0), prof, rng, FAST)
    assert part.p_value <= 1 / 200 and part.effect == pytest.approx(1.0, abs=0.3)
    assert ((hist["band_low"] <= hist["expected"] + 1) & (hist["expected"] <= hist["band_high"] + 1)).all()
    assert hist["frames"].sum() == 1500


def test_a_profile_without_clutter_is_contradicted_by_any_false_alarm():
    rng = np.random.default_rng(5)
    prof = clutter_params(fit_clutter(np.zeros(500, dtype=np.int64)), "range_bearing", 10.0)
    assert clutter_drift(np.zeros(500, dtype=np.int64), prof, rng, FAST)[0].p_value == 1.0
    c = np.zeros(500, dtype=np.int64)
    c[7] = 1
    assert clutter_drift(c, prof, rng, FAST)[0].p_value == pytest.approx(1 / 200)


# ------------------------------------------------------------------------------------------ noise and coverage


def _hotelling(mean: float, var: float) -> HotellingParams:
    return HotellingParams(names=["log_mse", "log_radius"], mean=[mean, -1.0], covariance=[[var, 0.0], [0.0, 0.2]], gamma=16.0)


def _clustered(rng, n_cl, size, sd_cl, sd, shift=0.0):
    cl = np.repeat(np.arange(n_cl), size)
    return shift + rng.normal(0, sd_cl, n_cl)[cl] + rng.normal(0, sd, cl.size), cl


def test_noise_and_coverage_tests_hold_their_level_with_clustered_detections():
    rng = np.random.default_rng(6)
    rej_noise = rej_cov = 0
    for _ in range(TRIALS):
        train, _ = _clustered(rng, 200, 20, 0.8, 1.0)
        hot = _hotelling(float(train.mean()), float(train.var()))
        held, cl = _clustered(rng, 200, 20, 0.8, 1.0)
        rej_noise += noise_drift_laser(held, cl, hot, train.size, FAST)[0].p_value <= 0.05
        miss_cl = rng.random(200) < 0.05  # a few landmarks are always outside the gate (odd size), the rest rarely
        inside = ~np.where(miss_cl[cl], rng.random(cl.size) < 0.5, rng.random(cl.size) < 0.005)
        t_inside = ~np.where((rng.random(200) < 0.05)[cl], rng.random(cl.size) < 0.5, rng.random(cl.size) < 0.005)
        rej_cov += coverage_drift(inside, cl, hot, float(t_inside.mean()), t_inside.size, FAST)[0].p_value <= 0.05
    assert rej_noise <= MAX_REJECTED and rej_cov <= MAX_REJECTED


def test_doubled_noise_is_drift_in_the_noise():
    rng = np.random.default_rng(7)
    train, _ = _clustered(rng, 200, 20, 0.8, 1.0)
    hot = _hotelling(float(train.mean()), float(train.var()))
    held, cl = _clustered(rng, 200, 20, 0.8, 1.0, shift=2 * np.log(2.0))  # sigma x 2: log mean square + 2 log 2
    part, _ = noise_drift_laser(held, cl, hot, train.size, FAST)
    assert part.p_value < 1e-6 and np.expm1(part.effect) == pytest.approx(1.0, abs=0.15)


def test_detection_noise_against_the_profiles_spread_and_bias():
    rng = np.random.default_rng(8)
    cl = np.repeat(np.arange(15), 300)
    noise = MeasurementNoise(range_sigma=0.1, bearing_sigma=0.01, range_bias=0.0, bearing_bias=0.0, samples=4500)
    same = pd.DataFrame({"cluster": cl, "range_residual": rng.normal(0, 0.1, cl.size), "bearing_residual": rng.normal(0, 0.01, cl.size)})
    assert noise_drift_detections(same, noise, FAST)[0].p_value > 0.01
    wide = same.assign(range_residual=rng.normal(0, 0.2, cl.size))
    part, _ = noise_drift_detections(wide, noise, FAST)
    assert part.p_value < 1e-4 and "range sigma" in part.text and np.expm1(part.effect) == pytest.approx(1.0, abs=0.15)


# ------------------------------------------------------------------------------------------ verdicts


def _part(name, p, sd_held, sd_profile=0.0, tol=0.05, n=1000):
    return Part(name, 0.0, p, 0.0, sd_held, sd_profile, tol, n, "pairs", "")


def test_verdicts_holm_and_the_count_a_log_would_need():
    cfg = DriftConfig()
    a = RowDrift("a", {"pd": _part("pd", 0.001, 0.001), "clutter": _part("clutter", 0.5, 0.1, tol=0.25)})
    b = RowDrift("b", {"pd": _part("pd", 0.02, 0.001), "clutter": _part("clutter", 0.5, 0.1, sd_profile=0.2, tol=0.25)})
    rep = decide([a, b], cfg)
    # four tests: 0.001 * 4 = 0.004 drifted; 0.02 * 3 = 0.06 not
    assert a.parts["pd"].verdict == "drifted" and b.parts["pd"].verdict == "consistent"
    assert a.parts["pd"].p_adjusted == pytest.approx(0.004) and b.parts["pd"].p_adjusted == pytest.approx(0.06)
    # z = 2.50 + 0.84: the clutter detects 0.334 > 0.25 with the log's 0.1; 0.1^2 x 1000 / ((0.25 / z)^2) frames would do
    z = 3.3392
    assert a.parts["clutter"].verdict == "too little data"
    assert a.parts["clutter"].needed == pytest.approx(1000 * 0.01 / (0.25 / z) ** 2, rel=0.01)
    assert b.parts["clutter"].needed == -1  # the profile's own 0.2 alone exceeds what the tolerance allows
    assert (a.verdict, b.verdict, rep.verdict) == ("drifted", "too little data", "drifted")
    assert "recalibrate" in b.headline and a.headline.startswith("drifted: P_D")


# ------------------------------------------------------------------------------------------ simulated parks

# the benchmark's --scale small (benchmarks/bench_drift.py): a park of 70 x 50 m simulates in about a second
SMALL = {"width": 70.0, "height": 50.0, "trees": {"count": 50}, "bushes": {"count": 20}, "walls": {"count": 1, "min_length": 3.0, "max_length": 10.0},
         "posts": {"count": 6}, "path": {"margin": 8.0}}


@functools.lru_cache(maxsize=64)
def _park_profile(seed: int):
    from calib.calibrate import CalibrateConfig, calibrate
    from calib.sim.park import ParkConfig, simulate_park

    return calibrate([simulate_park(ParkConfig.model_validate(SMALL), seed).log], CalibrateConfig(), name="park", version="1.0.0").profile


@pytest.mark.slow
def test_new_parks_of_the_same_settings_are_rarely_called_drifted():
    """20 seeds: a profile calibrated on park 2s - 1, validated on park 2s. With a right level of 5 % the number
    called drifted is Binomial(20, 0.05): at most 3 with probability 0.984 (4 or more: 1.6 %)."""
    from calib.sim.park import ParkConfig, simulate_park
    from calib.validate import validate

    verdicts = []
    for s in range(1, 21):
        v = validate(_park_profile(2 * s - 1), simulate_park(ParkConfig.model_validate(SMALL), 2 * s).log)
        verdicts.append(v.drift.verdict)
    assert sum(x == "drifted" for x in verdicts) <= 3, verdicts


@pytest.mark.slow
@pytest.mark.parametrize(("change", "part"), [("pd_lower", "pd"), ("clutter_double", "clutter"), ("noise_double", "noise")])
def test_a_changed_sensor_is_drift_at_the_part_that_changed(change, part):
    """Five seeds of each change (the benchmark runs 20 at full scale): every one is flagged at its part."""
    from calib.sim.park import ParkConfig, changed, simulate_park
    from calib.validate import validate

    for s in range(1, 6):
        v = validate(_park_profile(2 * s - 1), simulate_park(changed(ParkConfig.model_validate(SMALL), change), 2 * s).log)
        assert v.drift.rows[0].parts[part].verdict == "drifted", (s, v.drift.rows[0].headline)


def test_per_log_work_anywhere_gives_the_same_report():
    """validate(per_log=...) runs each log's labelling and its own drift tests where the log is; done in another
    order (as workers finish), the report is the same: every row draws from its own seeded stream."""
    from calib.sim.park import ParkConfig, simulate_park
    from calib.validate import validate

    prof = _park_profile(41)
    logs = [simulate_park(ParkConfig.model_validate(SMALL), s).log for s in (42, 43)]
    cfg = DriftConfig(replicates=199)
    here = validate(prof, logs, drift=cfg)

    def backwards(fn, args):
        return list(reversed([fn(*a) for a in reversed(args)]))

    there = validate(prof, logs, drift=cfg, per_log=backwards)
    assert [r.name for r in here.drift.rows] == ["all", "park_seed42", "park_seed43"]
    assert here.drift.summary() == there.drift.summary()
    assert here.per_log.equals(there.per_log)
