"""Identities a detector reads (a barcode naming its landmark): RB-PHD explains a measurement only by a feature born
of the same identity, or by clutter; merging keeps identities apart; runs take them when asked and refuse when not
possible."""

import numpy as np
import pytest

from detectors.external import LoggedDetections
from profiles.errors import UsageError
from slam_runtime.config import SlamConfig
from slam_runtime.gm import GMBatch, prune_merge
from slam_runtime.mapfilter import Measurements
from slam_runtime.rbphd import PHDMaps
from slam_runtime.run import uses_identities
from tests.slam_runtime.test_rbphd import model, phd


def test_merging_joins_only_components_of_one_identity():
    """Two coincident components merge without identities and with equal ones (the heavier's identity kept); with
    different identities they stay two."""
    mu = np.array([[[5.0, 1.0], [5.01, 1.0]]])
    cov = np.tile(np.eye(2) * 0.01, (1, 2, 1, 1))
    w = np.array([[0.4, 0.7]])
    plain, _ = prune_merge(GMBatch(w, mu, cov))
    assert plain.shape[1] == 1 and plain.ident is None
    same, _ = prune_merge(GMBatch(w, mu, cov, np.array([[6, 6]])))
    assert same.shape[1] == 1 and same.ident[0, 0] == 6 and same.w[0, 0] == pytest.approx(1.1)
    apart, _ = prune_merge(GMBatch(w, mu, cov, np.array([[6, 7]])))
    assert apart.shape[1] == 2
    assert dict(zip(apart.ident[0].tolist(), apart.w[0].tolist())) == pytest.approx({6: 0.4, 7: 0.7})


def _static(mf, lms, ids, steps, rng, with_ids=True):
    """A static sensor at the origin seeing ``lms`` every step (P_D 1), identities ``ids``, 0.3 m / 0.03 rad noise and no
    clutter; returns the final maps."""
    fm = mf.feature
    maps = mf.empty(1)
    for _ in range(steps):
        z, _ = fm.predict(np.zeros(3), lms)
        z = z + rng.normal(0, 1, z.shape) * [0.3, 0.03]
        maps, ll = mf.update(maps, np.zeros((1, 3)), Measurements(z, ident=np.asarray(ids) if with_ids else None))
        assert np.isfinite(ll).all()
    return maps


def test_two_landmarks_inside_each_others_gate_are_told_apart_by_their_identities():
    """Two landmarks 0.4 m apart at 10 m, measured with 0.3 m / 0.03 rad noise (the pair lies well inside one gate):
    with their identities each gets one feature of weight ~1, of its identity, within 0.15 m (the mean of 40 looks
    has ~0.05 m / 0.05 m spread); without them the two landmarks' measurements blur into each other's features
    (the identities are what tells them apart: the estimate is farther from the truth)."""
    lms = np.array([[10.0, -0.2], [10.0, 0.2]])
    ids = [6, 7]
    err = {}
    for with_ids in (True, False):
        mf = phd(model(rate=0.01, pd=0.99, buffer=False), sr=0.3, sb=0.03, weighting="empty_set", merge_rule="mutual")
        maps = _static(mf, lms, ids, 40, np.random.default_rng(3), with_ids)
        xy, w = mf.estimate(maps, 0)
        d = np.linalg.norm(xy[:, None, :] - lms[None], axis=2)
        err[with_ids] = d.min(axis=0).max() if len(xy) else np.inf
        if with_ids:
            keep = maps.gm.w[0] >= 0.5
            assert sorted(maps.gm.ident[0][keep].tolist()) == ids
            assert np.all(np.abs(w - 1.0) < 0.2)
            assert np.argmin(d, axis=1).tolist() == [ids.index(i) for i in maps.gm.ident[0][keep]]
    assert err[True] < 0.15
    assert err[False] > err[True]


def test_a_misread_identity_does_not_update_another_landmark_or_move_the_pose():
    """A feature of identity 6 mapped 10 m ahead; a measurement at that very place reading identity 7 (a misread) is
    not the feature's: its weight is only missed ((1 - P_D) w), the proposal keeps the motion prior, and the measurement
    gives birth to a feature of identity 7. Read as 6 it updates the feature and the proposal uses it."""
    mf = phd(model(rate=0.5, pd=0.9, buffer=False), sr=0.05, sb=0.005)
    lm = np.array([[[10.0, 0.0]]])
    maps = PHDMaps(GMBatch(np.array([[1.0]]), lm, np.array([[np.eye(2) * 1e-4]]), np.array([[6]])), GMBatch.empty(1, 0, 2, ident=True))
    z, _ = mf.feature.predict(np.zeros(3), lm[0])
    xbar = np.array([[0.0, 0.0, 0.03]])
    q = np.diag([0.01**2, 0.01**2, 0.03**2])[None]
    for read, used_expected in ((7, 0), (6, 1)):
        meas = Measurements(z, ident=np.array([read]))
        mean, _, used = mf.pose_proposal(maps, xbar, q, meas)
        assert used[0] == used_expected
        if not used_expected:
            assert np.array_equal(mean, xbar)
        upd, _ = mf.update(maps, np.zeros((1, 3)), meas)
        own = upd.gm.ident[0] == 6
        # missed: (1 - P_D) w = 0.1; detected: that plus the detection's share, ~1 against clutter (eq. 3.18)
        assert upd.gm.w[0][own].sum() == pytest.approx(0.1 if read == 7 else 1.1, abs=0.02)
        assert upd.birth.ident[0].tolist() == [read]


def test_a_mapped_identity_gives_no_second_birth():
    """An identity names one landmark. A feature of identity 6 (weight 1) mapped 10 m ahead; the robot, its heading lost,
    measures landmark 6 at 40 degrees off, outside every gate: the measurement is clutter to the map and gives birth
    to no second feature of identity 6, while a measurement of unmapped identity 7 beside it gives birth at the full
    weight. With half of landmark 6 mapped (weight 0.5), half the birth weight."""
    mf = phd(model(rate=0.5, pd=0.9, buffer=False), sr=0.05, sb=0.005)
    lm = np.array([[[10.0, 0.0]]])
    z = np.array([[10.0, np.radians(40.0)], [8.0, np.radians(-30.0)]])
    for mapped, want in ((1.0, 0.0), (0.5, 0.5), (0.0, 1.0)):
        maps = PHDMaps(GMBatch(np.array([[max(mapped, 1e-9)]]), lm, np.array([[np.eye(2) * 1e-4]]), np.array([[6]])), GMBatch.empty(1, 0, 2, ident=True))
        upd, _ = mf.update(maps, np.zeros((1, 3)), Measurements(z, ident=np.array([6, 7])))
        born = dict(zip(upd.birth.ident[0].tolist(), upd.birth.w[0].tolist()))
        assert born[7] == pytest.approx(mf.cfg.birth_weight)
        assert born[6] == pytest.approx(mf.cfg.birth_weight * want)
        assert upd.gm.w[0][upd.gm.ident[0] == 6].sum() == pytest.approx(0.1 * mapped)  # missed: (1 - P_D) w


def test_logged_detections_carry_the_identity_they_read():
    from tests.calib.camera import camera_log

    log = camera_log(1, n=200)
    src = LoggedDetections(log, identities=True)
    d = log.detections
    off = d.frame_slices()
    for f in range(5):
        rows = slice(off[f], off[f + 1])
        meas = src(type("F", (), {"rows": rows})())
        assert meas.ident.tolist() == np.asarray(d.descriptors["subject"])[rows].tolist()
    assert LoggedDetections(log).__call__(type("F", (), {"rows": slice(0, 3)})()).ident is None


class _MF:
    def __init__(self, takes):
        self.takes_identities, self.name = takes, "X"


def test_identities_setting_auto_on_off():
    def cfg(mode):
        return SlamConfig.model_validate({"detection": {"identities": mode}})

    assert uses_identities(cfg("auto"), True, _MF(True))
    assert not uses_identities(cfg("auto"), False, _MF(True))
    assert not uses_identities(cfg("auto"), True, _MF(False))
    assert not uses_identities(cfg("off"), True, _MF(True))
    assert uses_identities(cfg("on"), True, _MF(True))
    with pytest.raises(UsageError, match="name no landmark"):
        uses_identities(cfg("on"), False, _MF(True))
    with pytest.raises(UsageError, match="does not take identities"):
        uses_identities(cfg("on"), True, _MF(False))


def test_identities_on_off_from_yaml():
    """YAML reads a bare on / off as a boolean: the setting takes them for on and off."""
    import yaml

    assert SlamConfig.model_validate(yaml.safe_load("detection: {identities: off}")).detection.identities == "off"
    assert SlamConfig.model_validate(yaml.safe_load("detection: {identities: on}")).detection.identities == "on"


@pytest.mark.parametrize("kind", ["glmb", "lmb"])
def test_labelled_filters_keep_two_close_landmarks_apart_by_their_identities(kind):
    """The labelled filters on the two landmarks 0.4 m apart (0.3 m / 0.03 rad noise, P_D 0.9, a little clutter),
    four seeds: with identities each landmark ends as one track of its own identity within 0.15 m (a track's
    identity is that of the measurement it was born from, and it is assigned only measurements of that identity),
    and the larger of the two errors is smaller than without identities on average (the filters already keep the
    two tracks; the identities stop each from taking the other landmark's measurements)."""
    from slam_runtime.features import RangeBearing
    from slam_runtime.glmb import GLMB, GLMBConfig
    from slam_runtime.lmb import LMB, LMBConfig
    from tests.slam_runtime.test_glmb import model as lmodel

    cls, cfg_cls = (GLMB, GLMBConfig) if kind == "glmb" else (LMB, LMBConfig)
    lms = np.array([[10.0, -0.2], [10.0, 0.2]])
    ids = np.array([6, 7])
    err = {True: [], False: []}
    for seed in range(4):
        for use in (True, False):
            rng = np.random.default_rng(seed)
            mf = cls(RangeBearing(np.diag([0.3**2, 0.03**2])), lmodel(rate=0.2, pd=0.9, buffer=False), cfg_cls(survival=1.0), rng=np.random.default_rng(seed))
            maps = mf.empty(2)
            for _ in range(40):
                z, _ = mf.feature.predict(np.zeros(3), lms)
                seen = rng.uniform(size=2) < 0.9
                z = z[seen] + rng.normal(0, 1, (seen.sum(), 2)) * [0.3, 0.03]
                maps, ll = mf.update(maps, np.zeros((2, 3)), Measurements(z, ident=ids[seen] if use else None))
                assert np.isfinite(ll).all()
            label, x, _ = mf.labels(maps, 0)
            err[use].append(np.linalg.norm(x[:, None] - lms[None], axis=2).min(axis=0).max() if len(x) else np.inf)
            if use:
                got = mf._label_identity(label)
                assert x.shape[0] == 2 and sorted(got.tolist()) == [6, 7]
                for k, i in enumerate(ids):
                    assert np.linalg.norm(x[got == i][0] - lms[k]) < 0.15
    assert np.mean(err[True]) < np.mean(err[False])



def test_alternatives_of_two_identities_do_not_merge():
    """delta-GLMB's alternatives (two labels at one place that no hypothesis holds together) become one track only
    when they read one identity: two identities are two landmarks, however close."""
    from tests.slam_runtime.test_gibbs import _release

    a, b, c = [0.0, 0.0], [0.05, 0.0], [5.0, 5.0]
    hyps = [(0.6, [0, 2]), (0.35, [1, 2]), (0.05, [2])]
    lab, r, _ = _release([a, b, c], hyps, ident=[6, 6, 8])
    assert lab.tolist() == [1, 3] and r == pytest.approx([0.95, 1.0])
    lab, r, _ = _release([a, b, c], hyps, ident=[6, 7, 8])
    assert sorted(lab.tolist()) == [1, 2, 3] and sorted(r) == pytest.approx([0.35, 0.6, 1.0])


def test_a_label_reads_the_identity_of_its_own_birth_measurement():
    """Labels name (step, measurement): each reads that measurement's identity, a step without identities gives
    none (-1), a step begun again replaces its record; identities of the wrong length are refused."""
    from slam_runtime.features import RangeBearing
    from slam_runtime.labelled import LABEL_BITS
    from slam_runtime.lmb import LMB, LMBConfig
    from tests.slam_runtime.test_glmb import model as lmodel

    mf = LMB(RangeBearing(np.diag([0.1**2, 0.01**2])), lmodel(rate=0.5, pd=0.9, buffer=False), LMBConfig(), rng=np.random.default_rng(0))
    maps = mf.empty(1)
    z3 = np.array([[3.0, 0.1], [5.0, -0.2], [7.0, 0.3]])
    frames = [None, np.array([6, 7, 8]), None, np.array([11, 12, 13])]
    for ids in frames:
        maps, _ = mf.update(maps, np.zeros((1, 3)), Measurements(z3, ident=ids))
    lab = (np.arange(4)[:, None].astype(np.int64) << LABEL_BITS) + np.arange(3)[None, :]
    assert mf._label_identity(lab).tolist() == [[-1, -1, -1], [6, 7, 8], [-1, -1, -1], [11, 12, 13]]
    assert mf._label_identity(np.array([-1, (1 << LABEL_BITS) + 5, 9 << LABEL_BITS])).tolist() == [-1, -1, -1]
    mf._begin(np.zeros((1, 3)), Measurements(z3, ident=np.array([21, 22, 23])))  # step 4 begun twice
    mf._begin(np.zeros((1, 3)), Measurements(z3, ident=np.array([31, 32, 33])))
    assert mf._label_identity(lab[1:2] + (3 << LABEL_BITS)).tolist() == [[31, 32, 33]]
    with pytest.raises(UsageError, match="1 identities for 3 measurements"):
        mf.update(maps, np.zeros((1, 3)), Measurements(z3, ident=np.array([6])))


@pytest.mark.parametrize("weighting", ["marginal", "multi_feature", "single_feature"])
def test_a_feature_of_another_identity_does_not_raise_a_particles_weight(weighting):
    """Two particles at one pose, one measurement reading identity 7 where both maps hold a feature: particle A's is
    of identity 6, B's of identity 7. B's feature explains the measurement (a weight gain of about log(P_D g / kappa));
    A's cannot, so A is weighed as if its feature were missed and the measurement clutter: B ahead by several nats.
    P_D 0.3: A's missed feature keeps weight 0.7, still a map feature in the multi- and single-feature weights
    (eq. 3.13), whose likelihood of the measurement must count only for its own identity."""
    mf = phd(model(rate=0.5, pd=0.3, buffer=False), sr=0.05, sb=0.005, weighting=weighting)
    lm = np.array([10.0, 0.0])
    maps = PHDMaps(
        GMBatch(np.ones((2, 1)), np.broadcast_to(lm, (2, 1, 2)).copy(), np.broadcast_to(np.eye(2) * 1e-4, (2, 1, 2, 2)).copy(), np.array([[6], [7]])),
        GMBatch.empty(2, 0, 2, ident=True),
    )
    z, _ = mf.feature.predict(np.zeros(3), lm[None])
    _, ll = mf.update(maps, np.zeros((2, 3)), Measurements(z, ident=np.array([7])))
    assert ll[1] - ll[0] > 5.0


def test_the_labelled_proposal_associates_only_its_own_identity():
    """delta-GLMB with a confirmed track of identity 6 ten metres ahead (built from 10 frames of it): the pose
    proposal from a prior 0.03 rad off uses a measurement of it reading 6 and returns near the truth, and leaves
    one reading 7 (a misread) out, keeping the motion prior."""
    from slam_runtime.features import RangeBearing
    from slam_runtime.glmb import GLMB, GLMBConfig
    from tests.slam_runtime.test_glmb import model as lmodel

    mf = GLMB(RangeBearing(np.diag([0.05**2, 0.005**2])), lmodel(rate=0.5, pd=0.9, buffer=False), GLMBConfig(survival=1.0), rng=np.random.default_rng(1))
    lm = np.array([[10.0, 0.0]])
    z, _ = mf.feature.predict(np.zeros(3), lm)
    maps = mf.empty(1)
    for _ in range(10):
        maps, _ = mf.update(maps, np.zeros((1, 3)), Measurements(z, ident=np.array([6])))
    xbar, q = np.array([[0.0, 0.0, 0.03]]), np.diag([0.01**2, 0.01**2, 0.03**2])[None]
    mean, _, used = mf.pose_proposal(maps, xbar, q, Measurements(z, ident=np.array([6])))
    assert used[0] == 1 and abs(mean[0, 2]) < 0.006
    mean, _, used = mf.pose_proposal(maps, xbar, q, Measurements(z, ident=np.array([7])))
    assert used[0] == 0 and np.array_equal(mean, xbar)


def test_logged_detections_keep_the_identities_of_the_landmark_rows():
    """A log whose detections are labelled (UTIAS target: 1 landmark, 2 another robot): the filter's measurements are
    the landmark rows, and their identities are those rows' subjects, in order."""
    from detectors.sensor_log import Detections

    d = Detections(np.array([0, 10], np.int64), np.array([0, 0, 0, 1, 1]), np.array([1.0, 2.0, 3.0, 4.0, 5.0]), np.zeros(5),
                   {"subject": np.array([6, 1, 8, 9, 2]), "target": np.array([1, 2, 1, 1, 2])})
    log = type("Log", (), {"detections": d})()
    src = LoggedDetections(log, identities=True)
    off = d.frame_slices()
    got = [src(type("F", (), {"rows": slice(off[f], off[f + 1])})()) for f in range(2)]
    assert [g.z[:, 0].tolist() for g in got] == [[1.0, 3.0], [4.0]]
    assert [g.ident.tolist() for g in got] == [[6, 8], [9]]
