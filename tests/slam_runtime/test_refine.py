"""map_refine: the map re-estimated along a trajectory with the associations not given (slam_runtime.refine),
against a labelled least-squares reference without clutter, against the truth under heavy clutter, and in a run."""

import numpy as np
import pytest
from pydantic import ValidationError

from calib.sim.glmb_paper import GlmbPaperConfig, simulate_glmb_paper, truth_profile
from slam_runtime.config import SlamConfig, override
from slam_runtime.refine import refine_map
from slam_runtime.run import build, evaluate, run_slam
from slam_runtime.sources import frames


def _along_truth(clutter: float, seed: int, profile_clutter: float | None = None):
    """A glmb-paper log, the run's models for its truth profile, the true poses at its frames and each frame's
    measurements."""
    cfg = GlmbPaperConfig(clutter=clutter)
    log = simulate_glmb_paper(cfg, seed)
    prof = truth_profile(GlmbPaperConfig(clutter=clutter if profile_clutter is None else profile_clutter))
    b = build(log, prof, SlamConfig())
    stamps = np.array([fr.stamp for fr in log.frames()], dtype=np.int64)
    meas = [fi.meas for fi in frames(log, b.measure, stamps.size)]
    truth = log.reference["ground_truth"]
    poses = truth.poses[np.searchsorted(truth.stamp, stamps)]
    assert np.array_equal(truth.stamp[np.searchsorted(truth.stamp, stamps)], stamps)
    return cfg, log, b, poses, meas


def _labelled_least_squares(log, poses, x0, sr, sb, rmax):
    """The reference: each landmark by Gauss-Newton on its own (labelled) detections at the frames where it is in
    view from its start position x0 (range <= rmax), unit weights."""
    det = log.detections
    lab = np.asarray(det.descriptors["landmark"])
    out = x0.copy()
    for j in range(x0.shape[0]):
        k = np.flatnonzero(lab == j + 1)
        p = poses[det.frame[k]]
        k = k[np.hypot(*(x0[j] - p[:, :2]).T) <= rmax]
        p = poses[det.frame[k]]
        x = x0[j].copy()
        for _ in range(50):
            d = x - p[:, :2]
            r = np.hypot(d[:, 0], d[:, 1])
            b = np.arctan2(d[:, 1], d[:, 0]) - p[:, 2]
            e = np.column_stack([(det.range[k] - r) / sr, np.angle(np.exp(1j * (det.bearing[k] - b))) / sb])
            jac = np.stack([np.column_stack([d[:, 0] / r, d[:, 1] / r]) / sr, np.column_stack([-d[:, 1], d[:, 0]]) / r[:, None] ** 2 / sb], axis=1)
            a = np.einsum("mki,mkj->ij", jac, jac)
            step = np.linalg.solve(a, np.einsum("mki,mk->i", jac, e))
            x += step
            if np.abs(step).max() < 1e-12:
                break
        out[j] = x
    return out


def test_without_clutter_it_is_each_landmarks_least_squares():
    """No false alarms and a vanishing clutter intensity: every gated measurement is its landmark's for certain, so
    along the true path the refined map is each landmark's least-squares fit to its own detections (1e-5 m: the
    responsibilities are 1 - O(1e-7)). The gate is 5 sigma: with nothing to explain it otherwise, a detection
    5.3-5.7 sigma from a landmark that missed that scan would count for it too (each feature's term is its own)."""
    cfg, log, b, poses, meas = _along_truth(0.0, 3, profile_clutter=1e-6)
    rng = np.random.default_rng(0)
    x0 = log.landmarks.xy + rng.normal(0.0, 0.05, log.landmarks.xy.shape)
    got, it = refine_map(b.mapfilter, poses, meas, x0, gate=25.0)
    ref = _labelled_least_squares(log, poses, x0, cfg.sigma_range, cfg.sigma_bearing, cfg.range_max)
    assert 1 < it < 100
    np.testing.assert_allclose(got, ref, atol=1e-5)


def test_under_heavy_clutter_it_recovers_the_map_the_labels_would_give():
    """15 false alarms per scan, the true path, the map started 0.15 m (sd per axis) off the truth: the refined map,
    with the associations not given, is within 2.5 cm RMS of the labelled least-squares map (the false alarms
    take some weight from the detections and lend a little to themselves: 22 % of the information, by the clutter
    oracle) and its error from the truth within 25 % of that map's, where the start's is about four times it."""
    cfg, log, b, poses, meas = _along_truth(15.0, 4)
    truth = log.landmarks.xy
    x0 = truth + np.random.default_rng(1).normal(0.0, 0.15, truth.shape)
    got, _ = refine_map(b.mapfilter, poses, meas, x0)
    ref = _labelled_least_squares(log, poses, truth, cfg.sigma_range, cfg.sigma_bearing, cfg.range_max)
    rms = lambda a, c: float(np.sqrt(np.mean(np.sum((a - c) ** 2, axis=1))))  # noqa: E731
    assert rms(got, ref) < 0.025
    assert rms(got, truth) < 1.25 * rms(ref, truth)
    assert rms(x0, truth) > 3.0 * rms(got, truth)


def test_a_run_keeps_the_filters_map_beside_the_refined_one():
    """map_refine changes nothing in the filter (its map, trajectory and weights are the same bytes as without it);
    the refined map is the result's map, the filter's is kept, both scored; same seed, same bytes."""
    cfg = GlmbPaperConfig(clutter=5.0)
    log, prof = simulate_glmb_paper(cfg, 2), truth_profile(cfg)
    base = SlamConfig(particles=10, proposal="optimal", filter={"kind": "glmb"}, metric={"ospa_c": 0.5, "ospa_p": 1.0})
    plain = run_slam(log, prof, base, seed=3, max_frames=80)
    refined = run_slam(log, prof, override(base, map_refine=True), seed=3, max_frames=80)
    again = run_slam(log, prof, override(base, map_refine=True), seed=3, max_frames=80)
    assert plain.map_filter_xy is None and refined.map_filter_xy is not None
    assert np.array_equal(refined.map_filter_xy, plain.map_xy) and np.array_equal(refined.trajectory, plain.trajectory)
    assert np.array_equal(refined.map_w, plain.map_w)
    assert refined.map_xy.shape == plain.map_xy.shape and not np.array_equal(refined.map_xy, plain.map_xy)
    assert np.array_equal(again.map_xy, refined.map_xy)
    m = evaluate(log, refined, 0.5, 1.0)
    assert m["map_ospa_filter"] == pytest.approx(evaluate(log, plain, 0.5, 1.0)["map_ospa"])
    assert m["map_refine_iterations"] == refined.refine_iterations > 0
    assert "map_ospa_filter" not in evaluate(log, plain, 0.5, 1.0)


def test_planes_are_refused_naming_the_setting():
    with pytest.raises(ValidationError, match="map_refine re-estimates point features; it does not apply to planes"):
        SlamConfig(features="planes", map_refine=True)
