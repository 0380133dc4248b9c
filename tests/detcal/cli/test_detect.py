import numpy as np
import pandas as pd

from detcal.cli import main
from calib.io.native import write_native
from tests.detcal.cli.test_cli import assert_one_line_error, run
from tests.conftest import VENDORED

COLUMNS = ["time", "scan", "frame", "x", "y", "range", "bearing", "radius", "fit_error", "convexity", "points", "maha2"]


def test_detect_writes_table_config_and_plot(tmp_path, capsys, small_sim):
    log = write_native(small_sim.log, tmp_path / "park.dlog")
    code, out, err = run(capsys, "detect", str(log), "--out", str(tmp_path / "det"), "--plot", "10")
    assert code == 0, err
    table = pd.read_csv(tmp_path / "det/detections.csv")
    assert list(table.columns) == COLUMNS and len(table) > 100
    assert (table["frame"] == "sensor").all() and table["maha2"].isna().all()
    assert np.allclose(np.hypot(table.x, table.y), table["range"])
    assert (tmp_path / "det/scan_00010.png").stat().st_size > 10_000
    # gating with a Hotelling model from the config: every kept detection is inside
    (tmp_path / "c.yaml").write_text(
        "detector: {jump: 0.5}\nhotelling: {names: [radius, convexity], mean: [0.2, 0.15], covariance: [[0.01, 0.0], [0.0, 0.01]], gamma: 9.0}\n"
    )
    code, _, err = run(capsys, "detect", str(log), "--out", str(tmp_path / "g"), "--config", str(tmp_path / "c.yaml"))
    assert code == 0, err
    gated = pd.read_csv(tmp_path / "g/detections.csv")
    assert 0 < len(gated) < len(table) and (gated["maha2"] <= 9.0).all()


def test_detect_errors(tmp_path, capsys, small_sim):
    log = write_native(small_sim.log, tmp_path / "park.dlog")
    code, _, err = run(capsys, "detect", str(log), "--out", str(tmp_path / "d"), "--plot", "99999")
    assert code == 2  # a usage error, as --frames 0 is
    assert_one_line_error(err, "--plot: scan 99999 is outside the log")
    assert not (tmp_path / "d").exists()
    code, _, err = run(capsys, "detect", str(VENDORED / "victoria_park"), "--out", str(tmp_path / "v"))
    assert code == 1
    assert_one_line_error(err, "has no laser scans to detect circles in")
    (tmp_path / "bad.yaml").write_text("detector: {jump: -1}\n")
    code, _, err = run(capsys, "detect", str(log), "--out", str(tmp_path / "b"), "--config", str(tmp_path / "bad.yaml"))
    assert code == 2
    assert_one_line_error(err, "bad.yaml: detector.jump: Input should be greater than 0")
    assert main(["detect", "--help"]) == 0


def test_detect_with_the_bundled_profile(tmp_path, capsys, small_sim):
    log = write_native(small_sim.log, tmp_path / "park.dlog")
    code, _, err = run(capsys, "detect", str(log), "--out", str(tmp_path / "p"), "--profile", "sim-park-laser@1.0.0", "--plot", "5")
    assert code == 0, err
    table = pd.read_csv(tmp_path / "p/detections.csv")
    assert len(table) > 50 and np.isfinite(table["maha2"]).all() and (table["maha2"] <= 16.27).all()
    code, _, err = run(capsys, "detect", str(log), "--profile", "sim-park-laser", "--config", "x.yaml")
    assert code == 2
    assert_one_line_error(err, "--profile and --config both set the detector")
