"""Plane geometry: chart round trips, frame changes against first principles, Jacobians against finite differences."""

from __future__ import annotations

import numpy as np

from detectors.geometry3d import (
    beta_from_hesse,
    chart_from_normal,
    hesse_from_beta,
    min_area_rectangle,
    normal_from_chart,
    pose_matrix,
    pose_matrix_inverse,
    sensor_to_world,
    transform_beta,
    world_to_sensor,
)


def fd(f, x, eps=1e-6):
    """Central differences of f (..., m) with respect to x (..., n): (..., m, n)."""
    cols = []
    for i in range(x.shape[-1]):
        e = np.zeros_like(x)
        e[..., i] = eps
        cols.append((f(x + e) - f(x - e)) / (2 * eps))
    return np.stack(cols, axis=-1)


def random_planes(rng, n):
    x = np.column_stack([rng.uniform(-np.pi, np.pi, n), rng.uniform(-0.6, 0.6, n), rng.uniform(2.0, 30.0, n)])
    return x


def test_chart_round_trip_and_beta():
    rng = np.random.default_rng(0)
    x = random_planes(rng, 50)
    n, d = normal_from_chart(x)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    assert np.allclose(chart_from_normal(n, d), x)
    n2, d2 = hesse_from_beta(3.0 * beta_from_hesse(n, d))  # beta is defined up to scale
    assert np.allclose(n2, n) and np.allclose(d2, d)


def test_pose_matrix_inverse_is_exact():
    rng = np.random.default_rng(1)
    p = np.column_stack([rng.normal(0, 50, 20), rng.normal(0, 50, 20), rng.uniform(-np.pi, np.pi, 20)])
    eye = pose_matrix_inverse(p, 1.7) @ pose_matrix(p, 1.7)
    assert np.allclose(eye, np.eye(4), atol=1e-12)


def test_world_to_sensor_matches_points_on_the_plane():
    """A point on a world plane, moved into the sensor frame, lies on the predicted sensor-frame plane (eq. 28, 35)."""
    rng = np.random.default_rng(2)
    x = random_planes(rng, 30)
    sensor = np.column_stack([rng.normal(0, 5, 30), rng.normal(0, 5, 30), rng.uniform(-np.pi, np.pi, 30)])
    h = 1.73
    n, d = normal_from_chart(x)
    # points on each world plane
    u = np.cross(n, [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u, axis=1)[:, None]
    pw = n * d[:, None] + 3.0 * u
    ps = np.einsum("kij,kj->ki", pose_matrix_inverse(sensor, h), np.c_[pw, np.ones(30)])[:, :3]
    z, _ = world_to_sensor(x, sensor, h)
    ns, ds = normal_from_chart(z)
    assert np.allclose((ns * ps).sum(1), ds, atol=1e-9)
    # the same through beta^T R (eq. 35 with R_k = I)
    b = transform_beta(beta_from_hesse(n, d), pose_matrix(sensor, h))
    n3, d3 = hesse_from_beta(b)
    assert np.allclose(n3, ns) and np.allclose(d3, ds)


def test_jacobians_against_finite_differences():
    rng = np.random.default_rng(3)
    x = random_planes(rng, 10)
    sensor = np.column_stack([rng.normal(0, 5, 10), rng.normal(0, 5, 10), rng.uniform(-3, 3, 10)])
    _, h = world_to_sensor(x, sensor, 1.5)
    assert np.allclose(h, fd(lambda xx: world_to_sensor(xx, sensor, 1.5)[0], x), atol=1e-6)
    z, _ = world_to_sensor(x, sensor, 1.5)
    back, g = sensor_to_world(z, sensor, 1.5)
    assert np.allclose(back, x, atol=1e-9)
    assert np.allclose(g, fd(lambda zz: sensor_to_world(zz, sensor, 1.5)[0], z), atol=1e-6)
    assert np.allclose(g @ h, np.eye(3), atol=1e-9)  # inverse functions: inverse Jacobians


def test_min_area_rectangle_of_a_rotated_rectangle():
    a = 0.4
    c, s = np.cos(a), np.sin(a)
    r = np.array([[0, 0], [4, 0], [4, 2], [0, 2]], dtype=float) @ np.array([[c, s], [-s, c]])
    rect = min_area_rectangle(r)
    sides = np.linalg.norm(np.roll(rect, -1, 0) - rect, axis=1)
    assert np.allclose(sorted(sides), [2, 2, 4, 4], atol=1e-9)
