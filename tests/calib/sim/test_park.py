import numpy as np
import pytest

from calib.config import load_yaml_model
from calib.io.native import read_native
from calib.sim.park import ParkConfig, World, cast_world, sensor_poses, simulate_park
from detcal.reports.simulation import load_world, write_simulation_run
from detectors.geometry import relative
from profiles.errors import UsageError
from tests.conftest import small_park_config


def test_same_seed_same_bytes_different_seed_different_world(tmp_path):
    cfg = small_park_config()
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        write_simulation_run("park", cfg, seed, tmp_path / name)
    for f in ("log.dlog", "world.yaml", "config.yaml", "summary.yaml", "overview.png"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
    assert (tmp_path / "a/world.yaml").read_bytes() != (tmp_path / "c/world.yaml").read_bytes()


def _recast(log, world):
    """Noise-free ranges of every scan from the exported world, true poses and sensor model."""
    gt = log.reference["ground_truth"]
    idx = np.searchsorted(gt.stamp, log.scans.stamp)
    assert np.array_equal(gt.stamp[idx], log.scans.stamp)
    poses = sensor_poses(gt.poses[idx], log.sensor.mount)
    return np.stack([cast_world(world, p, log.sensor)[0] for p in poses])


def test_scans_rederive_from_exported_world(tmp_path, small_sim):
    write_simulation_run("park", small_sim.config, small_sim.seed, tmp_path / "run", figure=False)  # (small_sim again)
    log = read_native(tmp_path / "run/log.dlog")
    world = load_world(tmp_path / "run/world.yaml")
    truth = _recast(log, world)
    r = log.scans.ranges.astype(np.float64)
    ret = np.isfinite(r)
    close = np.abs(r - truth) <= 3 * log.sensor.range_sigma
    share = close[ret].mean()
    assert share >= 0.95, share
    # the misfits are accounted for: dust (p_spurious of all beams, also the empty ones)
    # plus the 0.27 % Gaussian tail beyond 3 sigma; 0.3 % slack for sampling
    dust = small_sim.config.laser.p_spurious * r.size / ret.sum()
    assert 1 - share <= dust + 0.0027 + 0.003
    # missing returns: about p_miss of the beams that hit something
    hit = np.isfinite(truth)
    assert abs((~ret[hit]).mean() - small_sim.config.laser.p_miss) < 0.005


def test_trees_occlude_what_stands_behind_them():
    # a trunk straight ahead at 10 m hides a bigger one at 20 m and a post at 30 m
    world = World(
        tree_xy=np.array([[10.0, 0.0], [20.0, 0.0]]),
        tree_r=np.array([0.5, 0.3]),
        post_xy=np.array([[30.0, 0.0]]),
        post_r=np.array([0.05]),
        bush_vertices=np.zeros((0, 2)),
        bush_offsets=np.array([0]),
        wall_p0=np.array([[40.0, -5.0]]),
        wall_p1=np.array([[40.0, 5.0]]),
    )
    sensor = ParkConfig().laser
    from calib.sim.park import sensor_model

    sm = sensor_model(ParkConfig.model_validate({"laser": {"n_beams": 721, "fov_deg": 180.0}}))
    ranges, ids = cast_world(world, np.zeros(3), sm)
    assert 1 not in ids and 2 not in ids  # nothing behind the near trunk is seen
    ahead = np.abs(sm.angles()) < 1e-9
    assert ranges[ahead][0] == pytest.approx(9.5)
    # beams grazing past the near trunk's shadow reach the wall, never the hidden shapes
    wall = ids == 3
    assert wall.any() and np.all(np.abs(sm.angles()[wall]) > np.arcsin(0.5 / 10.0) - 1e-3)
    assert sensor.n_beams == 361


def test_vectorised_cast_matches_a_plain_per_beam_caster(small_sim):
    world, log = small_sim.world, small_sim.log
    centres, radii = world.circles()
    p0, p1 = world.segments()
    gt = log.reference["ground_truth"]
    for k in (0, len(log.scans) // 2):
        pose = sensor_poses(gt.poses[np.searchsorted(gt.stamp, log.scans.stamp[k])][None], log.sensor.mount)[0]
        fast, _ = cast_world(world, pose, log.sensor)
        for b, ang in enumerate(log.sensor.angles()):
            d = np.array([np.cos(pose[2] + ang), np.sin(pose[2] + ang)])
            best = np.inf
            for c, r in zip(centres, radii, strict=True):  # textbook quadratic per circle
                m = pose[:2] - c
                bq, cq = 2 * d @ m, m @ m - r * r
                disc = bq * bq - 4 * cq
                if disc >= 0:
                    t = (-bq - np.sqrt(disc)) / 2
                    if t > 0:
                        best = min(best, t)
            for a, e in zip(p0, p1, strict=True):  # solve o + t d = a + u (e - a)
                mat = np.column_stack([d, a - e])
                if abs(np.linalg.det(mat)) < 1e-12:
                    continue
                t, u = np.linalg.solve(mat, a - pose[:2])
                if t > 0 and 0 <= u <= 1:
                    best = min(best, t)
            best = best if best <= log.sensor.range_max else np.inf
            assert (np.isinf(best) and np.isinf(fast[b])) or abs(best - fast[b]) < 1e-9


def test_odometry_noise_matches_its_model(small_sim):
    log, cfg = small_sim.log, small_sim.config.odometry
    truth = relative(log.reference["ground_truth"].poses[:-1], log.reference["ground_truth"].poses[1:])
    err = log.odometry.values - truth
    d = np.hypot(truth[:, 0], truth[:, 1])
    z = err[:, 0] / (cfg.alpha_trans * d)
    assert abs(z.mean()) < 0.1 and abs(z.std() - 1) < 0.1  # n ~ 1500: standard errors 0.026, 0.018


def test_lawnmower_path_and_uniform_radii():
    cfg = small_park_config(kind="lawnmower", row_spacing=10.0)
    cfg.trees.radius.kind = "uniform"
    sim = simulate_park(cfg, 3)
    r = sim.world.tree_r
    assert r.min() >= 0.05 and r.max() <= 0.5
    y = sim.log.reference["ground_truth"].poses[:, 1]
    assert np.ptp(y) >= 20.0 - 1e-9 and np.unique(np.round(y[np.abs(np.diff(y, prepend=y[0])) < 1e-9])).size >= 3  # three rows


def test_config_errors_name_the_field(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("trees:\n  count: 10\n  radus: {min: 0.1}\n")
    with pytest.raises(UsageError, match=r"c.yaml: trees.radus: unknown key"):
        load_yaml_model(ParkConfig, p)
    p.write_text("laser:\n  range_sigma: -1\n")
    with pytest.raises(UsageError, match=r"c.yaml: laser.range_sigma: Input should be greater than or equal to 0"):
        load_yaml_model(ParkConfig, p)
    p.write_text("trees: [1, 2\n")
    with pytest.raises(UsageError, match=r"c.yaml:\d+: not valid YAML"):
        load_yaml_model(ParkConfig, p)


def test_landmark_dropout_loses_far_trees_only():
    """With landmark_dropout 0.5 beyond 10 m, a trunk farther than 10 m returns nothing in about half the scans
    and a nearer one never vanishes; the default (0) draws nothing more, so its scans are the default's bytes."""
    cfg = small_park_config()
    base = simulate_park(cfg, 3)
    d = cfg.model_dump()
    d["laser"].update(landmark_dropout=0.5, dropout_beyond=10.0)
    lossy = simulate_park(ParkConfig.model_validate(d), 3)
    d["laser"].update(landmark_dropout=0.0)
    assert np.array_equal(simulate_park(ParkConfig.model_validate(d), 3).log.scans.ranges, base.log.scans.ranges, equal_nan=True)
    log, world = lossy.log, lossy.world
    gt = log.reference["ground_truth"]
    poses = sensor_poses(gt.poses[np.searchsorted(gt.stamp, log.scans.stamp)], log.sensor.mount)
    near_kept, far_lost, far_all = [], 0, 0
    for k in range(0, len(poses), 5):
        truth, hit = cast_world(world, poses[k], log.sensor)
        r = log.scans.ranges[k]
        tree = (hit >= 0) & (hit < world.tree_r.size)
        dist = np.hypot(*(world.tree_xy - poses[k, :2]).T)
        for t in np.unique(hit[tree]):  # the trees this scan sees: tens
            beams = hit == t
            returned = np.isfinite(r[beams]).any()
            if dist[t] <= 10.0:
                near_kept.append(returned or beams.sum() <= 2)  # a tree of one or two beams may lose them to p_miss
            else:
                far_all += 1
                far_lost += not returned
    assert all(near_kept)
    # lost with probability 0.5 (and rarely by p_miss on every beam): over some hundreds of sightings, within 0.1
    assert far_all > 100 and abs(far_lost / far_all - 0.5) < 0.1
