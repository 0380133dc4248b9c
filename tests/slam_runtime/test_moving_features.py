"""The labelled filters with moving point features (``filter.feature_motion: constant_velocity``): their prediction
against a finite-difference linearisation of the transition, and a moving point tracked from seeded measurements."""

import numpy as np
import pytest

from detectors.model import DetectionModel
from profiles.errors import UsageError
from profiles.schema import ClutterParams, PdTable, SensorModel
from slam_runtime.cv_transition import MovingPoint, process_noise, transition
from slam_runtime.features import RangeBearing
from slam_runtime.glmb import GLMB, GLMBConfig
from slam_runtime.lmb import LMB, LMBConfig
from slam_runtime.mapfilter import Measurements

SENSOR = SensorModel(kind="camera", fov=2 * np.pi, range_max=30.0)
FILTERS = [(GLMB, GLMBConfig), (LMB, LMBConfig)]
R = np.diag([0.1**2, 0.01**2])


def _model(rate=1.0, pd=0.9):
    pdt = PdTable(covariate="range", edges=[0.0, SENSOR.range_max], pd=[pd])
    return DetectionModel(pdt, ClutterParams(rate=rate, volume=SENSOR.field_of_view * SENSOR.range_max), SENSOR, buffer=False)


def _filter(cls, cfg_cls, seed=0, **cfg):
    return cls(RangeBearing(R), _model(), cfg_cls(feature_motion="constant_velocity", **cfg), rng=np.random.default_rng(seed))


def _fd_jacobian(x: np.ndarray, dt: float, eps: float = 1e-6) -> np.ndarray:
    """d f(x, 0) / d x by central differences of the transition."""
    cols = [(transition(x + e, np.zeros(2), dt) - transition(x - e, np.zeros(2), dt)) / (2 * eps) for e in np.eye(4) * eps]
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("cls,cfg_cls", FILTERS)
def test_prediction_is_the_linearised_transition(cls, cfg_cls):
    """Two updates give tracks and births; one prediction of dt = 0.7 s must move every Gaussian the maps hold as the
    EKF prediction through the transition does: mu' = f(mu, 0), P' = J P J^T + sigma^2 B B^T with J from finite
    differences (the transition is linear, so they agree to rounding: 1e-8)."""
    mf = _filter(cls, cfg_cls, feature_acceleration=0.3)
    assert isinstance(mf.feature, MovingPoint) and mf.feature.dim_x == 4
    maps = mf.empty(2)
    for z in ([[5.0, 0.2], [9.0, -0.4]], [[5.05, 0.21], [9.1, -0.41], [14.0, 0.9]]):
        maps, _ = mf.update(maps, np.zeros((2, 3)), Measurements(np.array(z)))
    # the Gaussians held: tracks (delta-GLMB's free tracks too) and the births of the next step
    parts = [k for k in ("tracks", "free", "births") if getattr(maps, k, None) is not None and getattr(maps, k).mu.shape[1]]
    assert "births" in parts and len(parts) >= 2, parts
    for k in parts:
        getattr(maps, k).mu[..., 2:] = [0.4, -0.25]  # a velocity, so that the positions move
    before = {k: (getattr(maps, k).mu.copy(), getattr(maps, k).cov.copy()) for k in parts}
    dt = 0.7
    out = mf.predict(maps, dt)
    q = process_noise(dt, 0.3)
    for k, (mu, cov) in before.items():
        j = _fd_jacobian(mu.reshape(-1, 4)[0], dt)
        np.testing.assert_allclose(getattr(out, k).mu, np.einsum("ij,...j->...i", j, mu), atol=1e-8)
        np.testing.assert_allclose(getattr(out, k).cov, j @ cov @ j.T + q, atol=1e-8)
    assert mf.predict(maps, 0.0) is maps  # no time, no motion


@pytest.mark.parametrize("cls,cfg_cls", FILTERS)
def test_moving_points_are_tracked(cls, cfg_cls):
    """Three points moving at 0.1-0.2 m/s (with acceleration noise 0.02 m/s^2) seen from the origin (a sensor seeing all
    round to 30 m, so that they stay in view) for 60 steps of 1 s (P_D 0.9, one false alarm per scan, sigma 0.1 m /
    0.01 rad): the filter told that they move ends with the three points and no other feature, each point's position
    within 0.6 m and its velocity within 0.2 m/s.

    Tolerances: the steady-state Kalman filter of this constant-velocity model (acceleration noise 0.02 m/s^2, a
    position noise of up to 0.2 m across the line of sight at 20 m) has standard deviations of about 0.12 m in
    position and 0.04 m/s in velocity (the discrete Riccati equation); 0.6 m and 0.2 m/s are five of them. A filter
    that kept the points static would lag them by metres after 60 s."""
    rng = np.random.default_rng(7)
    x = np.array([[5.0, 2.0, 0.1, 0.05], [8.0, -3.0, -0.05, 0.15], [12.0, 1.0, 0.12, -0.08]])
    mf = _filter(cls, cfg_cls, seed=3, feature_acceleration=0.02)
    fm = RangeBearing(R)
    maps = mf.empty(2)
    for _ in range(60):
        maps = mf.predict(maps, 1.0)
        x = transition(x, rng.normal(0.0, 0.02, (3, 2)), 1.0)
        z, _ = fm.predict(np.zeros(3), x[:, :2])
        z = z[rng.uniform(size=3) < 0.9]
        z = z + rng.normal(0.0, 1.0, z.shape) * [0.1, 0.01]
        n = rng.poisson(1.0)
        clutter = np.column_stack([rng.uniform(0, 30, n), rng.uniform(-np.pi, np.pi, n)])
        maps, ll = mf.update(maps, np.zeros((2, 3)), Measurements(np.vstack([z, clutter])))
        assert np.isfinite(ll).all()
    est, _ = mf.estimate(maps, 0)
    assert est.shape == (3, 4), (est.round(2).tolist(), x.round(2).tolist())
    d = np.linalg.norm(est[:, None, :2] - x[None, :, :2], axis=2)
    match = d.argmin(axis=0)
    assert sorted(match) == [0, 1, 2]
    assert d.min(axis=0).max() < 0.6, d
    assert np.abs(est[match, 2:] - x[:, 2:]).max() < 0.2, (est, x)


def test_planes_cannot_move():
    from slam_runtime.plane_features import PlaneFeature

    with pytest.raises(UsageError, match="feature_motion: constant_velocity moves point features"):
        LMB(PlaneFeature(np.eye(3) * 1e-4), _model(), LMBConfig(feature_motion="constant_velocity"), rng=np.random.default_rng(0))
