"""The glmb-paper scenario: reproducible, its statistics as configured (Table I of the delta-GLMB-SLAM paper),
the four clutter rates on one path, and the command that writes it."""

import numpy as np
import pytest
import yaml

from calib.sim.glmb_paper import GlmbPaperConfig, simulate_glmb_paper, truth_profile
from detectors.model import DetectionModel
from profiles.errors import UsageError
from tests.detcal.cli.test_cli import assert_one_line_error, run


@pytest.fixture(scope="module")
def logs():
    return {c: simulate_glmb_paper(GlmbPaperConfig(clutter=c), seed=5) for c in (1.0, 15.0)}


def test_same_seed_same_bytes_and_the_configured_statistics(tmp_path, logs):
    from calib.io.native import write_native

    log = logs[15.0]
    a = write_native(log, tmp_path / "a.dlog").read_bytes()
    assert a == write_native(simulate_glmb_paper(GlmbPaperConfig(clutter=15.0), seed=5), tmp_path / "b.dlog").read_bytes()
    assert a != write_native(simulate_glmb_paper(GlmbPaperConfig(clutter=15.0), seed=6), tmp_path / "c.dlog").read_bytes()
    d = log.detections
    lab = np.asarray(d.descriptors["landmark"])
    true = lab > 0
    gt = log.reference["ground_truth"]
    poses = gt.poses[np.searchsorted(gt.stamp, d.frame_stamp)]
    assert log.landmarks.xy.shape == (23, 2) and np.unique(lab[true]).size == 23  # every landmark is seen
    # P_D 0.7 over the (scan, landmark) pairs in range: ~700 pairs, binomial std 0.017
    rel = log.landmarks.xy[None] - poses[:, None, :2]
    inside = np.hypot(rel[..., 0], rel[..., 1]) <= 3.0
    hits = np.zeros_like(inside)
    hits[d.frame[true], lab[true] - 1] = True
    assert hits[inside].mean() == pytest.approx(0.7, abs=0.05)
    assert not hits[~inside].any()
    # clutter: Poisson with mean 15 per scan, uniform over 0-3 m (450 scans: the mean's std is 0.18)
    per_scan = np.bincount(d.frame[~true], minlength=d.n_frames)
    assert per_scan.mean() == pytest.approx(15.0, abs=0.6)
    assert per_scan.var() == pytest.approx(15.0, rel=0.2)
    assert d.range[~true].max() <= 3.0
    # range and bearing noise of the true detections (Table I: 0.3 m, 2 deg); ~700 samples, 3 % std of a std
    zr = np.hypot(*(log.landmarks.xy[lab[true] - 1] - poses[d.frame[true], :2]).T)
    assert np.std(d.range[true] - zr) == pytest.approx(0.3, rel=0.1)
    # the odometry: v = 1 m/s with 0.1 m/s of noise per control step
    assert np.mean(log.odometry.values[:, 0]) == pytest.approx(1.0, abs=0.01)
    assert np.std(log.odometry.values[:, 0]) == pytest.approx(0.1, rel=0.1)


def test_clutter_rates_share_the_path_and_the_detections(logs):
    """The paper's four runs differ only in their clutter: same controls, same landmark detections."""
    a, b = logs[1.0], logs[15.0]
    np.testing.assert_array_equal(a.odometry.values, b.odometry.values)
    np.testing.assert_array_equal(a.reference["ground_truth"].poses, b.reference["ground_truth"].poses)
    ta, tb = (np.asarray(x.detections.descriptors["landmark"]) > 0 for x in (a, b))
    np.testing.assert_array_equal(a.detections.range[ta], b.detections.range[tb])


def test_other_clutter_draws_keep_the_world(logs):
    """clutter_draw: the seed's path, controls and detections with false alarms from another stream (a
    different stream per draw, each reproducible, none the seed's own); a negative draw is refused."""
    own = logs[15.0]
    cfg = GlmbPaperConfig(clutter=15.0)
    draws = [simulate_glmb_paper(cfg, seed=5, clutter_draw=k) for k in (0, 1)]
    true = [np.asarray(x.detections.descriptors["landmark"]) > 0 for x in (own, *draws)]
    clutter = [x.detections.range[~t] for x, t in zip((own, *draws), true)]
    for x, t in zip(draws, true[1:]):
        np.testing.assert_array_equal(x.odometry.values, own.odometry.values)
        np.testing.assert_array_equal(x.detections.range[t], own.detections.range[true[0]])
        np.testing.assert_array_equal(x.detections.bearing[t], own.detections.bearing[true[0]])
    # each draw its own clutter (a different count, or else different points), and the same again for the same draw
    assert not np.array_equal(clutter[1], clutter[0]) and not np.array_equal(clutter[2], clutter[0])
    assert not np.array_equal(clutter[1], clutter[2])
    again = simulate_glmb_paper(cfg, seed=5, clutter_draw=1)
    np.testing.assert_array_equal(again.detections.range, draws[1].detections.range)
    assert abs(clutter[1].size / own.detections.n_frames - 15.0) < 0.6  # still Poisson(15) per scan
    # not a stream the seed already uses for its controls or detections: its first draw is the clutter count
    # of the first scan, which those streams would give as the seed's own first Poisson(15) draws
    for k, x in zip((0, 1), draws):
        counts = np.bincount(x.detections.frame[~(np.asarray(x.detections.descriptors["landmark"]) > 0)], minlength=x.detections.n_frames)
        streams = [np.random.default_rng(c).poisson(15.0, counts.size) for c in np.random.SeedSequence(5).spawn(3 + k + 1)]
        assert [np.array_equal(counts, s) for s in streams] == [False] * (3 + k) + [True]
        assert x.source["clutter_draw"] == k
    assert "clutter_draw" not in own.source
    for bad in (-1, 1.5, True):
        with pytest.raises(UsageError, match="clutter_draw"):
            simulate_glmb_paper(cfg, seed=5, clutter_draw=bad)


def test_truth_profile_states_the_simulators_statistics(logs):
    """P_D 0.7 out to 3 m by the landmark's range and 0 beyond (a noisy report may lie past 3 m), and the
    clutter intensity kappa = lambda / (3 m x 2 pi) where the clutter lies."""
    cfg = GlmbPaperConfig(clutter=5.0)
    det = DetectionModel.from_profile(truth_profile(cfg))
    np.testing.assert_allclose(det.pd_at(np.array([[1.0, 0.0], [2.99, 3.0], [3.2, 0.0]])), [0.7, 0.7, 0.0])
    assert det.clutter_intensity(np.array([[2.0, 1.0]]))[0] == pytest.approx(5.0 / (3.0 * 2 * np.pi))
    assert det.noise_sigmas == pytest.approx((0.3, np.radians(2.0)))
    log = logs[1.0]
    assert det.in_fov(np.column_stack([log.detections.range, log.detections.bearing])).all()


def test_simulate_glmb_paper_command(tmp_path, capsys):
    out = tmp_path / "gp"
    code, _, err = run(capsys, "simulate", "glmb-paper", "--out", str(out), "--clutter", "10", "--seed", "2")
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == [".detcal-output", "config.yaml", "log.dlog", "overview.png", "profile.yaml", "summary.yaml", "warnings.yaml"]
    s = yaml.safe_load((out / "summary.yaml").read_text())
    assert s["landmarks"] == 23 and s["landmarks_seen"] == 23 and 9.0 < s["false_alarms_per_scan"] < 11.0
    assert yaml.safe_load((out / "profile.yaml").read_text())["name"] == "glmb-paper-c10"
    code, _, err = run(capsys, "simulate", "glmb-paper", "--out", str(tmp_path / "bad"), "--clutter", "-1")
    assert code == 2
    assert_one_line_error(err, "--clutter: Input should be greater than or equal to 0")
    assert not (tmp_path / "bad").exists()
