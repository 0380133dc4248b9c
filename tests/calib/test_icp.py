import numpy as np
import pytest

from calib.icp import icp_ground_truth, odometry_poses, relation_errors, rigid_align
from calib.sim.park import simulate_park
from detectors.geometry import compose, interpolate_poses, relative
from detectors.sensor_log import Odometry
from tests.conftest import small_park_config


@pytest.fixture(scope="module")
def small_log():
    cfg = small_park_config()
    cfg.bushes.count = 30
    return simulate_park(cfg, 51).log


@pytest.mark.slow  # ICP and the pose graph over a whole simulated log
def test_icp_recovers_the_true_trajectory(small_log):
    log = small_log
    ref = log.reference["ground_truth"]
    truth = interpolate_poses(ref.stamp, ref.poses, log.scans.stamp)
    res = icp_ground_truth(log)
    ate = np.sqrt(np.mean(np.sum((rigid_align(res.poses, truth)[:, :2] - truth[:, :2]) ** 2, axis=1)))
    odo = np.sqrt(np.mean(np.sum((rigid_align(res.odometry, truth)[:, :2] - truth[:, :2]) ** 2, axis=1)))
    assert ate <= 0.05  # the bar: 5 cm of pose RMSE (after the usual rigid alignment)
    assert ate < odo / 3  # and far better than dead reckoning
    assert res.loops  # the figure-eight closes on itself


def test_dead_reckoning_composes_increments(small_log):
    odo = odometry_poses(small_log)
    o = small_log.odometry
    path = np.zeros(3)
    for v in o.values[: 40]:
        path = compose(path, v)
    k = np.searchsorted(small_log.scans.stamp, o.stamp[39])
    assert small_log.scans.stamp[k] == o.stamp[39]
    np.testing.assert_allclose(odo[k], relative(np.zeros(3), path), atol=1e-9)


def test_relation_errors_are_zero_for_the_truth_and_see_an_offset():
    stamps = np.arange(5) * 1_000_000_000
    poses = np.array([[0, 0, 0], [1, 0, 0.1], [2, 0.5, 0.2], [3, 1, 0.1], [4, 1, 0.0]], dtype=float)
    rel = np.column_stack([[0.0, 1.0, 0.0], [1.0, 3.0, 4.0], relative(poses[[0, 1, 0]], poses[[1, 3, 4]])])
    et, er = relation_errors(stamps, poses, rel)
    np.testing.assert_allclose(et, 0, atol=1e-12)
    moved = poses.copy()
    moved[4, 0] += 0.3
    et, _ = relation_errors(stamps, moved, rel)
    assert et[2] == pytest.approx(0.3) and et[0] == pytest.approx(0.0, abs=1e-12)


def test_velocity_odometry_integrates():
    from detectors.sensor_log import ScanBatch, SensorLog, SensorModel

    stamp = np.arange(101) * 100_000_000
    log = SensorLog(
        "v",
        sensor=SensorModel(n_beams=3, angle_min=-0.1, angle_increment=0.1, range_max=10.0),
        scans=ScanBatch(stamp[::10], np.ones((11, 3))),
        odometry=Odometry("velocity", stamp, np.column_stack([np.full(101, 1.0), np.zeros(101)])),
    )
    p = odometry_poses(log)
    np.testing.assert_allclose(p[:, 0], np.arange(11) * 1.0, atol=1e-9)
