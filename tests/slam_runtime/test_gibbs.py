"""The compiled pieces of the labelled filters against independent references, and one joint delta-GLMB /
LMB update against a brute-force enumeration of every association map."""

import itertools

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment
from scipy.stats import multivariate_normal

from detectors.model import DetectionModel
from profiles.schema import ClutterParams, PdTable, SensorModel
from slam_runtime.features import RangeBearing
from slam_runtime.gibbs import joint_update
from slam_runtime.hypotheses import reduce_hypotheses
from slam_runtime.kernels import argsort_stable, hungarian
from slam_runtime.glmb import GLMB, GLMBConfig, GLMBMaps
from slam_runtime.labelled import Births, Tracks
from slam_runtime.lmb import LMB, LMBConfig, LMBMaps
from slam_runtime.mapfilter import Measurements


@pytest.mark.parametrize("shape", [(1, 1), (3, 3), (4, 9), (7, 12), (12, 30)])
def test_hungarian_matches_scipy(shape):
    """Random costs, some pairs forbidden (a large cost): the same minimum as scipy's solver."""
    rng = np.random.default_rng(sum(shape))
    for _ in range(20):
        c = rng.normal(size=shape) * 10
        c[rng.uniform(size=shape) < 0.3] = 1e15
        n = shape[0]
        full = np.hstack([c, np.where(np.eye(n, dtype=bool), 5.0, 1e15)])  # every row can fall back on its own column
        cols = hungarian(full)
        r, k = linear_sum_assignment(full)
        assert len(set(cols.tolist())) == n
        assert full[np.arange(n), cols].sum() == pytest.approx(full[r, k].sum(), rel=1e-12, abs=1e-9)


def test_argsort_stable_matches_numpy():
    rng = np.random.default_rng(1)
    for n in (0, 1, 2, 7, 100, 1001):
        x = rng.integers(0, 10, n).astype(np.float64)  # many ties: stability matters
        np.testing.assert_array_equal(argsort_stable(x), np.argsort(x, kind="stable"))
        xi = rng.integers(-(2**62), 2**62, n)
        np.testing.assert_array_equal(argsort_stable(xi), np.argsort(xi, kind="stable"))


# ---------------------------------------------------------------------- one joint update, enumerated
SENSOR = SensorModel(kind="camera", fov=np.pi, range_max=20.0)
PD, PS, RB, RATE = 0.8, 0.9, 0.05, 2.0
R = np.diag([0.15**2, 0.03**2])
KAPPA = RATE / (np.pi * 20.0)
MU = {"A": np.array([5.0, 1.0]), "B": np.array([5.0, -0.6]), "b": np.array([8.0, 0.2])}
COV = {"A": np.eye(2) * 0.05**2, "B": np.eye(2) * 0.08**2, "b": np.diag([0.3**2, 0.3**2])}
LAB = {"A": 7, "B": 9, "b": 1 << 20}
POSE = np.array([0.3, -0.2, 0.05])


def _det():
    pdt = PdTable(covariate="range", edges=[0.0, 20.0], pd=[PD])
    return DetectionModel(pdt, ClutterParams(rate=RATE, volume=np.pi * 20.0), SENSOR, buffer=False)


def _meas(fm):
    """Three measurements: near A, between A and B, near the birth."""
    zs, _ = fm.predict(POSE[None], np.array([[5.02, 0.95], [5.0, 0.1], [7.9, 0.25]]))
    return zs


def _q(fm, key, z):
    """g(z | track) of eq. 27: the Gaussian of the predicted measurement, innovation wrapped."""
    zh, h = fm.predict(POSE[None], MU[key][None])
    s = h[0] @ COV[key] @ h[0].T + R
    nu = fm.innovation(z[None], zh)[0]
    return multivariate_normal(np.zeros(2), s).pdf(nu)


def _eta(fm, key, r, ps, a, z):
    """eta of eqs. 5, 13, 15 for candidate ``key`` of existence r: a = -1 absent, 0 missed, j + 1 detected by z_j."""
    if a < 0:
        return 1.0 - r * ps
    if a == 0:
        return r * ps * (1.0 - PD)
    return r * ps * PD * _q(fm, key, z[a - 1]) / KAPPA


def _enumerate(fm, z, parents):
    """Every child of every prior: parents [(weight, [(key, r, ps)])] -> {frozenset((key, a)): weight}, total."""
    out: dict = {}
    m = len(z)
    for w, cands in parents:
        for gamma in itertools.product(range(-1, m + 1), repeat=len(cands)):
            used = [a for a in gamma if a > 0]
            if len(used) != len(set(used)):
                continue
            wt = w
            for (key, r, ps), a in zip(cands, gamma, strict=True):
                wt *= _eta(fm, key, r, ps, a, z)
            k = frozenset((key, a) for (key, _, _), a in zip(cands, gamma, strict=True) if a >= 0)
            out[k] = out.get(k, 0.0) + wt
    return out, sum(out.values())


def _summary(children: dict, total: float):
    """Label-set distribution, existence per label and each label's posterior mean (under 'it exists')."""
    sets, exist = {}, {}
    for k, w in children.items():
        labels = frozenset(key for key, _ in k)
        sets[labels] = sets.get(labels, 0.0) + w / total
        for key, _ in k:
            exist[key] = exist.get(key, 0.0) + w / total
    return sets, exist


def _glmb_state(fm):
    tr = Tracks(np.stack([MU["A"], MU["B"]])[None], np.stack([COV["A"], COV["B"]])[None], np.array([[LAB["A"], LAB["B"]]]))
    logw = np.log(np.array([[0.6, 0.3, 0.1]]))
    member = np.array([[[True, True], [True, False], [False, False]]])
    births = Births(MU["b"][None, None], COV["b"][None, None], np.array([[RB]]), np.array([LAB["b"]]))
    return GLMBMaps(tr, logw, member, Tracks.empty(1, 2), np.zeros((1, 0)), births)


def _updated_mean(fm, key, a, z):
    """The track's mean after the EKF update with z_(a-1) (eq. 17), or its prior mean when missed (a = 0)."""
    if a == 0:
        return MU[key]
    zh, h = fm.predict(POSE[None], MU[key][None])
    s = h[0] @ COV[key] @ h[0].T + R
    k = COV[key] @ h[0].T @ np.linalg.inv(s)
    return MU[key] + k @ fm.innovation(z[a - 1][None], zh)[0]


def _filter_children(fm, z, maps) -> dict:
    """The filter's hypotheses as {frozenset((key, a)): weight}: each track version identified by its mean."""
    inv = {v: k for k, v in LAB.items()}
    out = {}
    for h in np.flatnonzero(np.isfinite(maps.logw[0])):
        k = []
        for slot in np.flatnonzero(maps.member[0, h]):
            key = inv[int(maps.tracks.label[0, slot])]
            a = min(range(len(z) + 1), key=lambda a: np.linalg.norm(_updated_mean(fm, key, a, z) - maps.tracks.mu[0, slot]))
            assert np.allclose(_updated_mean(fm, key, a, z), maps.tracks.mu[0, slot], atol=1e-9)
            k.append((key, a))
        out[frozenset(k)] = float(np.exp(maps.logw[0, h]))
    return out


def _run_glmb(fm, z, samples, state):
    cfg = GLMBConfig(samples=samples, merge=0.0, release_unseen=False, factor_independent=False, prune=1e-15, max_hypotheses=100_000, gate=1e6, survival=PS)
    mf = GLMB(fm, _det(), cfg, rng=np.random.default_rng(3))
    return mf.update(state, POSE[None], Measurements(z))


def test_joint_glmb_update_converges_to_the_enumeration():
    """One hypothesis {A, B} of weight 1, one birth, three measurements (one between A and B): 34 children.
    The Gibbs-sampled joint update (exact mode: no version merging, nothing released) finds a subset of them:
    each found child has exactly its enumerated weight (eqs. 12-17, normalised over what was found), and the
    normalisation constant (eq. 25), a lower bound, reaches the enumerated one as the samples grow (what is
    missing is the mass of the children not yet drawn, each of probability below 1e-3)."""
    fm = RangeBearing(R)
    z = _meas(fm)
    children, total = _enumerate(fm, z, [(1.0, [("A", 1.0, PS), ("B", 1.0, PS), ("b", RB, 1.0)])])
    state = _glmb_state(fm)
    state.logw = np.array([[0.0, -np.inf, -np.inf]])
    gaps = []
    for samples in (1, 10, 300, 20000):
        maps, ll = _run_glmb(fm, z, samples, state)
        found = _filter_children(fm, z, maps)
        sub = sum(children[k] for k in found)
        for k, w in found.items():
            assert w == pytest.approx(children[k] / sub, rel=1e-9)
        assert ll[0] == pytest.approx(np.log(sub), abs=1e-9)  # eq. 25 over the children found
        gaps.append(np.log(total) - ll[0])
    assert gaps[0] > 0.1  # the optimal child alone misses much of the mass
    assert all(a >= b >= 0.0 for a, b in itertools.pairwise(gaps))
    assert gaps[-1] < 1e-3


def test_joint_glmb_update_of_several_hypotheses_matches_the_enumeration():
    """Three prior hypotheses {A, B}, {A}, {} (0.6, 0.3, 0.1): children of different priors that are the same
    labelled hypothesis are merged (86 distinct children). With 20,000 samples the label-set distribution
    and every existence match the enumeration to within the mass not drawn (< 1e-3)."""
    fm = RangeBearing(R)
    z = _meas(fm)
    parents = [(0.6, [("A", 1.0, PS), ("B", 1.0, PS), ("b", RB, 1.0)]), (0.3, [("A", 1.0, PS), ("b", RB, 1.0)]), (0.1, [("b", RB, 1.0)])]
    children, total = _enumerate(fm, z, parents)
    sets, exist = _summary(children, total)
    maps, ll = _run_glmb(fm, z, 20000, _glmb_state(fm))
    assert 0.0 <= np.log(total) - ll[0] < 1e-3
    f_sets, f_exist = {}, {}
    for k, w in _filter_children(fm, z, maps).items():
        labels = frozenset(key for key, _ in k)
        f_sets[labels] = f_sets.get(labels, 0.0) + w
        for key, _ in k:
            f_exist[key] = f_exist.get(key, 0.0) + w
    for k, v in sets.items():
        assert f_sets.get(k, 0.0) == pytest.approx(v, abs=2e-3)
    for k, v in exist.items():
        assert f_exist[k] == pytest.approx(v, abs=2e-3)


def test_joint_lmb_update_matches_the_enumeration():
    """The LMB filter: the joint update of an LMB (tracks of existence 0.9 and 0.4, one birth) by the same
    enumeration; its posterior existences (the LMB approximation, Reuter et al. eq. 20) and the normalisation
    constant match to within the mass of the children not drawn (< 1e-3 with 20,000 samples)."""
    fm = RangeBearing(R)
    z = _meas(fm)
    children, total = _enumerate(fm, z, [(1.0, [("A", 0.9, PS), ("B", 0.4, PS), ("b", RB, 1.0)])])
    _, exist = _summary(children, total)
    tr = Tracks(np.stack([MU["A"], MU["B"]])[None], np.stack([COV["A"], COV["B"]])[None], np.array([[LAB["A"], LAB["B"]]]))
    births = Births(MU["b"][None, None], COV["b"][None, None], np.array([[RB]]), np.array([LAB["b"]]))
    mf = LMB(fm, _det(), LMBConfig(samples=20000, gate=1e6, survival=PS, prune_tracks=1e-12), rng=np.random.default_rng(1))
    maps, ll = mf.update(LMBMaps(tr, np.array([[0.9, 0.4]]), births), POSE[None], Measurements(z))
    assert 0.0 <= np.log(total) - ll[0] < 1e-3
    inv = {v: k for k, v in LAB.items()}
    got = {inv[int(x)]: float(r) for x, r in zip(maps.tracks.label[0], maps.r[0], strict=True) if x >= 0}
    for k, v in exist.items():
        assert got[k] == pytest.approx(v, abs=2e-3)


def test_lmb_updates_independent_tracks_exactly_outside_the_sampler():
    """LMB with ``factor_independent``: tracks A and B share the measurement between them (one chain), the birth
    gates only its own measurement and a track C in view gates none (both independent: updated outside the
    sampler). With one Gibbs sample the independent ones already have the existences and means that 20,000
    samples of the joint chain give (within the undrawn mass), and C's existence is the exact r P_S (1 - P_D) /
    (1 - r P_S P_D); with 20,000 samples either way every track agrees, and so does the normalisation constant."""
    fm = RangeBearing(R)
    z = _meas(fm)
    c_pos = np.array([3.0, -3.0])
    tr = Tracks(
        np.stack([MU["A"], MU["B"], c_pos])[None], np.stack([COV["A"], COV["B"], np.eye(2) * 0.05**2])[None], np.array([[LAB["A"], LAB["B"], 11]])
    )
    births = Births(MU["b"][None, None], COV["b"][None, None], np.array([[RB]]), np.array([LAB["b"]]))
    state = LMBMaps(tr, np.array([[0.9, 0.4, 0.6]]), births)

    def run(samples, factor):
        cfg = LMBConfig(samples=samples, survival=PS, prune_tracks=1e-12, factor_independent=factor)
        maps, ll = LMB(fm, _det(), cfg, rng=np.random.default_rng(1)).update(state, POSE[None], Measurements(z))
        keep = maps.tracks.label[0] >= 0
        return dict(zip(maps.tracks.label[0][keep].tolist(), zip(maps.r[0][keep], maps.tracks.mu[0][keep], strict=True), strict=True)), ll[0]

    ref, ll_ref = run(20000, False)
    one, _ = run(1, True)
    full, ll_full = run(20000, True)
    # with learn_pd the factors on P_D follow the same shares: the independent tracks' after one sample as the chain's
    ab = {}
    for samples, factor in ((20000, False), (1, True)):
        cfg = LMBConfig(samples=samples, survival=PS, prune_tracks=1e-12, factor_independent=factor, learn_pd=True)
        maps, _ = LMB(fm, _det(), cfg, rng=np.random.default_rng(1)).update(state, POSE[None], Measurements(z))
        ab[factor] = {int(x): maps.pd_ab[0, k] for k, x in enumerate(maps.tracks.label[0]) if x >= 0}
    for lab in (11, LAB["b"]):
        np.testing.assert_allclose(ab[True][lab], ab[False][lab], atol=2e-2)
    assert one[11][0] == pytest.approx(0.6 * PS * (1 - PD) / (1 - 0.6 * PS * PD), rel=1e-12)
    for lab in (11, LAB["b"]):
        assert one[lab][0] == pytest.approx(ref[lab][0], abs=2e-3)
        np.testing.assert_allclose(one[lab][1], ref[lab][1], atol=1e-3)
    for lab in ref:
        assert full[lab][0] == pytest.approx(ref[lab][0], abs=2e-3)
        np.testing.assert_allclose(full[lab][1], ref[lab][1], atol=1e-3)
    assert ll_full == pytest.approx(ll_ref, abs=1e-3)


# ---------------------------------------------------------------------- summed births, keyed random numbers
FAR = np.array([2.0, 6.0])  # a birth that gates none of the three measurements (in view, 5.8 m away from them)


def _far_birth_state(fm):
    tr = Tracks(np.stack([MU["A"], MU["B"]])[None], np.stack([COV["A"], COV["B"]])[None], np.array([[LAB["A"], LAB["B"]]]))
    births = Births(
        np.stack([MU["b"], FAR])[None], np.stack([COV["b"], np.eye(2) * 0.05**2])[None], np.array([[RB, RB]]), np.array([LAB["b"], (1 << 20) + 1])
    )
    return GLMBMaps(tr, np.zeros((1, 1)), np.ones((1, 1, 2), dtype=bool), Tracks.empty(1, 2), np.zeros((1, 0)), births)


def test_a_birth_that_gates_nothing_is_summed_out_exactly():
    """Hypothesis {A, B}, a birth near the third measurement and one far from every measurement (the
    default gate, 16). With 20,000 samples the normalisation constant is the same whether the far birth is
    summed out or sampled (what the sampler still misses is below 1e-4 either way), and below the
    enumeration without a gate (the gate drops the far pairs' mass). Summed out, no child holds the far
    birth, whose two options (not born, born and missed) only scale every child alike; sampled, the
    children in which it exists undetected are drawn too."""
    fm = RangeBearing(R)
    z = _meas(fm)
    _, total = _enumerate(fm, z, [(1.0, [("A", 1.0, PS), ("B", 1.0, PS), ("b", RB, 1.0)])])
    total *= (1.0 - RB) + RB * (1.0 - PD)  # the far birth: independent of the rest
    out = {}
    for summed in (True, False):
        cfg = GLMBConfig(samples=20000, merge=0.0, release_unseen=False, factor_independent=False, prune=1e-15, max_hypotheses=100_000, survival=PS, sum_idle_births=summed)
        mf = GLMB(fm, _det(), cfg, rng=np.random.default_rng(3))
        maps, ll = mf.update(_far_birth_state(fm), POSE[None], Measurements(z))
        held = (maps.tracks.label[0] == (1 << 20) + 1) & maps.member[0][np.isfinite(maps.logw[0])].any(axis=0)
        out[summed] = ll[0], bool(held.any())
    assert out[True][0] == pytest.approx(out[False][0], abs=1e-4)
    assert out[True][0] < np.log(total)
    assert not out[True][1] and out[False][1]


@pytest.mark.parametrize("forced", ["miss", "death"])
def test_a_candidate_with_one_option_is_in_every_child_with_it(forced):
    """The kernel on hand-made options: candidates 0 and 1 share measurement 0 (four and three options), candidate
    2 gates nothing and has one option only (missed: a track with P_S 1; or dead). The sampler does not draw
    it; with enough samples every child is found: the 11 distinct assignments of 0 and 1, each child holding 2
    with its one option, and the normalisation constant (eq. 25) the enumeration's, 2's factor included."""
    ln = np.log
    l_death = np.array([[ln(0.1), ln(0.1), 0.0 if forced == "death" else -np.inf]])
    l_miss = np.array([[ln(0.2), ln(0.2), -np.inf if forced == "death" else ln(0.3)]])
    l_det = np.array([[[ln(2.0), ln(0.5)], [ln(1.0), -np.inf], [-np.inf, -np.inf]]])
    opts = [[(-1, 0.1), (0, 0.2), (1, 2.0), (2, 0.5)], [(-1, 0.1), (0, 0.2), (1, 1.0)]]
    total = sum(w0 * w1 for (a0, w0), (a1, w1) in itertools.product(*opts) if a0 <= 0 or a0 != a1)
    total *= 1.0 if forced == "death" else 0.3
    out = joint_update(
        np.array([5]), np.zeros((1, 1)), np.ones((1, 1, 3), bool), np.array([[0, 1, 2]]), np.array([3]), l_death, l_miss, l_det,
        2000, 0.0, 1000, np.zeros((1, 3), bool), np.zeros((1, 3)), np.array([[10, 11, 12]]),
    )
    loglik, _, hyp_count, _, mem_count, mem_slot, _, slot_src, slot_a = out
    assert hyp_count[0] == 11
    assert loglik[0] == pytest.approx(ln(total), abs=1e-12)
    held_2 = [int(np.sum(slot_src[mem_slot[a:b]] == 2)) for a, b in itertools.pairwise(np.concatenate([[0], np.cumsum(mem_count)]))]
    assert held_2 == [0 if forced == "death" else 1] * 11
    assert np.all(slot_a[slot_src == 2] == 0)


def test_particles_that_agree_draw_the_same_children():
    """Two particles at one pose with maps {A, B} and {A, B, C}, C a track in view that gates no measurement
    (P_S 1: it can only be missed). The uniforms of the Gibbs draws are keyed by label, so C's presence
    does not shift the other candidates' draws: both particles draw the same children, and their
    log-likelihoods differ by C's miss, log(1 - P_D), to rounding, at 30 samples, where the sampled
    normalisation constant still misses mass (a stream of draws shared in order would give C one of them)."""
    fm = RangeBearing(R)
    z = _meas(fm)
    c = np.array([2.0, -1.5])
    mu = np.stack([np.stack([MU["A"], MU["B"], np.zeros(2)]), np.stack([MU["A"], MU["B"], c])])
    cov = np.stack([np.stack([COV["A"], COV["B"], np.eye(2)]), np.stack([COV["A"], COV["B"], np.eye(2) * 0.05**2])])
    tr = Tracks(mu, cov, np.array([[LAB["A"], LAB["B"], -1], [LAB["A"], LAB["B"], 11]]))
    member = np.array([[[True, True, False]], [[True, True, True]]])
    births = Births(np.tile(MU["b"], (2, 1, 1)), np.tile(COV["b"], (2, 1, 1, 1)), np.full((2, 1), RB), np.array([LAB["b"]]))
    state = GLMBMaps(tr, np.zeros((2, 1)), member, Tracks.empty(2, 2), np.zeros((2, 0)), births)
    cfg = GLMBConfig(samples=30, merge=0.0, release_unseen=False, factor_independent=False, prune=1e-15, max_hypotheses=100_000, survival=1.0)
    _, full = _enumerate(fm, z, [(1.0, [("A", 1.0, 1.0), ("B", 1.0, 1.0), ("b", RB, 1.0)])])
    for seed in range(5):
        mf = GLMB(fm, _det(), cfg, rng=np.random.default_rng(seed))
        _, ll = mf.update(state, np.tile(POSE, (2, 1)), Measurements(z))
        assert ll[1] - ll[0] == pytest.approx(np.log(1.0 - PD), abs=1e-12)
        assert np.log(full) - ll[0] > 0.0  # 30 samples leave mass undrawn: the draws matter


def test_lmb_gives_an_idle_birth_its_exact_existence():
    """The LMB filter with the far birth summed out of the sampler: that birth's track has its exact existence
    r_B (1 - P_D) / (1 - r_B P_D) and its birth density, as when it is sampled (to within the mass not drawn),
    and the other labels' existences are those of the sampled update."""
    fm = RangeBearing(R)
    z = _meas(fm)
    st = _far_birth_state(fm)
    r = {}
    for summed in (True, False):
        cfg = LMBConfig(samples=20000, survival=PS, prune_tracks=1e-12, sum_idle_births=summed)
        mf = LMB(fm, _det(), cfg, rng=np.random.default_rng(1))
        maps, _ = mf.update(LMBMaps(st.tracks, np.array([[0.9, 0.4]]), st.births), POSE[None], Measurements(z))
        r[summed] = {int(lab): (float(x), maps.tracks.mu[0, k]) for k, (lab, x) in enumerate(zip(maps.tracks.label[0], maps.r[0], strict=True)) if lab >= 0}
    far = (1 << 20) + 1
    assert r[True][far][0] == pytest.approx(RB * (1 - PD) / (1 - RB * PD), rel=1e-12)
    np.testing.assert_allclose(r[True][far][1], FAR, atol=1e-12)
    assert r[False][far][0] == pytest.approx(r[True][far][0], abs=1e-4)
    for lab in (LAB["A"], LAB["B"], LAB["b"]):
        assert r[True][lab][0] == pytest.approx(r[False][lab][0], abs=2e-3)


def test_a_likely_birth_is_sampled_not_held():
    """A far birth of probability 0.9 is likelier to exist (missed: 0.9 x 0.2) than not (0.1): it is not held
    absent but sampled, and exists with its exact probability 0.18 / 0.28 in the delta-GLMB's children."""
    fm = RangeBearing(R)
    z = _meas(fm)
    st = _far_birth_state(fm)
    st.births.r[0, 1] = 0.9
    cfg = GLMBConfig(samples=20000, merge=0.0, release_unseen=False, factor_independent=False, prune=1e-15, max_hypotheses=100_000, survival=PS)
    maps, _ = GLMB(fm, _det(), cfg, rng=np.random.default_rng(3)).update(st, POSE[None], Measurements(z))
    w = np.exp(maps.logw[0])
    holds = maps.member[0][:, maps.tracks.label[0] == (1 << 20) + 1].any(axis=1)
    assert w[np.isfinite(maps.logw[0]) & holds].sum() == pytest.approx(0.9 * (1 - PD) / (0.1 + 0.9 * (1 - PD)), abs=1e-3)


def _reduce(mu, hyps, merge=4.0, together=0.1, cov=0.01, release=True, labels=None, ident=None):
    """One particle whose slots (labels 1..n or ``labels``, means mu (n, 2), covariance cov I; identities ``ident``,
    none by default) are held by the hypotheses ``hyps`` [(weight, slot indices)], the slots released where
    ``release`` (one flag or one per slot); returns reduce_hypotheses' output."""
    n = len(mu)
    w = np.array([h[0] for h in hyps], dtype=np.float64)
    return reduce_hypotheses(
        np.array([n]), np.arange(1, n + 1, dtype=np.int64) if labels is None else np.asarray(labels, dtype=np.int64),
        np.asarray(mu, dtype=np.float64), np.tile(np.eye(2) * cov, (n, 1, 1)), np.broadcast_to(np.asarray(release, dtype=bool), (n,)).copy(),
        np.array([len(hyps)]), np.log(w / w.sum()), np.array([len(h[1]) for h in hyps], dtype=np.int64),
        np.array([s for h in hyps for s in h[1]], dtype=np.int64), merge, together, 1e-9, 100,
        np.full(n, -1, np.int64) if ident is None else np.asarray(ident, dtype=np.int64),
    )


def _release(mu, hyps, **kw):
    """Every slot released at once: the released (labels, existence, means)."""
    out = _reduce(mu, hyps, **kw)
    free_count, f_label, f_r, f_mu = out[9], out[10], out[11], out[12]
    assert free_count[0] == f_label.size
    return f_label, f_r, f_mu


def test_released_alternatives_of_one_landmark_leave_as_one():
    """Two labels at the same place that no hypothesis holds together (two births of one landmark, either of which
    the hypotheses took for it) leave the hypotheses as one Bernoulli: existence the weight of the hypotheses that
    hold either, density their moment match under the heavier's label. Released one by one, each has less than 1/2
    and the landmark drops out of every map estimate."""
    a, b, c = [0.0, 0.0], [0.05, 0.0], [5.0, 5.0]
    lab, r, mu = _release([a, b, c], [(0.6, [0, 2]), (0.35, [1, 2]), (0.05, [2])])
    assert lab.tolist() == [1, 3]  # A (with B merged in: the lighter), C (in every hypothesis)
    np.testing.assert_allclose(r, [0.95, 1.0], atol=1e-12)
    np.testing.assert_allclose(mu[0], [0.35 * 0.05 / 0.95, 0.0], atol=1e-12)
    # off: each label on its own, existence its marginal
    lab, r, _ = _release([a, b, c], [(0.6, [0, 2]), (0.35, [1, 2]), (0.05, [2])], together=0.0)
    np.testing.assert_allclose(sorted(r), [0.35, 0.6, 1.0], atol=1e-12)
    # rarely together: the existence is the union (0.97), not the sum of the marginals (0.99)
    _, r, _ = _release([a, b], [(0.6, [0]), (0.35, [1]), (0.02, [0, 1]), (0.03, [])])
    np.testing.assert_allclose(r, [0.97], atol=1e-12)


def test_released_labels_held_together_or_apart_stay_apart():
    """Two labels the hypotheses hold together (two landmarks close to each other), or two far apart, are released
    each with its own existence."""
    a, b = [0.0, 0.0], [0.05, 0.0]
    _, r, _ = _release([a, b], [(0.6, [0, 1]), (0.3, [0]), (0.1, [1])])
    np.testing.assert_allclose(sorted(r), [0.7, 0.9], atol=1e-12)
    _, r, _ = _release([a, [3.0, 0.0]], [(0.6, [0]), (0.4, [1])])  # 30 sigma apart
    np.testing.assert_allclose(sorted(r), [0.4, 0.6], atol=1e-12)


def test_independent_candidates_are_updated_exactly_outside_the_hypotheses():
    """Hypothesis {A, B}, the birth near the third measurement (which no other candidate gates, default gate) and
    the far birth of probability 0.9 (likelier present: not summed out). Factored out (``factor_independent``),
    the two births leave the sampler: each is one released track whose existence is the share of its options in
    which it exists and whose density is the moment match of its missed and detected versions. That is the
    joint update sampled with both in it, to within the mass not drawn: the same normalisation constant (the
    factored one above, by what the sampler leaves undrawn), the
    same existence of every label (the births' summed over the hypotheses that hold them), the same means."""
    fm = RangeBearing(R)
    z = _meas(fm)
    st = _far_birth_state(fm)
    st.births.r[0, 1] = 0.9
    got = {}
    for factor in (True, False):
        cfg = GLMBConfig(samples=20000, merge=0.0, release_unseen=False, factor_independent=factor, prune=1e-15, max_hypotheses=100_000, survival=PS)
        maps, ll = GLMB(fm, _det(), cfg, rng=np.random.default_rng(3)).update(st, POSE[None], Measurements(z))
        w = np.where(np.isfinite(maps.logw[0]), np.exp(maps.logw[0]), 0.0)
        ex, mean = {}, {}
        for k, lab in enumerate(maps.tracks.label[0]):
            if lab >= 0:
                wk = w @ maps.member[0][:, k]
                ex[int(lab)] = ex.get(int(lab), 0.0) + wk
                mean[int(lab)] = mean.get(int(lab), 0.0) + wk * maps.tracks.mu[0, k]
        mean = {lab: m / ex[lab] for lab, m in mean.items()}
        for k, lab in enumerate(maps.free.label[0]):
            if lab >= 0:
                ex[int(lab)], mean[int(lab)] = float(maps.free_r[0, k]), maps.free.mu[0, k]
        got[factor] = ll[0], ex, mean, set(maps.free.label[0][maps.free.label[0] >= 0].tolist())
    assert got[True][3] == {LAB["b"], (1 << 20) + 1} and not got[False][3]  # the births were released, or not
    assert 0.0 <= got[True][0] - got[False][0] < 5e-4  # the sampled constant is a lower bound; factored, it misses less
    assert got[True][1].keys() == got[False][1].keys()
    for lab, r in got[False][1].items():
        assert got[True][1][lab] == pytest.approx(r, abs=1e-3)
        np.testing.assert_allclose(got[True][2][lab], got[False][2][lab], atol=1e-3)
    assert got[True][1][(1 << 20) + 1] == pytest.approx(0.9 * (1 - PD) / (0.1 + 0.9 * (1 - PD)), rel=1e-12)  # far birth: no detection
    # a gate that takes every measurement: both births share them with A and B and stay in the sampler
    cfg = GLMBConfig(samples=2000, merge=0.0, release_unseen=False, prune=1e-15, max_hypotheses=100_000, survival=PS, gate=1e6)
    maps, _ = GLMB(fm, _det(), cfg, rng=np.random.default_rng(3)).update(st, POSE[None], Measurements(z))
    assert not (maps.free.label[0] >= 0).any()
    assert {LAB["b"], (1 << 20) + 1} <= set(maps.tracks.label[0].tolist())


def test_alternatives_in_the_hypotheses_become_one_track():
    """The same two alternatives kept in the hypotheses (in view): one track under the heavier's label, moment
    matched; the hypotheses that held either are one, of their summed weight."""
    out = _reduce([[0.0, 0.0], [0.05, 0.0], [5.0, 5.0]], [(0.6, [0, 2]), (0.35, [1, 2]), (0.05, [2])], release=False)
    slot_count, label, mu, hyp_count, hyp_logw, mem_count = out[1], out[2], out[3], out[5], out[6], out[7]
    assert slot_count[0] == 2 and sorted(label.tolist()) == [1, 3] and hyp_count[0] == 2
    np.testing.assert_allclose(np.exp(hyp_logw), [0.95, 0.05], atol=1e-12)
    assert mem_count.tolist() == [2, 1]
    np.testing.assert_allclose(mu[label == 1][0], [0.35 * 0.05 / 0.95, 0.0], atol=1e-12)
    out = _reduce([[0.0, 0.0], [0.05, 0.0], [5.0, 5.0]], [(0.6, [0, 2]), (0.35, [1, 2]), (0.05, [2])], release=False, together=0.0)
    assert out[1][0] == 3 and out[5][0] == 3  # off: three tracks, three hypotheses


def test_alternatives_held_together_once_are_held_once():
    """A hypothesis that held both alternatives (3 % of the weight, below the 10 % allowed) holds the merged track
    once: the three hypotheses {A}, {B}, {A, B} become one of weight 1."""
    out = _reduce([[0.0, 0.0], [0.05, 0.0]], [(0.6, [0]), (0.37, [1]), (0.03, [0, 1])], release=False)
    assert out[1][0] == 1 and out[5][0] == 1 and out[7].tolist() == [1]
    np.testing.assert_allclose(np.exp(out[6]), [1.0], atol=1e-12)


def _held_slots(out):
    """Each hypothesis's slots (indices), one particle."""
    off = np.concatenate([[0], np.cumsum(out[7])])
    return [out[8][off[h] : off[h + 1]].tolist() for h in range(out[5][0])]


def _held_labels(out):
    """Each hypothesis's labels, one particle."""
    return [out[2][slots].tolist() for slots in _held_slots(out)]


def test_no_merge_that_would_give_a_hypothesis_one_label_twice():
    """Label 1 has two versions 1 m apart (missed, and updated with z) that do not merge; label 2 (a birth that took
    z) lies at the first and is held beside the second in 30 % of the weight: it is no alternative of label 1 (merged,
    that hypothesis would hold label 1 twice)."""
    out = _reduce([[0.0, 0.0], [1.0, 0.0], [0.05, 0.0]], [(0.5, [0]), (0.3, [1, 2]), (0.2, [1])], release=False, labels=[1, 1, 2])
    assert sorted(out[2].tolist()) == [1, 1, 2]
    for held in _held_labels(out):
        assert len(set(held)) == len(held)


def test_a_merged_alternative_held_beside_its_labels_other_version_leaves_that_hypothesis():
    """Label 1 has two versions 1 m apart that do not merge; label 2 lies at the first and is held beside the second
    in 2 % of the weight only, under the 10 % that alternatives may be held together, so it merges into label 1's
    first version. The hypothesis that held it beside the far version keeps that version alone (it held label 1
    twice before: two slots of one label, its existence summed to 1.02): {1 near + 2} of weight 0.78, {1 far} of
    0.22, each label once, label 1's existence 1. The same whichever hypothesis comes first."""
    mu = [[0.0, 0.0], [1.0, 0.0], [0.05, 0.0]]
    for hyps in ([(0.5, [0]), (0.02, [1, 2]), (0.2, [1]), (0.28, [2])], [(0.02, [1, 2]), (0.5, [0]), (0.2, [1]), (0.28, [2])]):
        out = _reduce(mu, hyps, release=False, labels=[1, 1, 2])
        assert out[2].tolist() == [1, 1] and out[5][0] == 2
        np.testing.assert_allclose(np.exp(out[6]), [0.78, 0.22], atol=1e-12)
        assert _held_slots(out) == [[0], [1]]
        np.testing.assert_allclose(out[3][1], [1.0, 0.0], atol=1e-12)


def test_alternatives_merged_under_two_versions_of_one_label():
    """Labels 2 and 3 lie at label 1's two versions (1 m apart) and merge into them. Held together in 1 % (under 10 %
    of label 2's 0.15), the hypothesis that held both keeps the group of label 1's heavier version: {0.4 + 0.14 +
    0.01, 0.26 + 0.19}. Held together in 25 % (all of their weight) they are two landmarks: label 2 merges (the
    first tested), label 3, held beside label 2's group under label 1, does not, and that hypothesis keeps two
    tracks (before, both merged and label 1's existence came to 1.25)."""
    mu = [[0.0, 0.0], [1.0, 0.0], [0.05, 0.0], [1.05, 0.0]]
    out = _reduce(mu, [(0.4, [0]), (0.26, [1]), (0.14, [2]), (0.19, [3]), (0.01, [2, 3])], release=False, labels=[1, 1, 2, 3])
    assert out[2].tolist() == [1, 1] and out[5][0] == 2 and out[7].tolist() == [1, 1]
    np.testing.assert_allclose(np.exp(out[6]), [0.55, 0.45], atol=1e-12)
    np.testing.assert_allclose(out[3][out[8][0]], [0.0, 0.0], atol=0.05)
    out = _reduce(mu, [(0.35, [0]), (0.30, [1]), (0.25, [2, 3]), (0.10, [])], release=False, labels=[1, 1, 2, 3])
    assert sorted(out[2].tolist()) == [1, 1, 3]
    np.testing.assert_allclose(np.exp(out[6]), [0.35, 0.30, 0.25, 0.10], atol=1e-12)
    assert sorted(len(h) for h in _held_labels(out)) == [0, 1, 1, 2]


def test_every_reduced_hypothesis_holds_a_label_once():
    """Random small particles (labels of one to three versions, hypotheses holding at most one version of each,
    positions that put some alternatives within the gate, some released), reduced with the 10 % and 30 %
    allowances: every hypothesis holds distinct labels and slots, no two hypotheses hold the same slots, the
    weights sum to 1 per particle, every slot is held, a released label is released once and not also kept, and a
    released existence is at most 1. (The reduction before this test gave a hypothesis one label twice in 27 of these 2,000 cases.)"""
    rng = np.random.default_rng(11)
    for case in range(2000):
        n_p = int(rng.integers(1, 4))
        counts, labels, mus, covs, rel, hc, lw, mc, ms = [], [], [], [], [], [], [], [], []
        for _ in range(n_p):
            versions = [(lab, v) for lab in range(1, int(rng.integers(2, 5)) + 1) for v in range(int(rng.integers(1, 4)))]
            counts.append(len(versions))
            released = {lab: bool(rng.random() < 0.2) for lab, _ in versions}
            for lab, _ in versions:
                labels.append(lab)
                mus.append(rng.choice([0.0, 1.0], size=2) + rng.normal(0.0, 0.03, 2))
                covs.append(np.eye(2) * rng.choice([0.01, 0.02]))
                rel.append(released[lab])
            by_label = {}
            for s, (lab, _) in enumerate(versions):
                by_label.setdefault(lab, []).append(s)
            nh = int(rng.integers(1, 13))
            w = rng.random(nh) + 1e-3
            for h in range(nh):
                held = [int(rng.choice(v)) for v in by_label.values() if rng.random() < 0.5]
                mc.append(len(held))
                ms.extend(held)
            hc.append(nh)
            lw.extend(np.log(w / w.sum()))
        out = reduce_hypotheses(
            np.array(counts), np.array(labels, dtype=np.int64), np.array(mus), np.array(covs), np.array(rel), np.array(hc),
            np.array(lw), np.array(mc, dtype=np.int64), np.array(ms, dtype=np.int64), 4.0, float(rng.choice([0.1, 0.3])), 1e-9, 100,
            np.full(len(labels), -1, np.int64),
        )
        slot_count, lab_o, hyp_count, hyp_logw, mem_count, mem_slot = out[1], out[2], out[5], out[6], out[7], out[8]
        free_count, f_label, f_r = out[9], out[10], out[11]
        h0 = m0 = s0 = f0 = 0
        for p in range(n_p):
            hyps = []
            for h in range(hyp_count[p]):
                slots = mem_slot[m0 : m0 + mem_count[h0 + h]]
                m0 += mem_count[h0 + h]
                held = lab_o[s0 + slots]
                assert len(set(held.tolist())) == held.size and len(set(slots.tolist())) == slots.size, case
                hyps.append(tuple(sorted(slots.tolist())))
            assert len(set(hyps)) == len(hyps), case
            assert {s for h in hyps for s in h} == set(range(slot_count[p])), case
            assert np.exp(hyp_logw[h0 : h0 + hyp_count[p]]).sum() == pytest.approx(1.0, abs=1e-9), case
            freed = f_label[f0 : f0 + free_count[p]]
            assert len(set(freed.tolist())) == freed.size and not set(freed.tolist()) & set(lab_o[s0 : s0 + slot_count[p]].tolist()), case
            assert (f_r[f0 : f0 + free_count[p]] <= 1.0).all(), case
            h0 += hyp_count[p]
            s0 += slot_count[p]
            f0 += free_count[p]


def test_a_released_track_and_a_kept_one_do_not_merge():
    """Alternatives merge only among released or among kept tracks: a released track beside a kept one at the same
    place stays released on its own, the kept one in the hypotheses."""
    out = _reduce([[0.0, 0.0], [0.05, 0.0]], [(0.6, [0]), (0.4, [1])], release=[True, False])
    assert out[2].tolist() == [2] and out[10].tolist() == [1]
    np.testing.assert_allclose(out[11], [0.6], atol=1e-12)


def test_reduction_of_several_particles_keeps_each_its_own():
    """Two particles in one call (flat offsets): each particle's alternatives merge within it, the same result as
    reducing each alone."""
    mu = np.array([[0.0, 0.0], [0.05, 0.0], [5.0, 5.0], [0.0, 0.0], [3.0, 0.0]])
    lab = np.array([1, 2, 3, 1, 2], dtype=np.int64)
    w = np.array([0.6, 0.35, 0.05, 0.7, 0.3])
    out = reduce_hypotheses(
        np.array([3, 2]), lab, mu, np.tile(np.eye(2) * 0.01, (5, 1, 1)), np.ones(5, dtype=bool), np.array([3, 2]), np.log(w),
        np.array([2, 2, 1, 1, 1]), np.array([0, 2, 1, 2, 2, 0, 1]), 4.0, 0.1, 1e-9, 100, np.full(5, -1, np.int64),
    )
    assert out[9].tolist() == [2, 2]
    np.testing.assert_allclose(out[11][:2], [0.95, 1.0], atol=1e-12)  # particle 0: A with B, C
    np.testing.assert_allclose(out[11][2:], [0.7, 0.3], atol=1e-12)  # particle 1: 3 m apart, two tracks
