"""The commands issue 54 adds: `detcal slam run --filter mhfastslam` on point and planar logs, `detcal simulate
two-stage` with its options, and the labelled filters' moving features through `--set filter.feature_motion=...`."""

import csv

import numpy as np
import pytest
import yaml

from calib.sim.glmb_paper import GlmbPaperConfig
from detcal.reports.simulation import write_simulation_run
from tests.detcal.cli.test_cli import assert_one_line_error, run


@pytest.fixture(scope="module")
def paper(tmp_path_factory):
    folder = tmp_path_factory.mktemp("paper") / "c1"
    write_simulation_run("glmb-paper", GlmbPaperConfig(clutter=1.0), 2, folder)
    return folder


def test_mhfastslam_runs_on_points(tmp_path, capsys, paper):
    """glmb-paper (P_D 0.7, one false alarm per scan), 5 particles, the first 120 scans: the run folder of a
    non-labelled filter, the same bytes again, and a map whose features lie near landmarks.

    Tolerance: after 120 scans at 1 m/s (the first side of the loop) the landmarks seen are each detected about 10
    times at sigma 0.3 m / 2 deg; an OSPA (c = 0.5 m) of the map below 0.35 m means most mapped features lie within
    a few tenths of a metre of a landmark with few false or missing ones (a map of clutter would sit near c)."""
    args = ["slam", "run", str(paper / "log.dlog"), "--profile", str(paper / "profile.yaml"), "--filter", "mhfastslam", "--particles", "5"]
    args += ["--frames", "120", "--seed", "3", "--set", "metric.ospa_c=0.5"]
    code, _, err = run(capsys, *args, "--out", str(tmp_path / "a"))
    assert code == 0, err
    names = sorted(p.name for p in (tmp_path / "a").iterdir() if not p.name.startswith("."))
    assert names == ["config.yaml", "map.csv", "metrics.yaml", "ospa.png", "steps.csv", "timing.png", "trajectory.csv", "trajectory_map.png", "warnings.yaml"]
    m = yaml.safe_load((tmp_path / "a/metrics.yaml").read_text())
    assert m["filter"] == "MH-FastSLAM"
    assert yaml.safe_load((tmp_path / "a/config.yaml").read_text())["settings"]["filter"]["kind"] == "mhfastslam"
    assert m["landmarks_mapped"] >= 3 and m["map_ospa"] < 0.35, m
    code, _, err = run(capsys, *args, "--out", str(tmp_path / "b"))
    assert code == 0, err
    for f in ("trajectory.csv", "map.csv"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes()


def test_mhfastslam_runs_on_planes(tmp_path, capsys, small_street, street_profile):
    """The street's planes through the same command (--features planes), 12 frames: a map of planes is written."""
    from calib.io.native import write_native
    from profiles.store import dump_profile

    write_native(small_street.log, tmp_path / "street.dlog")
    (tmp_path / "prof.yaml").write_text(dump_profile(street_profile))
    code, _, err = run(
        capsys, "slam", "run", str(tmp_path / "street.dlog"), "--profile", str(tmp_path / "prof.yaml"), "--features", "planes",
        "--filter", "mhfastslam", "--particles", "4", "--frames", "12", "--out", str(tmp_path / "s"),
    )  # fmt: skip
    assert code == 0, err
    rows = list(csv.DictReader((tmp_path / "s/map.csv").read_text().splitlines()))
    assert rows and set(rows[0]) == {"L_nx", "L_ny", "L_nz", "d", "weight"}
    assert yaml.safe_load((tmp_path / "s/metrics.yaml").read_text())["map_normal_angle_median_deg"] < 1.0


def test_simulate_two_stage_with_its_options(tmp_path, capsys):
    """--path spiral --moving: the run folder holds the truth the options ask for; the same seed, the same bytes."""
    from calib.io.native import read_native
    from calib.sim.two_stage import TwoStageConfig, simulate_two_stage

    code, text, err = run(capsys, "simulate", "two-stage", "--path", "spiral", "--moving", "--seed", "4", "--out", str(tmp_path / "a"))
    assert code == 0, err
    assert "two-stage scenario" in text
    names = sorted(p.name for p in (tmp_path / "a").iterdir() if not p.name.startswith("."))
    assert names == ["config.yaml", "features.csv", "log.dlog", "overview.png", "profile.yaml", "summary.yaml", "warnings.yaml"]
    cfg = yaml.safe_load((tmp_path / "a/config.yaml").read_text())
    assert cfg["seed"] == 4 and cfg["two_stage"]["path"] == "spiral" and cfg["two_stage"]["moving"] is True
    truth = simulate_two_stage(TwoStageConfig(path="spiral", moving=True), 4)
    rows = np.loadtxt(tmp_path / "a/features.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(rows[:, 2:].reshape(truth.features.shape), truth.features, atol=1e-6)
    assert np.ptp(truth.features[:, :, :2], axis=0).max() > 10.0  # the points moved
    np.testing.assert_allclose(read_native(tmp_path / "a/log.dlog").landmarks.xy, truth.features[-1, :, :2])
    code, _, err = run(capsys, "simulate", "two-stage", "--path", "spiral", "--moving", "--seed", "4", "--out", str(tmp_path / "b"))
    assert code == 0, err
    for f in ("log.dlog", "features.csv", "profile.yaml"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes()
    code, _, err = run(capsys, "simulate", "two-stage", "--static", "--steps-typo", "3", "--out", str(tmp_path / "c"))
    assert code == 2
    code, _, err = run(capsys, "simulate", "two-stage", "--static", "--out", str(tmp_path / "c"))
    assert code == 0, err
    assert yaml.safe_load((tmp_path / "c/config.yaml").read_text())["two_stage"]["moving"] is False


def test_simulate_two_stage_refuses_a_bad_path(tmp_path, capsys):
    code, _, err = run(capsys, "simulate", "two-stage", "--path", "zigzag", "--out", str(tmp_path / "z"))
    assert code == 2
    assert_one_line_error(err, "--path")
    assert not (tmp_path / "z").exists()


@pytest.mark.parametrize("kind", ["lmb", "glmb"])
def test_labelled_filters_track_moving_points(tmp_path, capsys, kind):
    """A two-stage run whose points move, mapped along the true path by a labelled filter told that they move: the
    run folder's settings say so and the map estimate's positions (x, y) are written, not the velocity columns;
    the same filter on planes is refused with the setting named."""
    sim = tmp_path / "sim"
    code, _, err = run(capsys, "simulate", "two-stage", "--moving", "--seed", "2", "--out", str(sim))
    assert code == 0, err
    args = ["slam", "run", str(sim / "log.dlog"), "--profile", str(sim / "profile.yaml"), "--filter", kind, "--particles", "1"]
    args += ["--poses", "ground_truth", "--set", "filter.feature_motion=constant_velocity", "--set", "metric.ospa_c=100"]
    code, _, err = run(capsys, *args, "--out", str(tmp_path / "run"))
    assert code == 0, err
    cfg = yaml.safe_load((tmp_path / "run/config.yaml").read_text())["settings"]["filter"]
    assert cfg["feature_motion"] == "constant_velocity" and cfg["feature_acceleration"] == 0.5
    rows = list(csv.DictReader((tmp_path / "run/map.csv").read_text().splitlines()))
    assert rows and set(rows[0]) == {"x", "y", "weight"}
    code, _, err = run(capsys, *args, "--set", "filter.feature_motion=drifting", "--out", str(tmp_path / "bad"))
    assert code == 2
    assert_one_line_error(err, "feature_motion")
