"""3D ray caster and n_p of planes against closed-form ranges and counts."""

from __future__ import annotations

import numpy as np

from detectors.raytrace3d import BeamGrid, Scene, cast, range_image, visible_planes


def scene(wall_y=10.0, cyl=None, sph=None):
    ground = [[-100, -100, 0], [100, -100, 0], [100, 100, 0], [-100, 100, 0]]
    wall = [[-20, wall_y, 0], [20, wall_y, 0], [20, wall_y, 6], [-20, wall_y, 6]]
    cyl = cyl or ([], [], [])
    sph = sph or ([], [])
    return Scene(
        np.array([ground, wall], float), np.array([4, 4]),
        np.array(cyl[0], float).reshape(-1, 2), np.array(cyl[1], float), np.array(cyl[2], float).reshape(-1, 2),
        np.array(sph[0], float).reshape(-1, 3), np.array(sph[1], float),
    )


GRID = BeamGrid(np.radians(np.linspace(5.0, -20.0, 16)), np.radians(1.0))


def test_ranges_match_closed_form():
    h, yaw = 1.5, 0.3
    r, ids = cast(scene(), GRID, np.array([0.0, 0.0, yaw]), h, 100.0)
    el = GRID.elevations[:, None]
    az = GRID.azimuths[None, :] + yaw
    u = np.stack(np.broadcast_arrays(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)), -1)
    # ground: t = h / -u_z; wall y = 10: t = 10 / u_y, hit when 0 <= z <= 6 and |x| <= 20
    t_g = np.where(u[..., 2] < 0, h / np.maximum(-u[..., 2], 1e-12), np.inf)
    t_w = np.where(u[..., 1] > 0, 10.0 / np.maximum(u[..., 1], 1e-12), np.inf)
    tw0, tg0 = np.where(np.isfinite(t_w), t_w, 0.0), np.where(np.isfinite(t_g), t_g, 0.0)
    zw, xw = h + tw0 * u[..., 2], tw0 * u[..., 0]
    t_w = np.where((zw >= 0) & (zw <= 6) & (np.abs(xw) <= 20), t_w, np.inf)
    gx, gy = tg0 * u[..., 0], tg0 * u[..., 1]
    t_g = np.where((np.abs(gx) <= 100) & (np.abs(gy) <= 100), t_g, np.inf)
    expect = np.minimum(t_g, t_w)
    expect[expect > 100.0] = np.inf
    fin = np.isfinite(expect)
    assert np.array_equal(np.isfinite(r), fin)
    assert np.allclose(r[fin], expect[fin], rtol=1e-9)
    assert set(np.unique(ids[fin])) <= {0, 1}
    assert np.array_equal(ids[fin] == 1, (t_w <= t_g)[fin])


def test_cylinder_and_sphere_occlude():
    sc = scene(cyl=([[5.0, 0.0]], [0.5], [[0.0, 4.0]]), sph=([[0.0, 5.0, 1.0]], [1.0]))
    r, ids = cast(sc, GRID, np.zeros(3), 1.5, 100.0)
    k = np.argmin(np.abs(GRID.azimuths))  # straight ahead: the cylinder at 5 m, front surface at 4.5 m
    ring = np.argmin(np.abs(GRID.elevations))
    assert ids[ring, k] == 2 and np.isclose(r[ring, k], 4.5, atol=1e-9)
    k90 = np.argmin(np.abs(GRID.azimuths - np.pi / 2))  # left: the sphere (centre 5 m, radius 1) in front of the wall
    el = GRID.elevations
    ring2 = np.argmin(np.abs(el - np.arctan2(-0.5, 5.0)))
    assert ids[ring2, k90] == 3 and r[ring2, k90] < 5.0


def test_visible_planes_counts_and_occlusion():
    sc = scene()
    pose = np.array([0.0, 0.0, 0.0])
    r, ids = cast(sc, GRID, pose, 1.5, 100.0)
    clean = np.where(np.isfinite(r), r, np.nan)
    n_p, n_exp, cen = visible_planes(sc, GRID, pose, 1.5, clean, range_sigma=0.02, range_max=100.0)
    assert n_exp[1] == n_p[1] == int((ids == 1).sum())  # nothing in front of the wall
    assert np.isclose(cen[1, 1], 10.0 - 0.0, atol=1e-9)  # the unoccluded hits lie on the wall (y = 10 in the sensor frame)
    # an occluder returns shorter ranges on a third of the wall's beams
    occ = clean.copy()
    wall = np.argwhere(ids == 1)
    cut = wall[: len(wall) // 3]
    occ[cut[:, 0], cut[:, 1]] = 2.0
    n_p2, n_exp2, _ = visible_planes(sc, GRID, pose, 1.5, occ, range_sigma=0.02, range_max=100.0)
    assert n_exp2[1] == n_exp[1] and n_p2[1] == n_p[1] - len(cut)
    # a missing return is no occlusion
    gone = clean.copy()
    gone[cut[:, 0], cut[:, 1]] = np.nan
    assert visible_planes(sc, GRID, pose, 1.5, gone, range_sigma=0.02, range_max=100.0)[0][1] == n_p[1]


def test_range_image_puts_points_back_on_their_beams():
    r, _ = cast(scene(), GRID, np.array([1.0, -2.0, 0.7]), 1.5, 100.0)
    fin = np.isfinite(r)
    pts = r[fin][:, None] * GRID.directions()[fin]
    img = range_image(pts, GRID)
    assert np.array_equal(np.isfinite(img), fin)
    assert np.allclose(img[fin], r[fin])
