"""Resamplers and the ancestry: unbiased copies, and trajectories rebuilt exactly through resampling."""

import numpy as np
import pytest

from profiles.errors import UsageError
from slam_runtime.features import RangeBearing
from slam_runtime.mapfilter import MapFilter
from slam_runtime.particles import RESAMPLERS, ParticleHistory, ess, normalise_log, systematic
from slam_runtime.plane_features import PlaneFeature
from slam_runtime.slam import RBSlam, average_states, match_labels
from slam_runtime.sources import Measurements
from slam_runtime.vehicle import OdometryIncrement


def _nothing() -> Measurements:
    """A scan without measurements (the map filters of these tests take their likelihoods from elsewhere)."""
    return Measurements(np.zeros((0, 2)))


@pytest.mark.parametrize("name", sorted(RESAMPLERS))
def test_resamplers_copy_each_particle_in_proportion_to_its_weight(name):
    rng = np.random.default_rng(0)
    w = rng.dirichlet(np.ones(20))
    counts = np.zeros(20)
    runs = 4000
    for _ in range(runs):
        idx = RESAMPLERS[name](w, rng)
        assert idx.shape == (20,) and (np.diff(idx) >= 0).all()
        counts += np.bincount(idx, minlength=20)
    # expected copies P w; over 4,000 runs the mean of each count is within 0.05 (> 4 standard errors)
    np.testing.assert_allclose(counts / runs, 20 * w, atol=0.05)


def test_systematic_copies_are_the_floor_or_the_ceiling_of_p_w():
    rng = np.random.default_rng(1)
    for _ in range(200):
        w = rng.dirichlet(np.ones(13) * 0.5)
        c = np.bincount(systematic(w, rng), minlength=13)
        assert ((c == np.floor(13 * w)) | (c == np.ceil(13 * w))).all()


def test_ess_and_normalisation():
    lw, s = normalise_log(np.log(np.array([1.0, 1.0, 2.0])))
    np.testing.assert_allclose(np.exp(lw), [0.25, 0.25, 0.5])
    assert s == pytest.approx(np.log(4.0))
    assert ess(np.log(np.array([0.25, 0.25, 0.5]))) == pytest.approx(1 / (0.0625 * 2 + 0.25))
    with pytest.raises(FloatingPointError, match="zero weight"):
        normalise_log(np.full(3, -np.inf))


def test_ancestry_rebuilds_every_trajectory_through_resampling():
    """Each particle's state is a unique code of (step, particle); after random resamplings the rebuilt
    trajectory of every particle is its true lineage, which is followed here by hand."""
    rng = np.random.default_rng(2)
    p, steps = 6, 300
    x = np.zeros((p, 1))
    hist = ParticleHistory(x, capacity=4)  # small: the history grows by doubling
    lineage = [[(0, i)] for i in range(p)]  # per current particle: its (step, index) ancestors
    pending = np.arange(p)
    for t in range(1, steps):
        x = np.array([[t * 1000 + i] for i in range(p)], dtype=float)  # the state names its step and slot
        hist.append(x, pending)
        lineage = [lin + [(t, i)] for i, lin in enumerate(lineage)]
        if rng.uniform() < 0.5:
            idx = np.sort(rng.integers(0, p, p))
            lineage = [list(lineage[j]) for j in idx]
            pending = idx
            x = x[idx]
        else:
            pending = np.arange(p)
    for i in range(p):
        traj = hist.trajectory(int(pending[i]))[:, 0]
        expected = [0.0] + [t * 1000 + k for t, k in lineage[i][1:]]
        np.testing.assert_array_equal(traj, expected)
    assert hist.states.shape == (steps, p, 1) and hist.parents.shape == (steps, p)


class _ScoredMaps(MapFilter):
    """A map filter whose map is a score per particle; the log-likelihood of a step is the score (a particle's
    map says how well it explains the data), so which particle is heaviest is known."""

    name = "scored"

    def __init__(self, scores: np.ndarray) -> None:
        super().__init__(None, None)
        self.scores = scores

    def empty(self, n: int) -> np.ndarray:
        return self.scores[:n].copy()

    def predict(self, maps, dt):
        return maps

    def update(self, maps, poses, meas):
        return maps, maps.copy()

    def size(self, maps):
        return np.ones(maps.shape[0])

    def estimate(self, maps, i):
        return np.array([[maps[i], 0.0]]), np.ones(1)


@pytest.mark.parametrize("resampler", ["systematic", "stratified", "residual"])
def test_the_estimate_stays_with_the_heaviest_particle_through_resampling(resampler):
    """After a resampling every weight is 1/n; the estimate must still be the particle that was heaviest (the
    argmax of uniform weights would be particle 0, whatever it holds)."""
    # weights 0.3 and 0.6 for particles 0 and 3 (ESS 2.2 of 8: resampled); particle 0 keeps copies, so the
    # first particle after resampling is one of its copies, not the heaviest's
    scores = np.log([0.3, 0.01, 0.01, 0.6, 0.02, 0.02, 0.02, 0.02])
    slam = RBSlam(OdometryIncrement(), _ScoredMaps(scores), 8, np.zeros(3), np.random.default_rng(0), resampler=resampler)
    info = slam.update(_nothing())
    assert info.resampled and np.allclose(slam.weights(), 1 / 8)
    assert slam.maps[0] == scores[0]  # the argmax of the uniform weights would give particle 0's map
    assert slam.map_estimate()[0][0, 0] == scores[3]
    assert slam.maps[slam.best()] == scores[3] and slam.trajectory().shape == (2, 3)
    # the next step without resampling: the argmax again (the copies of particle 3 keep the largest score)
    slam.resample_ess = 0.0
    assert not slam.update(_nothing()).resampled and slam.map_estimate()[0][0, 0] == scores[3]


def test_islands_are_independent_filters():
    """Two islands of four particles: each normalises and resamples its own weights, so after a resampling each
    island holds only copies of its own particles and weighs half; the log evidence is the log of the mean of the
    islands' (0.25 and 0.5: log 0.375); the estimate is the heaviest particle of the island with the larger
    evidence. Particles that are not a multiple of the islands are refused."""
    scores = np.log([0.7, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 1.7])
    slam = RBSlam(OdometryIncrement(), _ScoredMaps(scores), 8, np.zeros(3), np.random.default_rng(0), islands=2)
    info = slam.update(_nothing())
    assert info.resampled
    assert set(slam.maps[:4].tolist()) <= set(scores[:4].tolist()) and set(slam.maps[4:].tolist()) <= set(scores[4:].tolist())
    assert np.all(slam._pending[:4] < 4) and np.all(slam._pending[4:] >= 4)  # the history's parents stay in the island
    w = slam.weights()
    assert w[:4].sum() == pytest.approx(0.5) and w[4:].sum() == pytest.approx(0.5)
    assert slam.log_evidence == pytest.approx(np.log(0.375))
    assert slam.maps[slam.best()] == scores[7] and slam.map_estimate()[0][0, 0] == scores[7]
    assert slam.trajectory().shape == (2, 3)
    with pytest.raises(UsageError, match="multiple of islands"):
        RBSlam(OdometryIncrement(), _ScoredMaps(scores), 8, np.zeros(3), np.random.default_rng(0), islands=3)


class _GivenLikelihoods(MapFilter):
    """A map filter whose map is the particle's index and whose step log-likelihoods are given, one row per step."""

    name = "given"

    def __init__(self, rows: list) -> None:
        super().__init__(None, None)
        self.rows = iter(rows)

    def empty(self, n: int) -> np.ndarray:
        return np.arange(n, dtype=np.float64)

    def predict(self, maps, dt):
        return maps

    def update(self, maps, poses, meas):
        return maps, np.asarray(next(self.rows), dtype=np.float64)

    def size(self, maps):
        return np.ones(maps.shape[0])

    def estimate(self, maps, i):
        return np.array([[maps[i], 0.0]]), np.ones(1)


def test_an_island_resamples_alone_and_the_trajectory_averages_across_the_wrap():
    """Island 0's weights collapse (one particle takes 0.97) and island 1's stay even: island 0 alone resamples
    (its particles become copies of particle 1, its weights uniform), island 1 keeps its particles and its
    weights. The islands' heaviest particles head pi - 0.05 and -pi + 0.15: the trajectory's last heading is
    their circular mean, -pi + 0.05 (a plain mean gives 0.05, the opposite way), and its position the mean of the
    two heaviest particles' own (particles 1 and 5: x = 1 and 3)."""
    step = np.log([0.01, 0.97, 0.01, 0.01, 0.2, 0.3, 0.25, 0.25])
    slam = RBSlam(OdometryIncrement(), _GivenLikelihoods([step]), 8, np.zeros(3), np.random.default_rng(0), islands=2)
    # the particles' positions differ, so the trajectory must follow each heaviest particle's own ancestor
    slam.x[:4] = [[0.0, 2.0, np.pi - 0.05], [1.0, 2.0, np.pi - 0.05], [5.0, 2.0, np.pi - 0.05], [7.0, 2.0, np.pi - 0.05]]
    slam.x[4:] = [[9.0, 0.0, -np.pi + 0.15], [3.0, 0.0, -np.pi + 0.15], [8.0, 0.0, -np.pi + 0.15], [6.0, 0.0, -np.pi + 0.15]]
    info = slam.update(_nothing())
    assert info.resampled
    assert np.all(slam.maps[:4] == 1.0) and np.array_equal(slam.maps[4:], [4.0, 5.0, 6.0, 7.0])
    w = slam.weights()
    np.testing.assert_allclose(w, [0.125] * 4 + [0.1, 0.15, 0.125, 0.125])
    assert slam.island_best(0) in range(4) and slam.island_best(1) == 5
    last = slam.trajectory()[-1]
    np.testing.assert_allclose(last, [2.0, 1.0, -np.pi + 0.05], atol=1e-12)


def test_island_maps_average_label_by_label():
    """The islands' map estimate: the reference's labels, each at the mean of its state in the estimates that hold
    it (label 5 in all three: (0 + 3 + 6) / 3; label 3 in two: (1 + 2) / 2; label 9, held by another island only,
    is not in the reference's set); an angular state component averages across the wrap."""
    fm = RangeBearing(np.eye(2))
    x = average_states(fm, np.array([5, 3]), np.array([[0.0, 1.0], [1.0, 1.0]]),
                       [(np.array([9, 3, 5]), np.array([[7.0, 7.0], [2.0, 1.0], [3.0, 1.0]])), (np.array([5]), np.array([[6.0, 1.0]]))])  # fmt: skip
    np.testing.assert_allclose(x, [[3.0, 1.0], [1.5, 1.0]])
    x = average_states(PlaneFeature(np.eye(3)), np.array([1]), np.array([[np.pi - 0.05, 0.0, 2.0]]), [(np.array([1]), np.array([[-np.pi + 0.15, 0.0, 4.0]]))])
    np.testing.assert_allclose(x, [[-np.pi + 0.05, 0.0, 3.0]], atol=1e-12)


def test_island_features_pair_by_position_when_their_labels_differ():
    """island_match: features that no label pairs are paired one to one by the least total distance, within the gate.
    Label 1 pairs by label even 3 m away; label 7 (0.1 m from the reference's 2) takes label 2; labels 8 and 9 go to
    the reference's 4 and 3, though 8 is nearer 3 (0.45 m) than 4 (0.55 m): pairing each with its nearest would give
    3 to 8 and leave 9 1.4 m from 4, beyond the gate; label 6, 2 m from every free feature, keeps its label. With a
    gate of 0.3 m only 7 pairs. The average then holds one landmark under two labels as one."""
    fm = RangeBearing(np.eye(2))
    ref_l, ref_x = np.array([1, 2, 3, 4]), np.array([[0.0, 0.0], [5.0, 0.0], [10.0, 0.0], [11.0, 0.0]])
    oth_l = np.array([1, 7, 8, 9, 6])
    oth_x = np.array([[3.0, 0.0], [5.1, 0.0], [10.45, 0.0], [9.6, 0.0], [5.0, 2.0]])
    out = match_labels(fm, ref_l, ref_x, oth_l, oth_x, 1.0)
    np.testing.assert_array_equal(out, [1, 2, 4, 3, 6])
    np.testing.assert_array_equal(oth_l, [1, 7, 8, 9, 6])  # not changed in place
    np.testing.assert_array_equal(match_labels(fm, ref_l, ref_x, oth_l, oth_x, 0.3), [1, 2, 8, 9, 6])
    x = average_states(fm, ref_l, ref_x, [(out, oth_x)])
    np.testing.assert_allclose(x, [[1.5, 0.0], [5.05, 0.0], [9.8, 0.0], [10.725, 0.0]])


def test_island_match_is_refused_for_planes_naming_the_setting():
    from pydantic import ValidationError

    from slam_runtime.config import SlamConfig

    with pytest.raises(ValidationError, match="island_match pairs point features by position; it does not apply to planes"):
        SlamConfig(features="planes", island_match=0.5)
    assert SlamConfig(island_match=0.5).island_match == 0.5


def test_the_optimal_proposal_is_refused_for_planes():
    """It was accepted, recorded in the run folder and not applied (the particle loop fell back to the prior)."""
    from pydantic import ValidationError

    from slam_runtime.config import SlamConfig

    with pytest.raises(ValidationError, match="proposal 'optimal' draws the pose from point features' measurements; it does not apply to planes"):
        SlamConfig(features="planes", proposal="optimal")
    assert SlamConfig(features="planes").proposal == "auto" and SlamConfig(proposal="optimal").proposal == "optimal"
    # auto: the optimal proposal for point (range-bearing) features only, the prior for planes
    from types import SimpleNamespace

    from slam_runtime.features import RangeBearing
    from slam_runtime.slam import resolve_proposal

    veh = OdometryIncrement()
    assert resolve_proposal("auto", veh, SimpleNamespace(proposes_poses=True, feature=object())) == "prior"
    assert resolve_proposal("auto", veh, SimpleNamespace(proposes_poses=True, proposal_default="optimal", feature=RangeBearing(np.eye(2)))) == "optimal"
    assert resolve_proposal("auto", veh, SimpleNamespace(proposes_poses=True, feature=RangeBearing(np.eye(2)))) == "prior"
    assert resolve_proposal("optimal", veh, SimpleNamespace(proposes_poses=False, feature=RangeBearing(np.eye(2)))) == "prior"


def test_each_island_counts_its_own_updates_since_it_resampled():
    """resample_every = 2 with two islands: at step 2 island 0's weights collapse and it resamples alone; at step 3
    both collapse, and only island 1 (three updates since it last resampled, against island 0's one) resamples.
    A count shared by the islands, reset whenever any island resamples, would hold island 1 back at step 3."""
    even = np.zeros(8)
    collapse = np.log([0.01, 0.97, 0.01, 0.01, 0.01, 0.01, 0.97, 0.01])
    first = np.concatenate([collapse[:4], even[4:]])
    slam = RBSlam(OdometryIncrement(), _GivenLikelihoods([even, first, collapse]), 8, np.zeros(3), np.random.default_rng(0),
                  resample_every=2, islands=2)  # fmt: skip
    assert not slam.update(_nothing()).resampled  # even weights
    assert slam.update(_nothing()).resampled
    assert np.all(slam.maps[:4] == 1.0) and np.array_equal(slam.maps[4:], [4.0, 5.0, 6.0, 7.0])
    assert slam.update(_nothing()).resampled
    assert np.all(slam.maps[:4] == 1.0) and np.all(slam.maps[4:] == 6.0)
    # island 0 collapsed but was not due: its weights carry the collapse (particle 1 of its four copies heaviest)
    w = slam.weights()
    assert w[1] == pytest.approx(0.5 * 0.97) and np.allclose(w[4:], 0.125)


class _ProposingMaps(_ScoredMaps):
    """As _ScoredMaps, offering a pose proposal five metres from the motion's mean (a draw no placed pose is near)."""

    proposes_poses = True

    def pose_proposal(self, maps, xbar, q, meas):
        return xbar + 5.0, q + np.eye(3) * 0.01, None


@pytest.mark.parametrize("proposal", ["prior", "optimal"])
def test_placed_poses_replace_the_motions_draw_and_the_ect_keeps_its_velocities(proposal):
    """Mapping with the path given: after ``place`` every particle holds the given pose whatever the motion or the
    optimal proposal would draw, and the trajectory records it; the ECT model's six states take the pose in X, Y
    and phi and keep the velocity states the odometry set."""
    slam = RBSlam(OdometryIncrement(), _ProposingMaps(np.zeros(4)), 4, np.zeros(3), np.random.default_rng(0), proposal=proposal)
    assert slam.proposal == proposal
    given = [np.array([1.0, 0.5, 0.2]), np.array([2.0, 1.0, -3.0])]
    for pose in given:
        slam.predict(np.array([[1.0, 0.0, 0.0]]), np.array([1.0]))
        slam.place(pose)
        slam.update(_nothing())
        np.testing.assert_array_equal(slam.x, np.repeat(pose[None], 4, axis=0))
    np.testing.assert_array_equal(slam.trajectory()[1:], np.stack(given))
    from slam_runtime.ect import ECT

    ect = RBSlam(ECT(), _ScoredMaps(np.zeros(4)), 4, np.zeros(3), np.random.default_rng(0))
    ect.predict(np.array([[2.0, 0.1]]), np.array([0.1]))
    vel = ect.x[:, [1, 3, 5]].copy()
    ect.place(given[0])
    np.testing.assert_array_equal(ect.vehicle.pose(ect.x), np.repeat(given[0][None], 4, axis=0))
    np.testing.assert_array_equal(ect.x[:, [1, 3, 5]], vel)
