"""Self-calibration against a SLAM run's own map: the simulator's statistics come back without its truth."""

import numpy as np
import pytest
import yaml

from calib.map_calibration import SelfCalConfig, profile_change, self_calibrate
from calib.sim.rfs import RfsSimConfig, simulate_rfs, truth_profile
from profiles.schema import ClutterParams
from tests.detcal.cli.test_cli import assert_one_line_error, run
from profiles.override import updated

SIM = RfsSimConfig(steps=300, pd=0.6, clutter_intensity=2.0 / (2.0 * 2 * np.pi))  # P_D 0.6, 2 false alarms per scan


@pytest.fixture(scope="module")
def log():
    return simulate_rfs(SIM, 5)


def nominal():
    """A wrong starting profile: P_D 0.9, 0.5 false alarms per scan (the noise is the sensor's)."""
    t = truth_profile(SIM)
    return updated(t, {"pd.pd": [0.9], "clutter": ClutterParams(rate=0.5, volume=t.clutter.volume)})


def test_measured_against_the_true_path_and_map_the_statistics_are_the_simulators(log):
    """With the truth as the 'SLAM run' the measurement is a calibration: ~5,000 (frame, landmark)
    pairs give P_D to +-0.02 (3 binomial std), 300 frames the clutter rate to +-10 %, and the
    residuals the noise to +-5 %."""
    c = self_calibrate(log, log.reference["ground_truth"].poses, log.landmarks.xy, None, truth_profile(SIM), SelfCalConfig(gate=0.1), name="x", version="1.0.0")
    assert c.profile.pd.pd[0] == pytest.approx(0.6, abs=0.02)
    assert c.profile.clutter.rate == pytest.approx(2.0, rel=0.1)
    assert c.profile.noise.range_sigma == pytest.approx(np.sqrt(5e-4), rel=0.05)
    assert c.profile.noise.bearing_sigma == pytest.approx(np.sqrt(5e-5), rel=0.05)
    assert "SLAM run" in c.profile.description


def test_the_loop_recovers_pd_and_clutter_from_a_wrong_start(log):
    """RB-PHD-SLAM with 20 particles from the wrong profile, three rounds: P_D within 0.05 of the truth; the
    clutter rate moves from 0.5 to within [0.9, 1.6] x the truth (above it: detections of the few landmarks
    the run merged with a neighbour a few cm away count as clutter, about one per scan here); the noise
    measured against the run is the sensor's plus the run's own error, so between 1x and 2.5x the truth."""
    from calib.config import load_yaml_model
    from detcal.pipelines.self_calibration import self_calibration
    from slam_runtime.config import SlamConfig, override
    from tests.conftest import ROOT

    cfg = override(load_yaml_model(SlamConfig, ROOT / "benchmarks/configs/rfs_sim.yaml"), particles=20)

    def measure(lg, traj, xy, w, prior, k):
        c = self_calibrate(lg, traj, xy, w, prior, SelfCalConfig(gate=0.3), name="x", version="1.0.0", iteration=k)
        return c.profile, c.summary

    hist = self_calibration(log, nominal(), cfg, 0, measure, profile_change, iterations=3)
    last = hist[-1].measured
    assert hist[0].change > 1.0  # the wrong start is far off
    assert last.pd.pd[0] == pytest.approx(0.6, abs=0.05)
    assert 0.9 * 2.0 <= last.clutter.rate <= 1.6 * 2.0
    assert np.sqrt(5e-4) <= last.noise.range_sigma <= 2.5 * np.sqrt(5e-4)
    assert np.sqrt(5e-5) <= last.noise.bearing_sigma <= 2.5 * np.sqrt(5e-5)


def test_selfcal_command_writes_its_folder_and_the_profile(tmp_path, capsys, log):
    from calib.io.native import write_native
    from profiles.store import dump_profile

    lp = write_native(simulate_rfs(updated(SIM, {"steps": 120}), 6), tmp_path / "sim.dlog")
    (tmp_path / "start.yaml").write_text(dump_profile(nominal()))
    cfg = tmp_path / "slam.yaml"
    cfg.write_text("particles: 5\nfilter: {kind: rbphd, noise_inflation: 10.0, weighting: marginal}\n")
    args = ["selfcal", str(lp), "--profile", str(tmp_path / "start.yaml"), "--config", str(cfg), "--iterations", "2"]
    code, out, err = run(capsys, *args, "--out", str(tmp_path / "sc"), "--profiles-dir", str(tmp_path / "profiles"), "--name", "sim-selfcal")
    assert code == 0, err
    names = sorted(p.name for p in (tmp_path / "sc").iterdir())
    assert names == [".detcal-output", "iterations.csv", "last_run", "pd_iterations.png", "profile.yaml", "profiles", "slam.yaml", "summary.yaml", "warnings.yaml"]
    prof = yaml.safe_load((tmp_path / "sc/profile.yaml").read_text())
    assert prof["name"] == "sim-selfcal" and prof["pd"]["covariate"] == "range"
    assert (tmp_path / "profiles").is_dir() and "sim-selfcal@1.0.0" in out
    saved = (tmp_path / "profiles/sim-selfcal@1.0.0.yaml").read_bytes()
    assert yaml.safe_load(saved) == prof  # the store holds what the run folder holds
    # the same version again (another run folder): refused before any work, nothing written
    code, _, err = run(capsys, *args, "--out", str(tmp_path / "sc2"), "--profiles-dir", str(tmp_path / "profiles"), "--name", "sim-selfcal")
    assert code == 2
    assert_one_line_error(err, "profile sim-selfcal@1.0.0 exists; bump the version")
    assert not (tmp_path / "sc2").exists() and (tmp_path / "profiles/sim-selfcal@1.0.0.yaml").read_bytes() == saved
    # a bundled name@version is never shadowed
    code, _, err = run(capsys, *args, "--out", str(tmp_path / "sc3"), "--profiles-dir", str(tmp_path / "profiles"), "--name", "sim-park-laser")
    assert code == 2
    assert_one_line_error(err, "is bundled with detcal")
    assert not (tmp_path / "sc3").exists()
    # errors: a laser log, a starting profile with an n_p table
    from detcal.reports.simulation import write_simulation_run
    from tests.conftest import small_park_config

    write_simulation_run("park", small_park_config(), 2, tmp_path / "park")
    code, _, err = run(capsys, "selfcal", str(tmp_path / "park/log.dlog"), "--profile", str(tmp_path / "start.yaml"), "--out", str(tmp_path / "x"))
    assert code == 2
    assert_one_line_error(err, "self-calibration takes a detection-level log")
    code, _, err = run(capsys, "selfcal", str(lp), "--profile", "sim-park-laser", "--out", str(tmp_path / "x"))
    assert code == 2
    assert_one_line_error(err, "self-calibration measures P_D against range")
    assert not (tmp_path / "x").exists()


def test_selfcal_measures_against_the_map_of_the_filter_it_is_given(tmp_path, capsys):
    """`--filter lmb`: every SLAM run of the self-calibration is LMB-SLAM (the run folder says so), and the profile is
    measured against that filter's map; an unknown filter is one clear error before any work."""
    from calib.io.native import write_native
    from profiles.store import dump_profile

    lp = write_native(simulate_rfs(updated(SIM, {"steps": 80}), 6), tmp_path / "sim.dlog")
    (tmp_path / "start.yaml").write_text(dump_profile(nominal()))
    base = ["selfcal", str(lp), "--profile", str(tmp_path / "start.yaml"), "--iterations", "1", "--particles", "3", "--profiles-dir", str(tmp_path / "p")]
    code, out, err = run(capsys, *base, "--filter", "lmb", "--out", str(tmp_path / "sc"), "--name", "sim-lmb")
    assert code == 0, err
    used = yaml.safe_load((tmp_path / "sc/last_run/config.yaml").read_text())["settings"]
    assert used["filter"]["kind"] == "lmb" and used["particles"] == 3
    assert yaml.safe_load((tmp_path / "sc/profile.yaml").read_text())["name"] == "sim-lmb"
    code, _, err = run(capsys, *base, "--filter", "ekf", "--out", str(tmp_path / "sc2"), "--name", "sim-x")
    assert code == 2
    assert_one_line_error(err, "--filter: expected one of rbphd, lmb, glmb, mhfastslam")
    assert not (tmp_path / "sc2").exists()


def test_pooled_runs_are_the_same_detections_not_more_data(log):
    """Averaging the iterates: n measurements of the same detections against the same map pool to the very
    same profile with the same counts and Wilson intervals (not sqrt(n) narrower: the runs add no detections);
    against two different maps, P_D is the pooled rate of the two runs' pairs and the clutter rate their mean."""
    from calib.map_calibration import pool_self_calibrations

    truth = log.reference["ground_truth"].poses
    cfg = SelfCalConfig(gate=0.1)
    one = self_calibrate(log, truth, log.landmarks.xy, None, truth_profile(SIM), cfg, name="x", version="1.0.0")
    three = pool_self_calibrations([one, one, one], cfg, iterations=[2, 3, 4])
    for key in ("pd", "counts", "detections", "wilson_low", "wilson_high", "edges"):
        assert getattr(three.pd, key) == pytest.approx(getattr(one.profile.pd, key))
    assert three.clutter.rate == pytest.approx(one.profile.clutter.rate)
    assert three.noise.range_sigma == pytest.approx(one.profile.noise.range_sigma)
    assert three.noise.samples == one.profile.noise.samples
    assert three.provenance.parameters["averaged_iterations"] == [2, 3, 4]
    assert "iterations 2-4" in three.description
    # a map that lost a fifth of its landmarks: more detections are clutter, fewer pairs
    rng = np.random.default_rng(0)
    keep = rng.uniform(size=log.landmarks.xy.shape[0]) > 0.2
    other = self_calibrate(log, truth, log.landmarks.xy[keep], None, truth_profile(SIM), cfg, name="x", version="1.0.0")
    two = pool_self_calibrations([one, other], cfg, iterations=[0, 1])
    assert other.clutter.rate > one.clutter.rate + 0.3
    assert two.clutter.rate == pytest.approx((one.clutter.rate + other.clutter.rate) / 2)
    n1, n2 = one.profile.pd.counts[0], other.profile.pd.counts[0]
    k1, k2 = one.profile.pd.detections[0], other.profile.pd.detections[0]
    assert two.pd.pd[0] == pytest.approx((k1 + k2) / (n1 + n2))
    assert two.pd.counts[0] == round((n1 + n2) / 2)
    p, lo, hi = (np.asarray(getattr(two.pd, k)) for k in ("pd", "wilson_low", "wilson_high"))
    assert ((lo <= p) & (p <= hi)).all()  # every interval holds its pooled rate
    with pytest.raises(ValueError, match="2 measurements to pool with 3 iteration numbers"):
        pool_self_calibrations([one, other], cfg, iterations=[0, 1, 2])


def test_a_pd_table_of_pooled_runs_has_one_runs_counts_and_no_empty_supported_bin():
    """fit_pd_table(runs=n): P_D is the pooled rate; min_count applies per run; counts and Wilson intervals are one
    run's (centred on the pooled rate); a bin holding fewer than n / 2 pooled pairs keeps a count of 1, not 0."""
    from calib.fits import PdFitConfig, fit_pd_table, wilson

    rng = np.random.default_rng(1)
    r = np.concatenate([[2.5], rng.uniform(5, 15, 3000)])  # one pair in the first bin, then two well-filled bins
    det = np.concatenate([[True], rng.uniform(size=3000) < 0.6])
    cfg = PdFitConfig(min_count=100, range_bin=5.0, zero_below=0.0, tail="last")
    one = fit_pd_table(r, det, "range", cfg)
    three = fit_pd_table(r, det, "range", cfg, runs=3)
    assert three.pd == pytest.approx(one.pd) and one.counts[0] == 1
    assert three.counts[1:] == [round(c / 3) for c in one.counts[1:]]
    lo, hi = wilson(np.array(one.detections) / 3, np.array(one.counts) / 3)
    assert three.wilson_low == pytest.approx(lo.tolist()) and three.wilson_high == pytest.approx(hi.tolist())
    assert all(lo_ <= p <= hi_ for lo_, p, hi_ in zip(three.wilson_low, three.pd, three.wilson_high, strict=True))
    assert three.counts[0] == 1 and three.detections[0] <= 1  # a third of a pair is not no pair
    assert "3 runs of the same detections pooled" in three.clamping and ">= 100 pairs per run" in three.clamping
    with pytest.raises(Exception, match="no P_D bin holds 2000 pairs per run"):
        fit_pd_table(r, det, "range", updated(cfg, {"min_count": 2000}), runs=3)


def test_selfcal_average_from_writes_the_average_of_the_runs(tmp_path, capsys):
    """`--average-from 1`: the profile written pools the measurements of iterations 1 and 2 (its provenance says
    so, its clutter rate is the mean of the two runs' measured rates); an iteration past the last is refused."""
    import pandas as pd

    from calib.io.native import write_native
    from profiles.store import dump_profile

    lp = write_native(simulate_rfs(updated(SIM, {"steps": 80}), 6), tmp_path / "sim.dlog")
    (tmp_path / "start.yaml").write_text(dump_profile(nominal()))
    base = ["selfcal", str(lp), "--profile", str(tmp_path / "start.yaml"), "--particles", "3", "--profiles-dir", str(tmp_path / "p")]
    code, out, err = run(capsys, *base, "--iterations", "3", "--average-from", "1", "--tolerance", "1e-9", "--out", str(tmp_path / "sc"), "--name", "sim-avg")
    assert code == 0, err
    prof = yaml.safe_load((tmp_path / "sc/profile.yaml").read_text())
    assert prof["provenance"]["parameters"]["averaged_iterations"] == [1, 2]
    from profiles.store import load_profile_file

    assert load_profile_file(tmp_path / "p/sim-avg@1.0.0.yaml").provenance.parameters["averaged_iterations"] == [1, 2]  # it loads
    rows = pd.read_csv(tmp_path / "sc/iterations.csv")
    assert rows["measured_averaged_runs"].tolist()[1:] == [1, 2]
    assert prof["clutter"]["rate"] == pytest.approx(rows["measured_false_alarms_per_frame"].iloc[1:].mean())
    assert "runs' mean +- s.e." in out
    assert "average settled" in out
    code, _, err = run(capsys, *base, "--iterations", "3", "--average-from", "2", "--out", str(tmp_path / "sc2"), "--name", "sim-x")
    assert code == 2
    assert_one_line_error(err, "--average-from: expected an iteration from 0 to 1")
    assert not (tmp_path / "sc2").exists()


def test_the_loop_averages_the_odometry_biases_with_the_profiles():
    """With ``average_from`` the next run's steering offset and speed scale are the mean of the runs measured so far
    (from that iteration on), while each iteration keeps its own run's measurement; before it, the run's own."""
    from calib.sim.glmb_paper import GlmbPaperConfig, simulate_glmb_paper
    from calib.sim.glmb_paper import truth_profile as glmb_truth
    from slam_runtime.config import SlamConfig
    from detcal.pipelines.self_calibration import self_calibration

    sc = GlmbPaperConfig(max_steps=800, clutter=1.0)
    lg = simulate_glmb_paper(sc, 3)
    cfg = SlamConfig.model_validate({"particles": 3, "filter": {"kind": "rbphd"}, "motion": {"ackermann": {"sigma_speed": 0.1, "sigma_steer": 0.035}}})

    def measure(lg_, traj, xy, w, prior, k):
        c = self_calibrate(lg_, traj, xy, w, prior, SelfCalConfig(gate=1.0, pd=updated(SelfCalConfig().pd, {"min_count": 20})), name="x", version="1.0.0", iteration=k)
        return c.profile, c.summary

    hist = self_calibration(lg, glmb_truth(sc), cfg, 0, measure, profile_change, iterations=3, tolerance=1e-12, average_from=1)
    assert len(hist) == 3
    off = [h.bias["steer_offset"] for h in hist]
    scale = [h.bias["speed_scale"] for h in hist]
    used = [h.next_config.motion.ackermann for h in hist]
    assert used[0].steer_offset == pytest.approx(off[0]) and used[0].speed_scale == pytest.approx(scale[0])
    assert used[1].steer_offset == pytest.approx(off[1]) and used[2].steer_offset == pytest.approx((off[1] + off[2]) / 2)
    assert used[2].speed_scale == pytest.approx((scale[1] + scale[2]) / 2)
    assert len(set(scale)) > 1  # the runs measured different scales: the mean is not one of them by accident
