"""The planar path through the command line: simulate street, log info, detect, calibrate, validate, slam run."""

from __future__ import annotations

import numpy as np
import yaml

from detcal.cli import main


def run(capsys, *args):
    code = main([str(a) for a in args])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_street_end_to_end(tmp_path, capsys):
    cfg = tmp_path / "street.yaml"
    cfg.write_text(yaml.safe_dump({"lidar": {"azimuth_increment_deg": 0.5}, "route": [{"kind": "straight", "length": 40.0}], "extend": 20.0}))
    sim = tmp_path / "sim"
    code, out, err = run(capsys, "simulate", "street", "--out", sim, "--seed", "2", "--frames", "6", "--config", cfg)
    assert code == 0, err
    log = sim / "log.dlog"
    code, out, _ = run(capsys, "log", "info", log)
    assert code == 0 and "point clouds" in out and "planes (truth)" in out and "64 rings" in out
    code, out, err = run(capsys, "detect", log, "--out", tmp_path / "det", "--plot", "3")
    assert code == 0, err
    names = {p.name for p in (tmp_path / "det").iterdir()}
    assert {"planes.csv", "outlines.csv", "planes_00003.png", "transition_00003.png", "transition_00003.csv", "summary.yaml"} <= names
    summary = yaml.safe_load((tmp_path / "det" / "summary.yaml").read_text())
    assert summary["transition_normal_angle_median_deg"] < 1.0  # eq. 35 with the true poses: the same planes again
    calcfg = tmp_path / "cal.yaml"
    calcfg.write_text(yaml.safe_dump({"pd": {"min_count": 5}}))
    code, out, err = run(capsys, "calibrate", log, "--name", "street-cli", "--out", tmp_path / "cal", "--profiles-dir", tmp_path / "prof", "--config", calcfg)
    assert code == 0, err
    prof = tmp_path / "prof" / "street-cli@1.0.0.yaml"
    assert yaml.safe_load(prof.read_text())["detector"]["kind"] == "plane3d"
    code, out, err = run(capsys, "validate", prof, log, "--out", tmp_path / "val")
    # six frames of its own calibration log: no part can be tested (a plane grid's P_D, clutter on under 100
    # frames): too little data, exit code 4
    assert code == 4 and "verdict: too little data" in out, out + err
    code, out, err = run(capsys, "slam", "run", log, "--profile", prof, "--features", "planes", "--particles", "5", "--out", tmp_path / "slam")
    assert code == 0, err
    m = yaml.safe_load((tmp_path / "slam" / "metrics.yaml").read_text())
    assert np.isfinite(m["trajectory_rmse_vs_ground_truth_m"]) and "map_ospa" in m
    assert (tmp_path / "slam" / "map.csv").read_text().startswith("L_nx,L_ny,L_nz,d,weight")
    # a plane profile on points, and points on a plane profile, are refused with the reason
    code, _, err = run(capsys, "slam", "run", log, "--profile", prof, "--out", tmp_path / "slam2")
    assert code == 2 and "run it with --features planes" in err
    code, _, err = run(capsys, "slam", "run", log, "--profile", prof, "--features", "lines", "--out", tmp_path / "slam3")
    assert code == 2 and "--features: expected one of points, planes" in err
    # a sweep whose varied features do not fit the profile is refused before any run, nothing written
    code, _, err = run(capsys, "slam", "sweep", log, "--profile", prof, "--vary", "features=points,planes", "--workers", "0", "--out", tmp_path / "sw")
    assert code == 2 and "--vary features=points: profile street-cli@1.0.0 is a lidar3d-planes profile; run it with features: planes (in --config or --vary)" in err
    assert not (tmp_path / "sw").exists()


def test_bad_clouds_exit_with_one_line(tmp_path, capsys):
    folder = tmp_path / "kitti"
    folder.mkdir()
    (folder / "000000.bin").write_bytes(np.zeros((10, 4), "<f4").tobytes()[:-4])
    code, _, err = run(capsys, "detect", folder / "000000.bin", "--out", tmp_path / "d1")
    assert code == 1 and "000000.bin: size 156 bytes is not a multiple of 16" in err and "Traceback" not in err
    pts = np.random.default_rng(0).normal(size=(50, 4)).astype("<f4")
    pts[7, 2] = np.nan
    (folder / "000000.bin").write_bytes(pts.tobytes())
    code, _, err = run(capsys, "detect", folder / "000000.bin", "--out", tmp_path / "d2")
    assert code == 1 and "point 7 has a NaN or infinite coordinate" in err
    (folder / "000000.bin").write_bytes(b"")
    code, _, err = run(capsys, "log", "info", folder / "000000.bin")
    assert code == 1 and "empty frame (no points)" in err
