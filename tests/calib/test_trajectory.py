import numpy as np
import pytest

from calib.trajectory import kitti_text, read_tum, relation_scores, tum_text
from detectors.geometry import relative


def _path(n=50, seed=0):
    rng = np.random.default_rng(seed)
    inc = np.column_stack([rng.uniform(0.1, 0.5, n), rng.normal(0, 0.02, n), rng.normal(0, 0.2, n)])
    th = np.cumsum(inc[:, 2])
    x = np.cumsum(inc[:, 0] * np.cos(th))
    y = np.cumsum(inc[:, 0] * np.sin(th))
    return np.column_stack([x, y, np.mod(th + np.pi, 2 * np.pi) - np.pi])


def test_tum_round_trip_keeps_stamps_and_poses(tmp_path):
    poses = _path()
    stamps = 1_700_000_000_123_456_789 + np.arange(len(poses), dtype=np.int64) * 100_000_001
    (tmp_path / "t.txt").write_text(tum_text(stamps, poses))
    t, back = read_tum(tmp_path / "t.txt")
    assert (tmp_path / "t.txt").read_text().splitlines()[1].startswith("1700000000.123456789 ")  # nanoseconds written exactly
    np.testing.assert_allclose(t, stamps / 1e9, rtol=0, atol=1e-6)
    np.testing.assert_allclose(back, poses, atol=1e-7)  # 9 significant digits of the coordinates


def test_kitti_rows_are_the_pose_matrices():
    poses = _path(5)
    rows = np.array([list(map(float, line.split())) for line in kitti_text(poses).splitlines()])
    assert rows.shape == (5, 12)
    m = rows.reshape(5, 3, 4)
    np.testing.assert_allclose(m[:, 0, 3], poses[:, 0], atol=1e-7)
    np.testing.assert_allclose(np.arctan2(m[:, 1, 0], m[:, 0, 0]), poses[:, 2], atol=1e-7)
    np.testing.assert_allclose(m[:, 2, :3], np.tile([0.0, 0.0, 1.0], (5, 1)))  # planar: rotation about z


def test_relation_scores_state_mean_sd_and_max():
    poses = _path(20)
    stamps = np.arange(20, dtype=np.int64) * 1_000_000_000
    i, j = np.arange(0, 18), np.arange(2, 20)
    rel = np.column_stack([i * 1.0, j * 1.0, relative(poses[i], poses[j])])
    moved = poses.copy()
    moved[7, :2] += [0.3, 0.4]  # one pose off by 0.5 m: the two relations that use it see 0.5 m
    sc = relation_scores(stamps, moved, rel)
    assert sc["relations"] == 18
    assert sc["trans_max_m"] == pytest.approx(0.5)
    assert sc["trans_mean_m"] == pytest.approx(2 * 0.5 / 18)
    assert sc["trans_sq_mean_m2"] == pytest.approx(2 * 0.25 / 18)
    assert sc["rot_max_deg"] == pytest.approx(0.0, abs=1e-9)
