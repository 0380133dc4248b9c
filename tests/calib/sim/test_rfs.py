"""The rfs-sim scenario: reproducible, its statistics as configured, and RB-PHD-SLAM recovers its truth."""

import numpy as np
import pytest

from calib.sim.rfs import RfsSimConfig, simulate_rfs, truth_profile


@pytest.fixture(scope="module")
def log():
    return simulate_rfs(RfsSimConfig(steps=400), seed=3)


def test_same_seed_same_bytes_and_the_configured_statistics(tmp_path, log):
    from calib.io.native import write_native

    a = write_native(log, tmp_path / "a.dlog").read_bytes()
    assert a == write_native(simulate_rfs(RfsSimConfig(steps=400), seed=3), tmp_path / "b.dlog").read_bytes()
    assert a != write_native(simulate_rfs(RfsSimConfig(steps=400), seed=4), tmp_path / "c.dlog").read_bytes()
    d = log.detections
    lab = np.asarray(d.descriptors["landmark"])
    true = lab > 0
    assert ((d.range >= 0.5) & (d.range <= 2.5)).all()
    # P_D: detections of each landmark over the steps its true range was inside the limits
    poses = log.reference["ground_truth"].poses
    rel = log.landmarks.xy[None] - poses[:, None, :2]
    inside = (np.hypot(rel[..., 0], rel[..., 1]) > 0.55) & (np.hypot(rel[..., 0], rel[..., 1]) < 2.45)  # away from the noisy edges
    inside[0] = False
    hits = np.zeros_like(inside)
    hits[d.frame[true], lab[true] - 1] = True
    pd = hits[inside].mean()
    assert pd == pytest.approx(0.99, abs=0.005)  # ~10^4 pairs: the binomial std is 0.001
    # the range residuals of true detections have the configured noise
    zr = np.hypot(*(log.landmarks.xy[lab[true] - 1] - poses[d.frame[true], :2]).T)
    assert np.std(d.range[true] - zr) == pytest.approx(np.sqrt(5e-4), rel=0.05)
    prof = truth_profile(RfsSimConfig())
    assert prof.pd.pd == [0.99] and prof.clutter.kappa == pytest.approx(1e-4)


def test_rbphd_slam_recovers_the_map_and_the_path(log):
    """50 particles over 400 steps (40 s) with the C++ library's settings: the map within a few cm of every
    landmark it saw and the path within 5 cm, where odometry drifts by decimetres. The full-length figures
    (1,000 steps, 50 and 200 particles) come from benchmarks/bench_slam.py."""
    from pathlib import Path

    from calib.config import load_yaml_model
    from slam_runtime.config import SlamConfig, override
    from slam_runtime.metrics import ospa
    from slam_runtime.run import evaluate, run_slam

    cfg = override(load_yaml_model(SlamConfig, Path(__file__).resolve().parents[3] / "benchmarks/configs/rfs_sim.yaml"), particles=50)
    res = run_slam(log, truth_profile(RfsSimConfig()), cfg, seed=0)
    m = evaluate(log, res)
    ids = np.unique(np.asarray(log.detections.descriptors["landmark"]))
    seen = log.landmarks.xy[ids[ids > 0] - 1]  # the landmarks the sensor reported in these 40 s
    assert m["odometry_rmse_vs_ground_truth_m"] > 0.1
    assert m["trajectory_rmse_vs_ground_truth_m"] < 0.05
    assert abs(res.map_xy.shape[0] - len(seen)) <= 1
    assert ospa(res.map_xy, seen, c=1.0, p=1.0) < 0.1
