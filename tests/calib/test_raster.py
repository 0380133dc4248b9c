import numpy as np
import pytest

from calib.raster import LikelihoodField, correlative_match, see_through, voxel_filter


def _room(rng, n_boxes=6):
    """World points (M, 2) on the walls of a 12 x 8 m room with a few boxes: truth for the matcher."""
    t = np.linspace(0.0, 1.0, 300)[:, None]
    segs = [((0, 0), (12, 0)), ((12, 0), (12, 8)), ((12, 8), (0, 8)), ((0, 8), (0, 0))]
    for _ in range(n_boxes):
        x, y = rng.uniform(1, 10), rng.uniform(1, 6)
        w, h = rng.uniform(0.3, 1.2, 2)
        segs += [((x, y), (x + w, y)), ((x + w, y), (x + w, y + h)), ((x + w, y + h), (x, y + h)), ((x, y + h), (x, y))]
    return np.vstack([np.array(a) + t * (np.array(b) - np.array(a)) for a, b in segs])


def _scan_of(world, pose, rng, radius=7.0):
    """Vehicle-frame points of the world points within ``radius`` of ``pose`` (a scan without occlusion), 1 cm noise."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    v = (world - pose[:2]) @ np.array([[c, -s], [s, c]])
    v = v[np.hypot(v[:, 0], v[:, 1]) < radius]
    return v + 0.01 * rng.standard_normal(v.shape)


def test_block_maxima_bound_the_field():
    rng = np.random.default_rng(0)
    f = LikelihoodField.from_points(_room(rng), 0.05, 0.05, depth=4)
    lv0, lv3 = f.levels[0], f.levels[3]
    for r, c in rng.integers(0, min(lv0.shape) - 8, size=(20, 2)):
        assert lv3[r, c] == pytest.approx(lv0[r : r + 8, c : c + 8].max())  # the block starting at (r, c), cv2.dilate anchor (0, 0)
    assert lv0[0].max() == 0.0 and lv0[:, -1].max() == 0.0  # the border ring reads 0 for clipped indices


def test_branch_and_bound_finds_the_exhaustive_optimum_with_less_work():
    rng = np.random.default_rng(1)
    world = _room(rng)
    true = np.array([5.0, 3.0, 0.4])
    pts = voxel_filter(_scan_of(world, true, rng, radius=5.0), 0.1)
    guess = true + np.array([0.35, -0.3, -0.08])
    deep = LikelihoodField.from_points(world, 0.05, 0.05, depth=6)
    flat = LikelihoodField.from_points(world, 0.05, 0.05, depth=0)  # no levels: every candidate is scored
    bb = correlative_match(deep, pts, guess, 0.5, 0.12)
    ex = correlative_match(flat, pts, guess, 0.5, 0.12)
    # branch and bound is exact: the same best candidate as the exhaustive search, for a fraction of the scores
    np.testing.assert_allclose(bb.pose, ex.pose)
    assert bb.score == pytest.approx(ex.score)
    assert bb.candidates < ex.candidates / 5
    # and the optimum is the truth within a cell (5 cm) and an angular step
    assert np.hypot(*(bb.pose[:2] - true[:2])) <= 0.075
    assert abs(bb.pose[2] - true[2]) <= 0.01


def test_motion_prior_picks_the_candidate_nearest_the_guess_on_a_plateau():
    # one long wall: every shift along it scores the same; the prior must keep the guess's position along it
    wall = np.column_stack([np.linspace(-20, 20, 2000), np.zeros(2000)])
    f = LikelihoodField.from_points(wall, 0.05, 0.05, depth=4)
    pts = np.column_stack([np.linspace(-5, 5, 200), np.full(200, -1.0)])  # the wall 1 m to the vehicle's right
    guess = np.array([0.3, 1.1, 0.0])  # 10 cm off across the wall
    m = correlative_match(f, pts, guess, 0.3, 0.05, translation_cost=0.5, rotation_cost=0.5)
    assert m.pose[0] == pytest.approx(0.3, abs=1e-9)  # along the wall: stays at the guess
    assert m.pose[1] == pytest.approx(1.0, abs=0.05)  # across it: found


def test_see_through_flags_beams_crossing_the_map():
    wall = np.column_stack([np.full(400, 5.0), np.linspace(-2, 2, 400)])
    f = LikelihoodField.from_points(wall, 0.05, 0.05)
    origin = np.zeros(2)
    ends = np.array([[4.9, 0.0], [8.0, 0.5], [5.0, 1.0], [3.0, 3.0]])  # short of the wall, through it, on it, beside it
    np.testing.assert_array_equal(see_through(f, origin, ends, 0.15), [False, True, False, False])


def test_no_candidate_above_the_floor_is_none():
    rng = np.random.default_rng(2)
    f = LikelihoodField.from_points(_room(rng), 0.1, 0.1, depth=5)
    far = np.column_stack([rng.uniform(30, 40, 50), rng.uniform(30, 40, 50)])  # points nowhere near the map
    assert correlative_match(f, far, np.zeros(3), 1.0, 0.2, min_score=0.3) is None
