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


def test_bounded_planes_see_through_a_plane_that_is_not_there(small_street, street_profile, monkeypatch):
    """With extents, a map plane is bounded by its detections' outlines and its n_p ray-traced by the calibration's
    own code: on a seeded street, frame 20's facade detected in frame 19 gets an n_p within 35 % of the ray-traced
    n_p of the true facade (the outline covers the part seen, not the whole polygon: the 35 % is a facade's
    unseen ends and the two frames' 0.7 m apart), and a plane 0.15 m in front of it -- a duplicate track, nothing
    there -- gets nearly as many (the beams pass through it to the facade: >= 80 % of the facade's), so its P_D is
    high and its misses count; the infinite plane's slab (3 sigma = 6 cm) holds none of the facade's returns, only
    those of other surfaces it cuts, and gives it a P_D at least 0.2 lower. Both paths call
    ``detectors.raytrace3d.visible_planes``, the calibration's function."""
    import calib.planes as cp
    import detectors.plane_model as pm
    from calib.planes import sensor_poses_at
    from detectors.geometry3d import orient_away
    from detectors.plane import CloudPlanes
    from detectors.raytrace3d import BeamGrid, polygon_scene, range_image, visible_planes

    calls = []

    def spy(*a, **k):
        calls.append(1)
        return visible_planes(*a, **k)

    monkeypatch.setattr(pm, "visible_planes", spy)
    assert cp.visible_planes is visible_planes  # the calibration's n_p: the function the runtime spies on here
    log = small_street.log
    m = PlaneDetectionModel.from_profile(street_profile, extents=True)
    slab = PlaneDetectionModel.from_profile(street_profile, extents=False)
    src = CloudPlanes(log, street_profile, m)
    from types import SimpleNamespace

    sps = sensor_poses_at(log, log.clouds.stamp[[19, 20]])
    meas19, meas20 = src(SimpleNamespace(rows=19)), src(SimpleNamespace(rows=20))
    height = log.sensor.lidar.height
    # the true landmark plane with the most unoccluded returns in frame 20
    grid = BeamGrid.of(log.sensor.lidar)
    steep = np.flatnonzero(np.abs(log.planes.normal[:, 2]) < 0.5)
    n_true, _, _ = visible_planes(polygon_scene(log.planes.take(steep)), grid, sps[1], height, range_image(log.clouds.frame(20), grid),
                                  range_sigma=0.02, range_max=120.0)
    best = steep[int(np.argmax(n_true))]
    n_w, d_w = orient_away(log.planes.normal[best][None], np.array([log.planes.offset[best] - log.planes.normal[best] @ np.array([*sps[1][:2], height])]))
    d_w = d_w + n_w[:, :] @ np.array([*sps[1][:2], height])  # back to the world offset, normal away from the sensor
    mu = chart_from_normal(np.vstack([n_w, n_w]), np.array([d_w[0], d_w[0] - 0.15]))[None]  # the facade, and 0.15 m in front
    cov = np.zeros((1, 2, 3, 3))
    m.pd_features(sps[0][None], mu, cov, meas19)  # frame 19 files its outlines
    pd, _ = m.pd_features(sps[1][None], mu, cov, meas20)
    n_b, _, bounded = m.bounded_points(sps[1], mu, log.clouds.frame(20))
    assert bounded.all() and calls
    assert abs(n_b[0, 0] - n_true.max()) <= 0.35 * n_true.max()
    assert n_b[0, 1] >= 0.8 * n_b[0, 0] and pd[0, 1] >= 0.85
    pd_slab, _ = slab.pd_features(sps[1][None], mu, cov, meas20)
    assert pd_slab[0, 0] >= 0.85 and pd_slab[0, 1] <= pd[0, 1] - 0.2
