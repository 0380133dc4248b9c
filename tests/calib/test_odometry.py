"""The odometry's noise and biases (calib.odometry) recovered from a simulated robot with known truth."""

from __future__ import annotations

import numpy as np
import pytest

from detectors.sensor_log import Odometry, ReferencePoses, SensorLog
from profiles.errors import DataError


def _robot(
    rng: np.random.Generator,
    *,
    scale: float,
    offset: float,
    s_v: float,
    s_w: float,
    seconds: float = 900.0,
    w_scale: float = 1.0,
    delay: int = 0,
    w_max: float = 0.4,
    dt: float = 0.02,
) -> SensorLog:
    """Velocity commands at 50 Hz held for 2 s each; the true motion is scale (v + e_v) and w_scale (omega + e_w)
    - offset with white noise (e_v, e_w) of std (s_v, s_w) per row on the command, integrated exactly as the unicycle
    does (slam_runtime.vehicle), ``delay`` rows after the command."""
    n = int(seconds / dt)
    hold = int(round(2.0 / dt))
    v = np.repeat(rng.uniform(0.0, 0.3, n // hold + 1), hold)[:n]
    w = np.repeat(rng.uniform(-w_max, w_max, n // hold + 1), hold)[:n]
    late = np.concatenate([np.zeros((delay, 2)), np.column_stack([v, w])[: n - delay]])
    vt = scale * (late[:, 0] + rng.normal(0.0, s_v, n))
    wt = w_scale * (late[:, 1] + rng.normal(0.0, s_w, n)) - offset
    pose = np.zeros((n, 3))
    for k in range(1, n):
        x, y, th = pose[k - 1]
        pose[k] = x + vt[k - 1] * dt * np.cos(th), y + vt[k - 1] * dt * np.sin(th), th + wt[k - 1] * dt
    stamp = np.rint(np.arange(n) * dt * 1e9).astype(np.int64) + 10**9
    odo = Odometry("velocity", stamp, np.column_stack([v, w]))
    truth = ReferencePoses("ground_truth", stamp, pose)
    return SensorLog(name="robot", odometry=odo, reference={"ground_truth": truth})


def test_velocity_odometry_biases_and_noise_against_truth():
    from calib.odometry import fit_velocity_odometry

    rng = np.random.default_rng(4)
    logs = [_robot(rng, scale=0.92, offset=0.01, s_v=0.08, s_w=0.3) for _ in range(2)]
    got = fit_velocity_odometry(logs)
    v = got["velocity"]
    # 1,800 one-second windows (seeds 0-3 gave scale 0.920-0.923, offset 0.009-0.011, sigma_v 0.078-0.081,
    # sigma_omega 0.29-0.30): the scale is a ratio of sums over ~270 m of path (error well below 1 %); the
    # offset is a median of 1,800 window errors of std 0.3 sqrt(0.02) ~ 0.04 rad/s (its error ~0.001 rad/s)
    assert v["speed_scale"] == pytest.approx(0.92, abs=0.006)
    assert v["omega_offset"] == pytest.approx(0.01, abs=0.003)
    # the per-row noise: a window's error is the mean of 50 rows, std s / sqrt(50), scaled back by
    # sqrt(window / dt); the std of 1,800 samples has a relative error ~ 1 / sqrt(2 * 1800) < 2 %
    assert v["sigma_v"] == pytest.approx(0.08, rel=0.06)
    assert v["sigma_omega"] == pytest.approx(0.3, rel=0.06)
    assert got["windows"] >= 1700 and got["row_period_s"] == pytest.approx(0.02)
    # (no delay: seeds 0-5 found 0 or one grid step, 0.02 s)
    assert v["omega_scale"] == pytest.approx(1.0, abs=0.02) and v["delay"] <= 0.021


def test_turn_rate_scale_and_delay():
    """A robot turning 5 % less than commanded, 0.2 s after the command (UTIAS's robots: 0.94-0.96, 0.18-0.3 s):
    the delay, the scale and the noise are recovered; measured as if the motion followed at once, the delay's
    misattributed turns inflate the noise and dilute the scale."""
    from calib.odometry import fit_velocity_odometry

    rng = np.random.default_rng(7)
    logs = [_robot(rng, scale=1.0, offset=0.0, s_v=0.05, s_w=0.3, w_scale=0.95, delay=10) for _ in range(2)]
    got = fit_velocity_odometry(logs)["velocity"]
    # the grid is the row period (0.02 s): a wrong step leaves a 0.02-s slice of every command change (every 2 s)
    # in the errors, a spread the 1,800 windows resolve
    assert got["delay"] == pytest.approx(0.2, abs=0.021)
    # 360 five-second windows of commanded turns ~1 rad rms, heading noise 0.3 sqrt(0.02 x 5) ~ 0.09 rad each:
    # slope error ~0.09 / (1 x sqrt(360)) ~ 0.005, plus the command changes inside a window (seeds 0-5 gave
    # 0.944-0.963, delay 0.20-0.22 s, sigma_omega 0.294-0.302, and 0.415-0.428 without the delay)
    assert got["omega_scale"] == pytest.approx(0.95, abs=0.02)
    assert got["sigma_omega"] == pytest.approx(0.3, rel=0.08)
    assert got["sigma_v"] == pytest.approx(0.05, rel=0.08) and got["speed_scale"] == pytest.approx(1.0, abs=0.01)
    at_once = fit_velocity_odometry(logs, max_delay=0.0)["velocity"]
    assert at_once["delay"] == 0.0 and at_once["sigma_omega"] > 1.3 * got["sigma_omega"]


def test_fast_turns_mixed_row_periods_and_too_little_data():
    """A robot turning up to 1.2 rad/s (6 rad in a 5-s window: the heading change is unwrapped about the command) and
    one logging at 25 Hz beside one at 50 Hz (each log's windows from its own row period) give the scale, delay and
    noise of the simulation; no log, or logs of a few rows, are refused as too little odometry, not a numpy error."""
    from calib.odometry import fit_velocity_odometry

    rng = np.random.default_rng(5)
    fast = fit_velocity_odometry([_robot(rng, scale=1.0, offset=0.0, s_v=0.05, s_w=0.3, w_scale=0.95, delay=10, w_max=1.2) for _ in range(2)])
    assert fast["velocity"]["omega_scale"] == pytest.approx(0.95, abs=0.02)
    assert fast["velocity"]["delay"] == pytest.approx(0.2, abs=0.021)
    assert fast["velocity"]["sigma_omega"] == pytest.approx(0.3, rel=0.08)
    mixed = [_robot(rng, scale=0.92, offset=0.0, s_v=0.05, s_w=0.3, dt=0.04), _robot(rng, scale=0.92, offset=0.0, s_v=0.05, s_w=0.3)]
    got = fit_velocity_odometry(mixed)
    # one-second windows of either log: 25 rows of the first, 50 of the second (900 each)
    assert got["windows"] == pytest.approx(2 * 900, rel=0.01)
    assert got["velocity"]["speed_scale"] == pytest.approx(0.92, abs=0.006)
    with pytest.raises(DataError, match="too little odometry"):
        fit_velocity_odometry([])
    short = _robot(rng, scale=1.0, offset=0.0, s_v=0.05, s_w=0.3, seconds=0.04)
    with pytest.raises(DataError, match="too little odometry"):
        fit_velocity_odometry([short])


def test_a_glitch_in_the_ground_truth_is_not_odometry_noise():
    """A motion-capture heading that jumps 2.5 rad for one sample (UTIAS robot 1 at 1,270 s): the windows over it are
    left out, and the noise is that of the clean log."""
    from calib.odometry import fit_velocity_odometry

    log = _robot(np.random.default_rng(3), scale=1.0, offset=0.0, s_v=0.05, s_w=0.3)
    g = log.reference["ground_truth"]
    poses = g.poses.copy()
    poses[20_000, 2] += 2.5
    bad = SensorLog(name="robot", odometry=log.odometry, reference={"ground_truth": ReferencePoses("ground_truth", g.stamp, poses)})
    clean, broken = fit_velocity_odometry([log]), fit_velocity_odometry([bad])
    assert broken["broken_truth_intervals"] == 2 and clean["broken_truth_intervals"] == 0
    assert broken["velocity"]["sigma_omega"] == pytest.approx(clean["velocity"]["sigma_omega"], rel=0.01)
    assert broken["windows"] < clean["windows"]


def test_velocity_odometry_needs_truth():
    from calib.odometry import fit_velocity_odometry

    log = _robot(np.random.default_rng(0), scale=1.0, offset=0.0, s_v=0.01, s_w=0.01, seconds=30.0)
    bare = SensorLog(name="robot", odometry=log.odometry)
    with pytest.raises(DataError, match="needs velocity odometry and ground-truth poses"):
        fit_velocity_odometry([bare])


def test_calibrate_writes_the_motion_settings_it_measured(tmp_path, capsys):
    """A detection-level calibration of logs with velocity odometry and ground truth writes motion.yaml,
    loadable as SLAM settings, with the same figures as the library call on the same log."""
    from calib.config import load_yaml_model
    from calib.io.registry import read_log
    from calib.odometry import fit_velocity_odometry
    from slam_runtime.config import SlamConfig
    from tests.detcal.cli.test_cli import run
    from tests.conftest import VENDORED

    src = VENDORED / "utias_dataset1"
    cal_cfg = tmp_path / "cal.yaml"  # 30 s of one robot: small bins, so that the excerpt calibrates at all
    cal_cfg.write_text("pd: {table: {min_count: 5, range_bin: 1.0}}\n")
    args = ["calibrate", str(src), "--config", str(cal_cfg), "--out", str(tmp_path / "cal"), "--profiles-dir", str(tmp_path / "p")]
    code, out, err = run(capsys, *args)
    assert code == 0, err
    cfg = load_yaml_model(SlamConfig, tmp_path / "cal/motion.yaml")
    want = fit_velocity_odometry([read_log(src)])["velocity"]
    got = cfg.motion.velocity
    for k in ("sigma_v", "sigma_omega", "speed_scale", "omega_offset", "omega_scale", "delay"):
        assert getattr(got, k) == pytest.approx(want[k], rel=1e-3, abs=1e-6)
