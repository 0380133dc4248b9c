"""Resamplers and the ancestry: unbiased copies, and trajectories rebuilt exactly through resampling."""

import numpy as np
import pytest

from slam_runtime.particles import RESAMPLERS, ParticleHistory, ess, normalise_log, systematic


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
