import numpy as np
import pytest

from calib.sim.park import sensor_poses
from detectors.raytrace import buffer_zone, count_unoccluded, pd_grid
from profiles.schema import PdTable

TABLE = PdTable(edges=[0, 1, 2, 3, 4, 5, 6, 7], pd=[0.0, 0.0, 0.0, 0.36, 0.76, 0.89, 0.9])


def plain_np(pose, angles, ranges, centre, radius, sigma, k, rmax):
    """Independent n_p: the landmark's angular interval, then a per-beam quadratic and occlusion test."""
    rel = centre - pose[:2]
    dist = np.hypot(*rel)
    if dist <= radius:
        return 0, 0, 0.0
    half = np.arcsin(radius / dist)
    bearing = np.arctan2(rel[1], rel[0]) - pose[2]
    n_p = n_exp = 0
    offs = (angles - bearing + np.pi) % (2 * np.pi) - np.pi
    closest = float(np.min(np.abs(np.abs(offs) - half)))
    for b in np.flatnonzero(np.abs(offs) <= half + 1e-6):  # candidate beams; each is tested on its own
        off = offs[b]
        if abs(off) > half:
            continue
        # range along the beam to the near intersection: dist cos(off) - sqrt(r^2 - dist^2 sin^2(off))
        e = dist * np.cos(off) - np.sqrt(max(radius**2 - (dist * np.sin(off)) ** 2, 0.0))
        if e > rmax:
            continue
        n_exp += 1
        if not (ranges[b] < e - k * sigma):
            n_p += 1
    return n_p, n_exp, closest


def test_n_p_matches_a_plain_per_beam_implementation(small_sim):
    sim, log = small_sim, small_sim.log
    gt = log.reference["ground_truth"]
    idx = np.arange(len(log.scans))
    sp = sensor_poses(gt.poses[np.searchsorted(gt.stamp, log.scans.stamp[idx])], log.sensor.mount)
    ang = log.sensor.angles()
    sig = log.sensor.range_sigma
    n_p, n_exp = count_unoccluded(sp, ang, log.scans.ranges[idx], sim.world.tree_xy, sim.world.tree_r, range_sigma=sig, range_max=80.0)
    agree = total = 0
    unexplained = []
    for si in range(idx.size):
        r = log.scans.ranges[idx[si]].astype(np.float64)
        for li in range(sim.world.tree_r.size):
            p, e, closest = plain_np(sp[si], ang, r, sim.world.tree_xy[li], sim.world.tree_r[li], sig, 3.0, 80.0)
            total += 1
            if (p, e) == (n_p[si, li], n_exp[si, li]):
                agree += 1
            elif closest > 1e-9:
                unexplained.append((si, li))
    assert total > 10_000 and (n_exp > 0).sum() > 1000
    assert agree / total >= 0.999
    # any disagreement is a beam tangent to the trunk to within 1e-9 rad (floating-point edge)
    assert unexplained == []


def test_a_trunk_behind_another_is_occluded():
    ang = np.linspace(-np.pi / 2, np.pi / 2, 361)
    centres = np.array([[10.0, 0.0], [20.0, 0.0], [10.0, 5.0]])
    radii = np.array([0.5, 0.3, 0.3])
    # the measured scan sees only the near trunk on the beams it covers
    d = np.column_stack([np.cos(ang), np.sin(ang)])
    proj = d @ centres[0]
    disc = proj**2 - (100 - 0.25)
    meas = np.where(disc >= 0, proj - np.sqrt(np.maximum(disc, 0)), np.nan)
    n_p, n_exp = count_unoccluded(np.zeros(3), ang, meas, centres, radii, range_sigma=0.02)
    assert n_exp[0, 1] > 0 and n_p[0, 1] == 0  # hidden
    assert n_p[0, 0] == n_exp[0, 0] > 0  # the occluder itself is fully visible
    assert n_p[0, 2] == n_exp[0, 2] > 0  # a missing return (NaN) does not occlude


def test_pd_field_shadow_and_range_falloff():
    ang = np.linspace(-np.pi / 2, np.pi / 2, 361)
    meas = np.full(361, np.nan)
    meas[170:191] = 5.0  # a wall piece 5 m ahead
    xs, ys = np.linspace(0.5, 30, 60), np.linspace(-10, 10, 41)
    pd, n_p = pd_grid(np.zeros(3), ang, meas, xs, ys, 0.1, TABLE.lookup, range_sigma=0.02)
    assert pd.shape == (41, 60)
    row = np.argmin(np.abs(ys))
    behind = xs > 6
    assert np.all(pd[row, behind] == 0)  # in the shadow
    off = np.argmin(np.abs(ys - 4))
    assert pd[off, 2] > 0.5 and pd[off, -1] == 0  # close: seen; far: too few beams on 0.2 m


def test_buffer_zone_rules():
    ang = np.linspace(-np.pi / 2, np.pi / 2, 361)
    meas = np.full(361, np.nan)
    dists = np.linspace(4, 12, 81)
    n_line, _ = count_unoccluded(np.zeros(3), ang, meas, np.column_stack([dists, np.zeros(81)]), 0.1, range_sigma=0.02)
    far = dists[np.flatnonzero(n_line[0] == 3)[0]]  # P_D(3) = 0.36
    centres = np.array([[3.0, 0.0], [0.2, 3.0], [far, 0.0]])
    pd, buf = buffer_zone(np.zeros(3), ang, meas, centres, 0.1, np.array([0.3, 0.6, 0.3]), TABLE.lookup, range_sigma=0.02)
    # in the open and close: well detected, not in the buffer
    assert pd[0] == pytest.approx(0.9) and not buf[0]
    # at the edge of the 180 deg field of view: some lateral samples are outside -> buffer, max used
    assert buf[1] and pd[1] > 0
    # far away: 0 < P_D < 0.5 or zero/non-zero mix -> buffer
    n_p, _ = count_unoccluded(np.zeros(3), ang, meas, centres[2:], 0.1, range_sigma=0.02)
    assert 0 < TABLE.lookup(n_p)[0, 0] < 0.5 and buf[2]
    with pytest.raises(ValueError, match="odd"):
        buffer_zone(np.zeros(3), ang, meas, centres, 0.1, 0.3, TABLE.lookup, samples=4, range_sigma=0.02)


def test_one_scan_shared_by_many_poses_in_several_chunks(small_sim):
    """Particles share the current scan: the (B,) or (1, B) scan must serve every chunk of poses."""
    log = small_sim.log
    ang, scan = log.sensor.angles(), log.scans.ranges[5].astype(np.float64)
    gt = log.reference["ground_truth"]
    base = sensor_poses(gt.poses[np.searchsorted(gt.stamp, log.scans.stamp[5])][None], log.sensor.mount)[0]
    rng = np.random.default_rng(3)
    poses = base + rng.normal(0, [0.2, 0.2, 0.02], (3, 3))
    centres = base[:2] + rng.uniform(-30, 30, (3, 12_000, 2))  # 361 beams x 12,000 landmarks: one pose per chunk
    for shared in (scan, scan[None]):
        n_p, _ = count_unoccluded(poses, ang, shared, centres, 0.2, range_sigma=0.02)
        for s in range(3):
            alone, _ = count_unoccluded(poses[s], ang, scan[None], centres[s], 0.2, range_sigma=0.02)
            np.testing.assert_array_equal(n_p[s], alone[0])
    assert n_p.sum() > 0
    pd, _ = buffer_zone(poses, ang, scan, centres[:, :4000], 0.2, 0.3, TABLE.lookup, range_sigma=0.02)
    assert pd.shape == (3, 4000)
