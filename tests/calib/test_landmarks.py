import numpy as np
from scipy.spatial import cKDTree

from calib.calibrate import scan_sensor_poses
from calib.landmarks import landmarks_from_cloud
from calib.sim.park import simulate_park
from profiles.schema import CircleDetectorParams
from tests.conftest import small_park_config


def test_recurring_circles_are_the_trees():
    cfg = small_park_config(laps=2.0)
    cfg.bushes.count = 30
    cfg.bushes.min_radius, cfg.bushes.max_radius = 0.3, 1.0
    sim = simulate_park(cfg, 61)
    sp, _ = scan_sensor_poses(sim.log, "reference")
    ids, xy, r = landmarks_from_cloud(sim.log, sp, CircleDetectorParams())
    d, j = cKDTree(sim.world.tree_xy).query(xy)
    tree = d < 0.2
    assert ids.size >= 10
    assert tree.mean() >= 0.8  # most recurring, viewpoint-consistent circles are trunks
    # with true poses the centre is the median of many fits: well under the 2 cm of one fit
    assert np.median(d[tree]) <= 0.02
    assert np.median(np.abs(r[tree] - sim.world.tree_r[j[tree]])) <= 0.02
