"""Cross-validation of a calibration, as a library call and as ``detcal validate --cv``."""

import numpy as np
import pandas as pd
import pytest
import yaml

from calib.crossval import cross_validate, halves, time_slice
from calib.io.native import write_native
from profiles.errors import UsageError
from tests.calib.camera import camera_log
from tests.calib.test_calibrate import park
from tests.detcal.cli.test_cli import assert_one_line_error, run


def test_halves_split_frames_and_odometry():
    lg = park(51, 1.0)
    a, b = halves(lg)
    assert len(a.scans) + len(b.scans) == len(lg.scans) and abs(len(a.scans) - len(b.scans)) <= 1
    assert a.scans.stamp[-1] < b.scans.stamp[0] and len(a.odometry) + len(b.odometry) == len(lg.odometry)
    assert a.reference["ground_truth"] is lg.reference["ground_truth"]  # truth stays whole
    cam = camera_log(1, n=2000)
    first = time_slice(cam, int(cam.detections.frame_stamp[0]), int(cam.detections.frame_stamp[100]), "x")
    assert first.detections.n_frames == 100 and (np.diff(first.detections.frame) >= 0).all()
    assert len(first.detections) == int((cam.detections.frame < 100).sum())


@pytest.mark.slow  # end to end: whole simulated runs, tens of CPU seconds; make test-slow (CI) runs it
def test_camera_sensors_cross_validate():
    logs = [camera_log(s, robot=s) for s in (1, 2, 3)]
    cv = cross_validate(logs, "robots")
    t = cv.table
    assert list(t["fold"]) == ["robot1", "robot2", "robot3"] and (t["profile"] == "pooled").all()
    # three sensors of one camera model: every held-out robot is predicted (ECE of a few 1e-3, noise ~0.01)
    assert (t["ece"] < 0.03).all() and (t["false_alarm_relative_error"].abs() < 0.1).all()
    s = cv.summary["pooled"]
    assert s["rows"] == 3 and s["mean_ece"] == pytest.approx(t["ece"].mean())
    tm = cross_validate(logs, "time")
    assert len(tm.table) == 12 and set(tm.table["profile"]) == {"pooled", "own"}  # 2 directions x 3 logs x 2 profiles
    assert set(tm.table["fold"]) == {"1st->2nd", "2nd->1st"} and (tm.table["ece"] < 0.05).all()
    ad = cross_validate(logs, "robots", adapt=300.0)
    assert len(ad.table) == 6 and ad.summary["adapt_s"] == 300.0
    with pytest.raises(UsageError, match="--adapt applies to --cv robots"):
        cross_validate(logs, "time", adapt=10.0)


@pytest.mark.slow  # a calibration per fold and its figures
def test_cv_command_writes_a_table_and_a_figure_per_fold(tmp_path, capsys):
    paths = [write_native(camera_log(s, n=6000), tmp_path / f"cam{s}.dlog") for s in (1, 2)]
    code, out, err = run(capsys, "validate", "--cv", "robots", *map(str, paths), "--out", str(tmp_path / "cv"))
    assert code == 0, err
    assert "cross-validation (robots)" in out and "pooled profile over the folds" in out
    files = sorted(p.name for p in (tmp_path / "cv").iterdir())
    assert {"folds.csv", "folds.png", "summary.yaml", "fold01_pooled.png", "fold02_pooled.png"} <= set(files)
    t = pd.read_csv(tmp_path / "cv/folds.csv")
    assert len(t) == 2 and {"ece", "brier", "loglik_per_pair", "false_alarm_relative_error_ci95_low"} <= set(t.columns)
    s = yaml.safe_load((tmp_path / "cv/summary.yaml").read_text())
    assert s["cv"] == "robots" and s["pooled"]["rows"] == 2


def test_laser_time_split(tmp_path, capsys):
    path = write_native(park(52, 2.0), tmp_path / "p.dlog")
    (tmp_path / "c.yaml").write_text("pd: {min_count: 50}\n")
    code, out, err = run(capsys, "validate", "--cv", "time", str(path), "--config", str(tmp_path / "c.yaml"), "--out", str(tmp_path / "cv"))
    assert code == 0, err
    t = pd.read_csv(tmp_path / "cv/folds.csv")
    # a lap calibrates the other lap of the same park: P_D is well predicted, the gate's coverage is stated
    assert len(t) == 2 and (t["ece"] < 0.05).all() and (t["hotelling_coverage"] > 0.97).all()
    # the coverage comes with the number of held-out true detections it is a share of
    assert (t["true_detections"] >= 50).all()
    assert "coverage" in out and f"of {int(t['true_detections'][0])}" in out


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--cv", "bogus", "x.dlog"], "--cv: expected robots or time, got 'bogus'"),
        (["--cv", "robots"], "--cv needs the logs to cross-validate"),
        (["some-profile"], "validate needs a PROFILE and at least one LOG"),
        (["p", "x.dlog", "--adapt", "10"], "--config and --adapt go with --cv"),
    ],
)
def test_validate_usage_errors(capsys, args, needle):
    code, _, err = run(capsys, "validate", *args)
    assert code == 2
    assert_one_line_error(err, needle)


def test_cross_validation_errors():
    cams = [camera_log(1, n=2000), camera_log(2, n=2000)]
    with pytest.raises(UsageError, match="--cv robots needs at least two logs"):
        cross_validate(cams[:1], "robots")
    with pytest.raises(UsageError, match="cross-validate laser logs and detection-level logs separately"):
        cross_validate([cams[0], park(51, 0.2)], "time")
    with pytest.raises(UsageError, match="--adapt 9999 s is longer than log 'cam1'"):
        cross_validate(cams, "robots", adapt=9999.0)
    with pytest.raises(UsageError, match="log 'cam1_x' has too few frames to cut in halves"):
        halves(time_slice(cams[0], 0, int(3 * 0.25e9), "x"))


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--cv", "robots", "a.dlog", "--adapt", "-5"], "--adapt: expected a positive number of seconds, got -5"),
    ],
)
def test_cv_option_errors(capsys, args, needle):
    code, _, err = run(capsys, "validate", *args)
    assert code == 2
    assert_one_line_error(err, needle)


def test_per_sensor_needs_several_detection_level_sensors(tmp_path, capsys):
    cam = write_native(camera_log(1, n=3000), tmp_path / "cam.dlog")
    code, _, err = run(capsys, "calibrate", str(cam), "--per-sensor", "--out", str(tmp_path / "r"), "--profiles-dir", str(tmp_path / "p"))
    assert code == 2
    assert_one_line_error(err, "--per-sensor needs logs of at least two sensors")
    assert not (tmp_path / "r").exists() and not (tmp_path / "p").exists()  # nothing half-written
    laser = write_native(park(53, 0.3), tmp_path / "p.dlog")
    code, _, err = run(capsys, "calibrate", str(laser), "--per-sensor", "--out", str(tmp_path / "r2"))
    assert code == 2
    assert_one_line_error(err, "--per-sensor applies to detection-level logs")
