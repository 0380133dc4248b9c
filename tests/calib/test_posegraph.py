import numpy as np
import pytest

from calib.posegraph import Edges, GraphConfig, sequential_sigma, solve
from detectors.geometry import compose, relative
from profiles.errors import DataError


def _square_loop(seed=0, drift=0.0015):
    """Truth: 40 poses round a 10 m square; odometry edges with a heading drift; loop edges from the truth."""
    rng = np.random.default_rng(seed)
    legs = []
    for k in range(4):
        th = k * np.pi / 2
        for s in np.arange(0, 10, 1.0):
            legs.append([s * np.cos(th), s * np.sin(th), th])
    corners = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float)
    truth = np.array(legs)
    truth[:, :2] += np.repeat(corners, 10, axis=0)
    truth[:, :2] -= truth[0, :2]
    z = relative(truth[:-1], truth[1:])
    z_noisy = z + np.column_stack([rng.normal(0, 0.003, len(z)), rng.normal(0, 0.003, len(z)), np.full(len(z), drift)])
    x0 = np.zeros_like(truth)
    x0[0] = truth[0]
    for k in range(1, len(truth)):
        x0[k] = compose(x0[k - 1], z_noisy[k - 1])
    return truth, z_noisy, x0


def _graph(truth, z_noisy, cfg, false_loops=()):
    e = Edges.empty().plus(np.arange(len(truth) - 1), np.arange(1, len(truth)), z_noisy, sequential_sigma(z_noisy, cfg), loop=False)
    i = np.array([0, 1, 2, 5, 10, 20])
    j = np.array([39, 38, 37, 35, 30, 25])
    loops = relative(truth[i], truth[j])
    lsig = [[cfg.loop_sigma_xy, cfg.loop_sigma_xy, cfg.loop_sigma_theta]]
    e = e.plus(i, j, loops, lsig, loop=True)
    for a, b, off in false_loops:
        e = e.plus([a], [b], [compose(relative(truth[a], truth[b]), np.asarray(off, float))], lsig, loop=True)
    return e


@pytest.mark.parametrize("solver,robust", [("gtsam", "gnc"), ("gtsam", "cauchy"), ("scipy", "cauchy"), ("gtsam", "none")])
def test_loops_remove_the_drift(solver, robust):
    truth, z, x0 = _square_loop()
    cfg = GraphConfig(solver=solver, robust=robust)
    sol = solve(x0, _graph(truth, z, cfg), cfg)
    err = np.hypot(*(sol.poses[:, :2] - truth[:, :2]).T)
    odo = np.hypot(*(x0[:, :2] - truth[:, :2]).T)
    # 1.5 mrad of heading drift a step (the front end's order) gives decimetres by the end; six true loops take
    # most of it away; what stays (under 0.12 m) is the systematic drift spread over the chain by least squares
    assert odo.max() > 0.3
    assert err.max() < min(0.12, odo.max() / 3)
    assert (sol.weight == 1.0).all()


def test_one_false_loop_is_turned_off_and_does_not_fold_the_map():
    truth, z, x0 = _square_loop(seed=1)
    false = [(15, 32, (2.0, -1.0, 0.3))]  # the far side of the square, 2 m and 17 degrees wrong
    robust = GraphConfig(robust="gnc")
    sol = solve(x0, _graph(truth, z, robust, false), robust)
    assert sol.weight[-1] < 0.5 and (sol.weight[:-1] == 1).all()
    clean = solve(x0, _graph(truth, z, robust), robust)  # the same graph without the false loop
    np.testing.assert_allclose(sol.poses, clean.poses, atol=1e-3)  # turned off: as if it were not there
    plain = GraphConfig(robust="none")
    folded = solve(x0, _graph(truth, z, plain, false), plain)
    assert np.hypot(*(folded.poses[:, :2] - truth[:, :2]).T).max() > 0.2  # without the robust cost it bends the map


def test_gnc_needs_gtsam_and_edges_need_nodes():
    truth, z, x0 = _square_loop()
    cfg = GraphConfig(solver="scipy", robust="gnc")
    with pytest.raises(DataError, match="gnc"):
        solve(x0, _graph(truth, z, cfg), cfg)
    bad = Edges.empty().plus([0], [99], [[1.0, 0.0, 0.0]], [[0.1, 0.1, 0.1]], loop=False)
    with pytest.raises(DataError, match="node"):
        solve(x0, bad, GraphConfig())
