"""`detcal slam run` and `detcal slam sweep`: run folders, reproducibility, clear errors."""

import csv
import shutil

import pytest
import yaml

from detcal.reports.simulation import write_simulation_run
from tests.detcal.cli.test_cli import assert_one_line_error, run
from tests.conftest import VENDORED, small_park_config
from profiles.override import updated


@pytest.fixture(scope="module")
def park_log(tmp_path_factory):
    cfg = small_park_config()
    cfg.bushes.count = 30
    folder = tmp_path_factory.mktemp("slam") / "park"
    write_simulation_run("park", cfg, 71, folder)
    return folder / "log.dlog"


def test_slam_run_writes_a_reproducible_run_folder(tmp_path, capsys, park_log):
    args = ["slam", "run", str(park_log), "--profile", "sim-park-laser", "--frames", "60", "--seed", "3"]
    code, out, err = run(capsys, *args, "--out", str(tmp_path / "a"))
    assert code == 0, err
    names = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert names == [".detcal-output", "config.yaml", "map.csv", "metrics.yaml", "ospa.png", "steps.csv", "timing.png", "trajectory.csv", "trajectory_map.png", "warnings.yaml"]
    m = yaml.safe_load((tmp_path / "a/metrics.yaml").read_text())
    assert m["frames"] == 60 and m["landmarks_true"] == 40
    # the truth is known: the filter, started at the true pose, stays within a metre over 12 s
    assert m["trajectory_rmse_vs_ground_truth_m"] < 1.0 and m["odometry_rmse_vs_ground_truth_m"] < 1.0
    assert 0.0 <= m["map_ospa"] <= 1.0
    cfg = yaml.safe_load((tmp_path / "a/config.yaml").read_text())
    assert cfg["profile"] == "sim-park-laser@1.0.0" and cfg["seed"] == 3 and cfg["settings"]["particles"] == 20 and cfg["settings"]["filter"]["kind"] == "rbphd"
    # same inputs and seed: same trajectory and map, byte for byte
    code, _, err = run(capsys, *args, "--out", str(tmp_path / "b"))
    assert code == 0, err
    for f in ("trajectory.csv", "map.csv"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes()
    rows = list(csv.DictReader((tmp_path / "a/steps.csv").read_text().splitlines()))
    assert len(rows) == 60 and all(float(r["ess"]) > 0 for r in rows)
    # never silently replaced
    code, _, err = run(capsys, *args, "--out", str(tmp_path / "a"))
    assert code == 2
    assert_one_line_error(err, "already exists")


def test_slam_run_usage_and_data_errors(tmp_path, capsys, park_log):
    base = ["slam", "run", str(park_log), "--profile", "sim-park-laser", "--out", str(tmp_path / "x")]
    code, _, err = run(capsys, *base, "--filter", "ekf")
    assert code == 2
    assert_one_line_error(err, "--filter: expected one of rbphd")
    code, _, err = run(capsys, *base, "--particles", "0")
    assert code == 2
    assert_one_line_error(err, "--particles: expected a positive integer")
    bad = tmp_path / "bad.yaml"
    bad.write_text("filter:\n  kind: rbphd\n  prunne: 0.1\n")
    code, _, err = run(capsys, *base, "--config", str(bad))
    assert code == 2
    assert_one_line_error(err, "filter.rbphd.prunne: unknown key")
    bad.write_text("particles: 0\n")
    code, _, err = run(capsys, *base, "--config", str(bad))
    assert code == 2
    assert_one_line_error(err, "particles: Input should be greater than or equal to 1")
    code, _, err = run(capsys, *base, "--profile", "no-such-profile")
    assert code != 0
    assert_one_line_error(err, "no-such-profile")
    vp = VENDORED / "victoria_park"
    code, _, err = run(capsys, "slam", "run", str(vp), "--profile", "sim-park-laser", "--out", str(tmp_path / "y"))
    assert code == 2
    assert_one_line_error(err, "detects circles in laser scans, and this log has none")
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_slam_run_on_a_detection_log_with_gps(tmp_path, capsys):
    """The vendored Victoria Park excerpt: detections + Ackermann odometry, scored against GPS after a rigid fit."""
    prof = VENDORED.parent.parent / "benchmarks/profiles/victoria-park-nominal@1.0.0.yaml"
    folder = tmp_path / "vp"
    shutil.copytree(VENDORED / "victoria_park", folder)
    code, out, err = run(capsys, "slam", "run", str(folder), "--profile", str(prof), "--particles", "5", "--out", str(tmp_path / "r"))
    assert code == 0, err
    # the summary says why a figure is not defined instead of printing nan (GPS: the end is placed by the rigid fit)
    assert "nan" not in out and "n/a (a rigid fit to GPS places the end" in " ".join(out.split())
    m = yaml.safe_load((tmp_path / "r/metrics.yaml").read_text())
    assert m["alignment_vs_gps"].startswith("rigid") and m["points_vs_gps"] > 0
    assert m["trajectory_rmse_vs_gps_m"] >= 0 and "map_ospa" not in m
    # two frames see one GPS point: a rigid fit (3 degrees of freedom) matches it exactly, so no RMSE is claimed
    code, out, err = run(capsys, "slam", "run", str(folder), "--profile", str(prof), "--particles", "2", "--frames", "2", "--out", str(tmp_path / "r2"))
    assert code == 0, err
    assert "nan" not in out and "n/a (fewer than 3 reference points" in " ".join(out.split())
    m = yaml.safe_load((tmp_path / "r2/metrics.yaml").read_text())
    assert m["points_vs_gps"] < 3 and m["trajectory_rmse_vs_gps_m"] != m["trajectory_rmse_vs_gps_m"]  # NaN


def test_slam_sweep_tabulates_runs(tmp_path, capsys, park_log):
    code, out, err = run(
        capsys, "slam", "sweep", str(park_log), "--profile", "sim-park-laser", "--seeds", "2", "--frames", "25",
        "--particles", "5", "--workers", "0", "--out", str(tmp_path / "sw"),
    )
    assert code == 0, err
    runs = list(csv.DictReader((tmp_path / "sw/runs.csv").read_text().splitlines()))
    assert len(runs) == 4 and {r["pd_mode"] for r in runs} == {"profile", "constant"} and {r["seed"] for r in runs} == {"0", "1"}
    summary = list(csv.DictReader((tmp_path / "sw/summary.csv").read_text().splitlines()))
    assert len(summary) == 2 and all(s["runs"] == "2" for s in summary)
    assert len([p for p in (tmp_path / "sw").iterdir() if p.is_dir()]) == 4
    # the P_D modes compared run by run: calibrated - constant on the same log and seed
    pairs = [r for r in csv.DictReader((tmp_path / "sw/paired.csv").read_text().splitlines()) if r["metric"] == "map_ospa"]
    ospa = {(r["pd_mode"], r["seed"]): float(r["map_ospa"]) for r in runs}
    diff = [ospa["profile", s] - ospa["constant", s] for s in ("0", "1")]
    assert len(pairs) == 1 and (pairs[0]["varies"], pairs[0]["a"], pairs[0]["b"], pairs[0]["pairs"]) == ("pd_mode", "profile", "constant", "2")
    assert float(pairs[0]["mean_difference"]) == pytest.approx(sum(diff) / 2, abs=1e-5)
    assert int(pairs[0]["a_lower"]) == sum(d < 0 for d in diff)
    assert "paired by log and seed" in out and "pd_mode:" in out
    code, _, err = run(capsys, "slam", "sweep", str(park_log), "--profile", "sim-park-laser", "--pd-mode", "fixed", "--out", str(tmp_path / "s2"))
    assert code == 2
    assert_one_line_error(err, "--pd-mode: expected one of profile, constant")


def test_an_n_p_profile_refuses_a_laser_of_another_beam_geometry(tmp_path, capsys, park_log):
    from profiles.store import dump_profile, resolve

    prof = resolve("sim-park-laser@1.0.0")
    other = updated(prof, {"name": "coarse", "sensor.n_beams": 181, "sensor.angle_increment": 0.017453292519943295})
    (tmp_path / "coarse.yaml").write_text(dump_profile(other))
    code, _, err = run(capsys, "slam", "run", str(park_log), "--profile", str(tmp_path / "coarse.yaml"), "--out", str(tmp_path / "r"))
    assert code == 2
    assert_one_line_error(err, "calibrated for 181 beams from -90.00 deg every 1.0000 deg; this log's laser has 361")
    assert not (tmp_path / "r").exists()


def test_slam_run_with_the_poses_given_maps_along_the_truth(tmp_path, capsys, park_log):
    """``--poses ground_truth``: mapping only, every particle on the simulator's path, so the run's trajectory is the
    truth (to rounding) and the config records the mode; a log with GPS only, or a setting that is not a mode, is
    refused in one line before anything is written, by ``slam sweep`` before any run."""
    args = ["slam", "run", str(park_log), "--profile", "sim-park-laser", "--frames", "60", "--particles", "5", "--poses", "ground_truth"]
    code, out, err = run(capsys, *args, "--out", str(tmp_path / "a"))
    assert code == 0, err
    m = yaml.safe_load((tmp_path / "a/metrics.yaml").read_text())
    assert m["trajectory_rmse_vs_ground_truth_m"] < 1e-9 and m["odometry_rmse_vs_ground_truth_m"] > 0.01
    assert yaml.safe_load((tmp_path / "a/config.yaml").read_text())["settings"]["poses"] == "ground_truth"
    assert "poses: ground truth" in out
    code, _, err = run(capsys, *args[:-1], "truth", "--out", str(tmp_path / "b"))
    assert code == 2
    assert_one_line_error(err, "--poses: expected one of estimated, ground_truth, got 'truth'")
    prof = VENDORED.parent.parent / "benchmarks/profiles/victoria-park-nominal@1.0.0.yaml"
    vp = ["--profile", str(prof), "--particles", "5", "--poses", "ground_truth"]
    code, _, err = run(capsys, "slam", "run", str(VENDORED / "victoria_park"), *vp, "--out", str(tmp_path / "c"))
    assert code == 1
    assert_one_line_error(err, "poses: ground_truth needs ground-truth poses, and the log has none (its references: gps)")
    code, _, err = run(capsys, "slam", "sweep", str(VENDORED / "victoria_park"), *vp, "--workers", "0", "--out", str(tmp_path / "d"))
    assert code == 1
    assert_one_line_error(err, "poses: ground_truth needs ground-truth poses")
    assert not any((tmp_path / n).exists() for n in "bcd")
    code, _, err = run(
        capsys, "slam", "sweep", str(park_log), "--profile", "sim-park-laser", "--frames", "20", "--particles", "5",
        "--poses", "ground_truth", "--workers", "0", "--out", str(tmp_path / "e"),
    )
    assert code == 0, err
    runs = list(csv.DictReader((tmp_path / "e/runs.csv").read_text().splitlines()))
    assert len(runs) == 2 and all(float(r["trajectory_rmse_vs_ground_truth_m"]) < 1e-9 for r in runs)


def test_a_runs_counted_warnings_are_saved_in_its_folder(tmp_path, capsys, park_log):
    """A legal but suspicious profile (no clutter, two P_D bins of 1): its counted warnings, as printed, are the run
    folder's warnings.yaml and are listed in its summary; a second run writes the same bytes."""
    from profiles.store import BUILTIN

    d = yaml.safe_load((BUILTIN / "sim-park-laser@1.0.0.yaml").read_text())
    d["clutter"].update(rate=0.0, kappa=None)
    (tmp_path / "quiet.yaml").write_text(yaml.safe_dump(d))
    args = ["slam", "run", str(park_log), "--profile", str(tmp_path / "quiet.yaml"), "--frames", "20", "--seed", "3"]
    code, _, err = run(capsys, *args, "--out", str(tmp_path / "a"))
    assert code == 0, err
    printed = [x.removeprefix("detcal: warning: ") for x in err.splitlines() if x.startswith("detcal: warning: ")]
    assert any("pd: 2 of 9 P_D bins are 1 with clutter.rate 0" in x for x in printed)
    assert any(f"clutter.rate: 0 false alarms in {d['clutter']['frames']} frames" in x for x in printed)
    saved = yaml.safe_load((tmp_path / "a/warnings.yaml").read_text())
    assert saved == {"count": len(printed), "warnings": printed}
    assert yaml.safe_load((tmp_path / "a/metrics.yaml").read_text())["warnings"] == printed
    code, _, err = run(capsys, *args, "--out", str(tmp_path / "b"))
    assert code == 0, err
    assert (tmp_path / "a/warnings.yaml").read_bytes() == (tmp_path / "b/warnings.yaml").read_bytes()
