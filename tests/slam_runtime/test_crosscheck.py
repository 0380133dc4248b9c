"""Cross-checks against independent implementations (test-only dependencies).

* One GM-PHD map update with constant P_D against Stone Soup's ``PHDUpdater``
  (Vo & Ma's equations, one Python loop per component and measurement).
  Stone Soup's conventions, accounted for here: its bearing-range model orders
  the measurement (bearing, range); its clutter density is per unit of that
  space, which is our kappa per m rad; components tagged "birth" lose their
  missed-detection copy, so none are tagged; survival is set to 1.
* OSPA against ``pytcl`` (the nrl-tracker package).
"""

import numpy as np
import pytest

from detectors.model import DetectionModel
from profiles.schema import ClutterParams, PdTable, SensorModel
from slam_runtime.features import RangeBearing
from slam_runtime.gm import GMBatch
from slam_runtime.mapfilter import Measurements
from slam_runtime.metrics import ospa
from slam_runtime.rbphd import RBPHD, PHDMaps, RBPHDConfig


def test_one_gm_phd_update_agrees_with_stone_soup():
    ss = pytest.importorskip("stonesoup", reason="Stone Soup is a test-only dependency (pip install '.[test]')")
    from datetime import datetime

    from stonesoup.models.measurement.nonlinear import CartesianToBearingRange
    from stonesoup.types.array import StateVector
    from stonesoup.types.detection import Detection, MissedDetection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.multihypothesis import MultipleHypothesis
    from stonesoup.types.state import TaggedWeightedGaussianState
    from stonesoup.updater.kalman import ExtendedKalmanUpdater
    from stonesoup.updater.pointprocess import PHDUpdater

    del ss
    rng = np.random.default_rng(4)
    sensor = SensorModel(kind="camera", fov=np.pi, range_max=30.0)
    rate, volume, pd = 2.0, 30.0 * np.pi, 0.8
    model = DetectionModel(
        PdTable(covariate="range", edges=[0.0, 30.0], pd=[pd]), ClutterParams(rate=rate, volume=volume), sensor, constant_pd=pd, buffer=False
    )
    sr, sb = 0.15, 0.02
    cfg = RBPHDConfig(prune=1e-300, merge=1e-12, cap=1000, weighting="empty_set", gate=1e300)
    pose = np.array([1.0, -2.0, 0.4])
    mf = RBPHD(RangeBearing(np.diag([sr**2, sb**2])), model, cfg)
    # a prior map in front of the sensor, and measurements near some of its components plus clutter
    j = 6
    mu = pose[:2] + np.column_stack([rng.uniform(4, 12, j), rng.uniform(-5, 5, j)])
    a = rng.normal(0, 0.3, (j, 2, 2))
    cov = a @ np.swapaxes(a, 1, 2) + np.eye(2) * 0.05
    w = rng.uniform(0.3, 1.2, j)
    prior = PHDMaps(GMBatch(w[None], mu[None], cov[None]), GMBatch.empty(1, 0))
    rel = mu[:4] - pose[:2]
    z = np.column_stack([np.hypot(rel[:, 0], rel[:, 1]), np.arctan2(rel[:, 1], rel[:, 0]) - pose[2]])
    z = np.vstack([z + rng.normal(0, 1, z.shape) * [sr, sb], [[7.0, 0.3], [10.0, -0.5]]])
    post, _ = mf.update(prior, pose[None], Measurements(z))
    ours = sorted(zip(post.gm.w[0], post.gm.mu[0].tolist(), post.gm.cov[0].tolist(), strict=True), key=lambda t: -t[0])

    t0 = datetime(2026, 1, 1)
    meas_model = CartesianToBearingRange(
        ndim_state=2, mapping=(0, 1), noise_covar=np.diag([sb**2, sr**2]),
        translation_offset=StateVector([pose[0], pose[1]]), rotation_offset=StateVector([0.0, 0.0, pose[2]]),
    )
    comps = [TaggedWeightedGaussianState(StateVector(m), c, weight=wt, tag=str(i), timestamp=t0) for i, (m, c, wt) in enumerate(zip(mu, cov, w, strict=True))]
    dets = [Detection(StateVector([b, r]), timestamp=t0, measurement_model=meas_model) for r, b in z]
    hyps = [MultipleHypothesis([SingleHypothesis(c, d) for c in comps]) for d in dets]
    hyps.append(MultipleHypothesis([SingleHypothesis(c, MissedDetection(timestamp=t0)) for c in comps]))
    upd = PHDUpdater(ExtendedKalmanUpdater(meas_model), clutter_spatial_density=rate / volume, prob_detection=pd, prob_survival=1.0)
    theirs = sorted(
        ((float(c.weight), np.asarray(c.mean, dtype=float).ravel().tolist(), np.asarray(c.covar, dtype=float).tolist()) for c in upd.update(hyps)),
        key=lambda t: -t[0],
    )
    # compare every component either side keeps above 1e-12 (Stone Soup floors zero weights at eps)
    ours = [t for t in ours if t[0] > 1e-12]
    theirs = [t for t in theirs if t[0] > 1e-12]
    assert len(ours) == len(theirs) >= j + 4
    for (w1, m1, c1), (w2, m2, c2) in zip(ours, theirs, strict=True):
        assert w1 == pytest.approx(w2, rel=1e-6, abs=1e-9)
        np.testing.assert_allclose(m1, m2, atol=1e-6)
        np.testing.assert_allclose(c1, c2, atol=1e-6)


@pytest.mark.parametrize("c,p", [(1.0, 1.0), (2.0, 2.0), (0.5, 1.0), (5.0, 3.0)])
def test_ospa_agrees_with_pytcl(c, p):
    pe = pytest.importorskip("pytcl.performance_evaluation", reason="pytcl (nrl-tracker) is a test-only dependency (pip install '.[test]')")
    rng = np.random.default_rng(int(c * 10 + p))
    for _ in range(25):
        x = rng.uniform(0, 6, (rng.integers(0, 9), 2))
        y = rng.uniform(0, 6, (rng.integers(0, 9), 2))
        ref = pe.ospa(list(x), list(y), c=c, p=p).ospa
        assert ospa(x, y, c, p) == pytest.approx(float(ref), rel=1e-9, abs=1e-12)
