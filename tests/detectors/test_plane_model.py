"""The runtime detection model of planes: visible points from the cloud, P_D, buffer, clutter."""

from __future__ import annotations

import numpy as np
import pytest

from detectors.geometry3d import chart_from_normal
from detectors.plane_model import PlaneDetectionModel
from profiles.errors import DataError
from profiles.schema import ClutterParams, PdTable
from slam_runtime.mapfilter import Measurements

TABLE = PdTable(covariate="points", edges=[0, 50, 200, 1000, 2000], pd=[0.0, 0.3, 0.8, 0.95])


def model(**kw):
    clutter = ClutterParams(rate=2.0, space="plane", volume=PlaneDetectionModel.chart_volume(np.radians(45), 80.0))
    return PlaneDetectionModel(TABLE, clutter, 1.7, 0.02, np.radians(45), 80.0, **kw)


def cloud(rng):
    """A wall y = 8 (2000 returns) and the ground z = -1.7 (5000 returns), sensor frame."""
    wall = np.column_stack([rng.uniform(-5, 5, 2000), 8.0 + rng.normal(0, 0.02, 2000), rng.uniform(-1.7, 2.0, 2000)])
    ground = np.column_stack([rng.uniform(-20, 20, 5000), rng.uniform(-6, 6, 5000), -1.7 + rng.normal(0, 0.02, 5000)])
    return np.vstack([wall, ground])


def test_visible_points_count_the_slab():
    """Seen from the origin (sensor at 1.7 m), the wall's slab holds its 2000 returns (the ground ends at y = 6, short
    of it); the plane x = 30 has nothing on it (the ground ends at x = 20); one beyond the range limit is out of view."""
    rng = np.random.default_rng(0)
    m = model()
    mu = chart_from_normal(np.array([[0, 1.0, 0], [1.0, 0, 0], [0, 1.0, 0]]), np.array([8.0, 30.0, 90.0]))[None]
    n, ang = m.visible_points(np.zeros((1, 3)), mu, np.zeros((1, 3, 3, 3)), cloud(rng))
    assert n[0, 0] == pytest.approx(2000, rel=0.01)
    assert n[0, 1] == 0 and n[0, 2] == 0
    assert np.degrees(ang[0, 0]) < 10  # the wall's returns lie around its foot point
    pd, buf = m.pd_features(np.zeros((1, 3)), mu, np.zeros((1, 3, 3, 3)), Measurements(np.zeros((0, 3)), cloud=cloud(rng)))
    assert np.allclose(pd, [[0.95, 0.0, 0.0]]) and not buf.any()


def test_uncertain_planes_take_a_wider_slab():
    rng = np.random.default_rng(1)
    m = model()
    mu = chart_from_normal(np.array([[0, 1.0, 0]]), np.array([8.3]))[None]  # 30 cm off the wall
    tight = m.visible_points(np.zeros((1, 3)), mu, np.zeros((1, 1, 3, 3)), cloud(rng))[0][0, 0]
    loose = m.visible_points(np.zeros((1, 3)), mu, np.diag([1e-6, 1e-6, 0.15**2])[None, None], cloud(rng))[0][0, 0]
    assert tight < 50 and loose == pytest.approx(2000, rel=0.02)


def test_constant_mode_buffer_and_clutter():
    m = model(constant_pd=0.9)
    mu = chart_from_normal(np.array([[0, 1.0, 0], [0, 0, 1.0], [0, 1.0, 0]]), np.array([8.0, 5.0, 79.99]))[None]
    pd, buf = m.pd_features(np.zeros((1, 3)), mu, np.zeros((1, 3, 3, 3)), Measurements(np.zeros((0, 3))))
    assert np.allclose(pd, [[0.9, 0.0, 0.9]])  # a horizontal plane is no landmark
    assert buf.tolist() == [[False, False, True]]  # at the range limit: the buffer zone
    z = np.array([[0.1, 0.2, 10.0], [0.1, 1.2, 10.0], [0.1, 0.2, 100.0]])
    assert np.allclose(m.clutter_intensity(z), [2.0 / m.clutter.volume, 0.0, 0.0])
    with pytest.raises(DataError, match="P_D of planes needs the frame's point cloud"):
        model().pd_features(np.zeros((1, 3)), mu, np.zeros((1, 3, 3, 3)), Measurements(np.zeros((0, 3))))


def test_particles_share_one_pd_of_a_plane():
    """Particles a degree apart see the same plane with one P_D (from their mean pose); with their own poses the one
    turned off the wall finds fewer returns in its slab and so expects the wall less."""
    rng = np.random.default_rng(2)
    pts = cloud(rng)
    mu = np.repeat(chart_from_normal(np.array([[0, 1.0, 0]]), np.array([8.0]))[None], 2, axis=0)
    poses = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, np.radians(1.0)]])
    meas = Measurements(np.zeros((0, 3)), cloud=pts)
    cov = np.zeros((2, 1, 3, 3))
    own = model(common_pose=False).visible_points(poses, mu, cov, pts)[0]
    assert own[1, 0] < 0.8 * own[0, 0]  # 1 deg tilts the slab 9 cm off the wall 5 m along it
    pd, _ = model().pd_features(poses, mu, cov, meas)
    assert pd[0, 0] == pd[1, 0] > 0.5
