"""Detection-level calibration: a seeded camera-like simulator makes the truth."""

import numpy as np
import pytest

from calib.detlevel import DetectionCalibConfig, IdentityAudit, calibrate_detections, validate_detections
from calib.drift import DriftConfig
from detectors.model import DetectionModel
from profiles.errors import DataError, UsageError
from profiles.profile import DetectorProfile
from tests.calib.camera import FOV, PERIOD, camera_log, pd_edges, pd_range
from tests.conftest import shared
from profiles.override import updated


@pytest.fixture(scope="module")
def plain():
    return calibrate_detections([camera_log(1), camera_log(2)], DetectionCalibConfig(), name="cam", version="1.0.0")


def test_recovers_pd_of_range_and_the_clutter_rate(plain):
    s = plain.summary
    assert s["frame_period_s"] == pytest.approx(PERIOD)
    assert np.degrees(plain.profile.sensor.fov) == pytest.approx(60, abs=2)
    m = DetectionModel.from_profile(plain.profile)
    r = np.arange(1.25, 5.5, 0.5)
    # ~24,000 pairs: the model's P_D at bearing 0 is within 0.06 of the truth (a few s.e. of a
    # 0.5 m x 7.5 deg cell with ~700 pairs, plus the slope across a bin)
    np.testing.assert_allclose(m.pd_at(np.column_stack([r, np.zeros_like(r)])), pd_range(r), atol=0.06)
    # frames with no detection are absent from the log, so epochs are rebuilt: the rate is per epoch
    assert plain.profile.clutter.rate == pytest.approx(0.4, rel=0.05)
    # Poisson clutter: no significant over-dispersion, so the thesis's Poisson model is kept
    assert plain.profile.clutter.count_model == "poisson" and plain.profile.clutter.dispersion_test.p_value > 0.01
    v = validate_detections(plain.profile, [camera_log(3)]).summary
    assert v["ece"] < 0.03 and abs(v["false_alarm_relative_error"]) < 0.1
    lo, hi = v["false_alarm_relative_error_ci95"]
    assert lo < 0 < hi  # the interval of a calibrated rate holds 0
    assert v["frame_period_s"] == pytest.approx(PERIOD) and v["frame_period_training_s"] == pytest.approx(PERIOD)


def test_bearing_falloff_is_modelled_and_chosen_by_held_out_likelihood():
    logs = [camera_log(s, pd=pd_edges) for s in (4, 5)]
    cal = calibrate_detections(logs, DetectionCalibConfig(), name="cam", version="1.0.0")
    t = cal.profile.pd
    sel = t.selection
    assert t.covariate == "range_bearing" and sel.chosen != "range" and sel.folds == "sensors (2)"
    ll = dict(zip(sel.candidates, sel.loglik, strict=True))
    assert ll[sel.chosen] > ll["range"]
    m = DetectionModel.from_profile(cal.profile)
    be = np.asarray(t.bearing_edges)
    r, b = np.meshgrid(np.arange(1.25, 5.0, 0.5), (be[:-1] + be[1:]) / 2)
    # the truth averaged over each cell's bearing span (a piecewise-constant model estimates cell means)
    fine = np.linspace(0, 1, 41)
    truth = np.mean([pd_edges(r, be[:-1, None] + f * np.diff(be)[:, None]) for f in fine], axis=0)
    # cells of 100-900 pairs: s.e. <= 0.05; 0.08 allows that plus the additive model's smoothing across cells
    np.testing.assert_allclose(m.pd_at(np.stack([r, b], axis=-1)), truth, atol=0.08)
    assert (m.pd_at(np.array([[2.0, FOV / 2 + 0.05], [9.0, 0.0]])) == 0).all()  # outside the field of view
    # held out: the grid predicts the new log better than a range table does
    range_only = calibrate_detections(logs, DetectionCalibConfig(pd={"candidates": ["range"]}), name="cam", version="1.0.0")
    test = [camera_log(6, pd=pd_edges)]
    v2, v1 = validate_detections(cal.profile, test).summary, validate_detections(range_only.profile, test).summary
    assert v2["loglik_per_pair"] > v1["loglik_per_pair"] and v2["brier"] < v1["brier"] and v2["ece"] < 0.03


def test_over_dispersed_clutter_gets_a_negative_binomial_and_a_density():
    def counts(rng, n):  # Poisson-gamma: mean 0.5, shape r = 1.5
        return rng.poisson(rng.gamma(1.5, 0.5 / 1.5, n))

    def near(rng, k):  # clutter crowds the near half of the range
        return rng.triangular(0.5, 0.5, 6.0, k)

    cal = calibrate_detections(
        [camera_log(s, clutter_counts=counts, clutter_range=near) for s in (7, 8)], DetectionCalibConfig(), name="cam", version="1.0.0"
    )
    c = cal.profile.clutter
    assert c.count_model == "negative_binomial" and c.dispersion_test.p_value < 1e-6
    # 24,000 frames: r is estimated to ~10 %; 30 % leaves room for the epochs' rebuilding
    assert c.rate == pytest.approx(0.5, rel=0.06) and c.size == pytest.approx(1.5, rel=0.3)
    d = c.density
    assert d.selection.chosen != "uniform"
    m = DetectionModel.from_profile(cal.profile)
    near_k, far_k = m.clutter_intensity(np.array([[1.0, 0.0], [5.5, 0.0]]))
    # the triangular density at 1 m is 5.5 times the one at 5.5 m (0.5 / 0.09); the histogram's cells are coarse
    assert near_k > 3 * far_k
    v = validate_detections(cal.profile, [camera_log(9, clutter_counts=counts, clutter_range=near)]).summary
    assert v["clutter_density_loglik"] > v["clutter_density_loglik_uniform"]
    assert v["clutter_chi2_p_value"] > 0.001 and v["clutter_dispersion"] > 1.2


def test_identity_audit_finds_swapped_landmark_truth():
    logs = [camera_log(s, swap=(8, 12)) for s in (1, 2)]
    cal = calibrate_detections(logs, DetectionCalibConfig(), name="cam", version="1.0.0")
    assert cal.profile.provenance.parameters["identity_remap"] == {"8": 12, "12": 8}
    assert set(cal.summary["identity_remap"]) == {"8->12", "12->8"}
    off = calibrate_detections(logs, DetectionCalibConfig(audit=IdentityAudit(enabled=False)), name="cam", version="1.0.0")
    # without the audit two landmarks' detections are clutter and they are never detected: P_D drops, clutter rises
    assert off.summary["pd_overall"] < cal.summary["pd_overall"] - 0.03
    assert off.profile.clutter.rate > cal.profile.clutter.rate + 0.1


def test_per_sensor_profiles_pool_partially():
    def lower(r, b):
        return 0.6 * pd_range(r)

    logs = [camera_log(1, robot=1), camera_log(2, robot=2), camera_log(3, n=1500, pd=lower, robot=3)]
    cal = calibrate_detections(logs, DetectionCalibConfig(), name="cam", version="1.0.0", per_sensor=True)
    sp = cal.profile.sensors
    assert sp.names == ["robot1", "robot2", "robot3"] and sp.member is None and sp.pd_between_sd > 0.02
    assert [m.name for m in cal.members] == ["cam-robot1", "cam-robot2", "cam-robot3"]
    small = cal.members[2]
    assert small.sensors.member == "robot3" and small.pd.model == "partial_pooling"
    # the small sensor's own P_D is 60 % of the others'; its profile sits between its raw rates and the pooled table
    z = np.array([[2.0, 0.0], [3.0, 0.0]])
    own, pooled = DetectionModel.from_profile(small).pd_at(z), DetectionModel.from_profile(cal.profile).pd_at(z)
    assert (own < pooled).all() and (own > lower(z[:, 0], 0) - 0.1).all()
    for prof in (cal.profile, *cal.members):
        DetectorProfile.model_validate(prof.model_dump())  # every profile is valid on its own


def test_the_held_out_logs_own_frame_period_is_used(plain):
    v = validate_detections(plain.profile, [camera_log(10, period=0.2)]).summary
    assert v["frame_period_s"] == pytest.approx(0.2) and v["frame_period_training_s"] == pytest.approx(PERIOD)
    # clutter is per frame whatever the period: counted at the test's own period the rate still matches
    assert abs(v["false_alarm_relative_error"]) < 0.1


def test_errors():
    with pytest.raises(DataError, match="has no detections"):
        calibrate_detections([camera_log(1).__class__("empty")], DetectionCalibConfig(), name="x", version="1.0.0")


def test_real_utias_robots_1_3_predict_robots_4_5():
    from calib.io.utias import read_utias

    root = shared("utias_mrclam/dataset1")
    cal = calibrate_detections([read_utias(root, robot=r) for r in (1, 2, 3)], DetectionCalibConfig(), name="u", version="1.0.0")
    v = validate_detections(cal.profile, [read_utias(root, robot=r) for r in (4, 5)]).summary
    assert cal.summary["frame_period_s"] == pytest.approx(0.24)
    # the dataset's truth swaps landmarks 11 and 17: every one of their detections falls on the other
    assert set(cal.summary["identity_remap"]) == {"11->17", "17->11"} and set(v["identity_remap"]) == {"11->17", "17->11"}
    assert cal.profile.clutter.count_model == "negative_binomial"  # dispersion 1.3, Poisson rejected at p ~ 1e-100
    # robots 4 and 5 see less and more than robots 1-3 (P_D 0.18 and 0.43 against 0.30-0.34): alone their ECE
    # is 0.14 and 0.10; together the two errors partly cancel (0.046 measured)
    assert v["ece"] < 0.07 and v["pairs_informative"] > 20000


def test_same_inputs_same_bytes(plain):
    from profiles.store import dump_profile

    again = calibrate_detections([camera_log(1), camera_log(2)], DetectionCalibConfig(), name="cam", version="1.0.0")
    assert dump_profile(again.profile) == dump_profile(plain.profile)


def test_validation_errors(plain):
    from tests.profiles.test_store import make_profile

    with pytest.raises(UsageError, match="has an n_p P_D table; a detection-level log needs a range or range_bearing table"):
        validate_detections(make_profile(), [camera_log(3, n=500)])
    no_fov = updated(plain.profile, {"sensor.fov": None})
    with pytest.raises(DataError, match="the sensor has no fov or range_max"):
        validate_detections(no_fov, [camera_log(3, n=500)])


# ------------------------------------------------------------------------------------------ drift verdicts


# 499 replicates: p-values down to 0.002, enough for the few tests of one validation
QUICK = DriftConfig(replicates=499)


def test_a_log_of_the_same_camera_is_not_drift_and_a_changed_one_is_at_its_part(plain):
    same = validate_detections(plain.profile, [camera_log(3, n=6000)], drift=QUICK)
    assert same.drift.verdict != "drifted", same.drift.rows[0].headline
    more_clutter = validate_detections(plain.profile, [camera_log(4, n=6000, clutter=0.8)], drift=QUICK).drift.rows[0]
    assert more_clutter.parts["clutter"].verdict == "drifted" and more_clutter.parts["clutter"].effect == pytest.approx(1.0, abs=0.25)

    def weaker(r, b):
        return pd_range(r) - 0.1 * (np.asarray(r) > 3.0)

    low = validate_detections(plain.profile, [camera_log(5, n=6000, pd=weaker)], drift=QUICK).drift.rows[0]
    assert low.parts["pd"].verdict == "drifted"
    # the bins named are beyond 3 m, and there P_D is lower
    assert low.parts["pd"].where and all(float(w.split("-")[0]) >= 2.5 and "-0." in w for w in low.parts["pd"].where if w[0].isdigit())


def test_each_robot_beside_the_pooled_verdict_and_the_worst_one_overall(plain):
    def lower(r, b):
        return 0.6 * pd_range(r)

    v = validate_detections(plain.profile, [camera_log(6, n=6000, robot=6), camera_log(7, n=6000, pd=lower, robot=7)], drift=QUICK)
    rows = {r.name: r for r in v.drift.rows}
    assert list(rows) == ["all", "cam6", "cam7"]
    assert rows["cam7"].verdict == "drifted" and rows["cam7"].parts["pd"].effect < -0.1
    assert rows["cam6"].verdict != "drifted" and v.drift.verdict == "drifted"
    t = v.per_log.set_index("log")
    assert t.loc["cam7", "verdict"] == "drifted" and t.loc["all", "verdict"] == rows["all"].verdict
    # one family: every part of every row, Holm-adjusted together
    assert v.drift.tests == sum(len(r.parts) for r in v.drift.rows)


def test_exchangeability_names_the_odd_sensor():
    from calib.detlevel import exchangeability

    def lower(r, b):
        return 0.6 * pd_range(r)

    logs = [camera_log(11, n=6000, robot=1), camera_log(12, n=6000, robot=2), camera_log(13, n=6000, robot=3), camera_log(14, n=6000, pd=lower, robot=4)]
    rep = exchangeability(logs, DetectionCalibConfig(), QUICK)
    verdicts = {r.name: r.verdict for r in rep.rows}
    # the odd sensor pulls the pooled profile of every other one: it is set apart first, and the rest agree
    assert rep.odd == ["robot4"] and rep.steps == 2, (rep.odd, verdicts)
    assert verdicts["robot4"] == "drifted" and all(verdicts[f"robot{k}"] != "drifted" for k in (1, 2, 3)), verdicts


def test_drift_verdicts_are_the_same_bytes_for_the_same_seed(plain, tmp_path):
    from calib.validate import write_validation_run

    logs = [camera_log(8, n=3000)]
    for name, seed in (("a", 0), ("b", 0), ("c", 1)):
        write_validation_run(validate_detections(plain.profile, logs, drift=DriftConfig(replicates=199, seed=seed)), tmp_path / name)
    for f in ("summary.yaml", "logs.csv", "drift_bins.csv", "clutter_counts.csv", "reliability.png"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
    assert (tmp_path / "a/drift_bins.csv").read_bytes() != (tmp_path / "c/drift_bins.csv").read_bytes()


def test_occluder_radius_is_found_where_a_nearer_landmark_hides_another(plain):
    """Landmarks as posts of radius 0.15 m hide what lies behind them (the simulator never detects a landmark within
    the angle a nearer post subtends): the calibration finds the radius as the change point of the detection rate
    against the clearance, within 0.01 m (its grid is 0.005 m; the clearance r_c |sin(db)| and the simulator's angle
    asin(0.15 / r_c) agree to well under that at these ranges), and fits P_D on the unhidden pairs only, so the
    range table is that of the simulator's P_D as for the plain log. The plain log hides nothing: no radius."""
    hid = calibrate_detections([camera_log(1, occluder=0.15), camera_log(2, occluder=0.15)], DetectionCalibConfig(), name="cam", version="1.0.0")
    assert hid.profile.detector.occluder_radius == pytest.approx(0.15, abs=0.01)
    occ = hid.summary["occlusion"]
    assert occ["pd_hidden"] == 0.0 and occ["pairs_removed"] > 500
    m = DetectionModel.from_profile(hid.profile)
    r = np.arange(1.25, 5.5, 0.5)
    np.testing.assert_allclose(m.pd_at(np.column_stack([r, np.zeros_like(r)])), pd_range(r), atol=0.06)
    assert plain.profile.detector.occluder_radius is None and "reason" in plain.summary["occlusion"]
    off = calibrate_detections([camera_log(1, occluder=0.15)], DetectionCalibConfig(occlusion=False), name="cam", version="1.0.0")
    assert off.profile.detector.occluder_radius is None
