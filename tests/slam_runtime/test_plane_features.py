"""The plane feature model: closed-form cases, finite differences, innovation, the map metric, RB-PHD on planes."""

from __future__ import annotations

import numpy as np

from detectors.geometry3d import chart_from_normal
from detectors.plane_model import PlaneDetectionModel
from profiles.schema import ClutterParams
from slam_runtime.mapfilter import Measurements
from slam_runtime.plane_features import PlaneFeature, embed, plane_distance
from slam_runtime.rbphd import RBPHD, RBPHDConfig
from tests.detectors.test_geometry3d import fd


def feature(mount=(0.0, 0.0, 0.0), height=1.7):
    return PlaneFeature(np.diag([0.002**2, 0.002**2, 0.02**2]), np.array(mount), height=height)


def test_closed_form_cases():
    fm = feature()
    wall = np.array([0.0, 0.0, 10.0])  # the plane x = 10
    z, _ = fm.predict(np.zeros(3), wall)
    assert np.allclose(z, [0.0, 0.0, 10.0])
    z, _ = fm.predict(np.array([3.0, 1.0, np.pi / 2]), wall)  # 3 m closer, turned left: the wall is to the right
    assert np.allclose(z, [-np.pi / 2, 0.0, 7.0])
    tilted = np.array([0.0, 0.2, 10.0])  # a tilted plane: the sensor's height moves it
    z, _ = fm.predict(np.zeros(3), tilted)
    assert np.isclose(z[2], 10.0 - np.sin(0.2) * 1.7)
    z, _ = feature(mount=(1.0, 0.0, 0.0)).predict(np.zeros(3), wall)  # a sensor 1 m ahead of the vehicle origin
    assert np.isclose(z[2], 9.0)


def test_jacobians_and_inverse():
    rng = np.random.default_rng(0)
    fm = feature(mount=(0.8, 0.1, 0.05))
    x = np.column_stack([rng.uniform(-3, 3, 8), rng.uniform(-0.5, 0.5, 8), rng.uniform(3, 30, 8)])
    poses = np.column_stack([rng.normal(0, 3, 8), rng.normal(0, 3, 8), rng.uniform(-3, 3, 8)])
    z, h = fm.predict(poses, x)
    assert np.allclose(h, fd(lambda xx: fm.predict(poses, xx)[0], x), atol=1e-6)
    back, g = fm.inverse(poses, z)
    assert np.allclose(back, x)
    assert np.allclose(g, fd(lambda zz: fm.inverse(poses, zz)[0], z), atol=1e-6)


def test_innovation_wraps_the_azimuth():
    fm = feature()
    nu = fm.innovation(np.array([[np.pi - 0.01, 0.1, 5.0]]), np.array([[-np.pi + 0.01, 0.05, 4.5]]))
    assert np.allclose(nu, [[-0.02, 0.05, 0.5]])


def test_metric_identifies_a_plane_and_its_flip():
    n = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    a = embed(n, np.array([5.0, 0.02]), 10.0)
    b = embed(-n, np.array([-5.0, -0.02]), 10.0)
    assert np.allclose(np.diag(plane_distance(a, b)), 0.0)
    c = embed(np.array([[np.sin(0.01), np.cos(0.01), 0.0]]), np.array([5.1]), 10.0)
    assert np.isclose(plane_distance(a[:1], c)[0, 0], np.hypot(10 * 2 * np.sin(0.005), 0.1))


def test_rbphd_maps_planes_from_a_still_vehicle():
    """RB-PHD on the plane feature (d = 3): three walls seen for 12 frames with P_D 0.9 and a little clutter give
    three map planes of weight about 1 within 2 cm and 0.1 deg of the truth (the noise is 2 cm, 0.1 deg)."""
    rng = np.random.default_rng(1)
    fm = PlaneFeature(np.diag([0.002**2, 0.002**2, 0.02**2]), np.zeros(3), height=1.7)
    det = PlaneDetectionModel(
        None, ClutterParams(rate=0.5, space="plane", volume=PlaneDetectionModel.chart_volume(np.radians(45), 60.0)), 1.7, 0.02,
        np.radians(45), 60.0, constant_pd=0.9,
    )
    truth = chart_from_normal(np.array([[0, 1.0, 0], [0, -1.0, 0], [1.0, 0, 0]]), np.array([8.0, 9.0, 30.0]))
    mf = RBPHD(fm, det, RBPHDConfig())
    maps = mf.empty(5)
    poses = np.zeros((5, 3))
    for _ in range(12):
        z, _ = fm.predict(np.zeros(3), truth)
        z = z + rng.normal(0, [0.002, 0.002, 0.02], z.shape)
        z = z[rng.random(3) < 0.9]
        maps, _ = mf.update(maps, poses, Measurements(z))
    x, w = mf.estimate(maps, 0)
    assert len(x) == 3 and np.all(np.abs(w - 1) < 0.15)
    order = np.argsort(x[:, 2])
    assert np.allclose(x[order], truth[np.argsort(truth[:, 2])], atol=[0.002, 0.002, 0.02])
