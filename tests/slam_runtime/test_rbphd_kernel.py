"""The compiled RB-PHD update (slam_runtime.rbphd_kernel) against the numpy batch it stands in for, step by step
along a seeded run."""

import numpy as np
import pytest

from calib.sim.rfs import simulate_rfs, truth_profile
from profiles.parameters import RfsSimConfig
from slam_runtime.config import SlamConfig
from slam_runtime.rbphd import RBPHD
from slam_runtime.run import run_slam


@pytest.mark.parametrize("weighting", ["marginal", "multi_feature"])
def test_the_compiled_update_gives_the_numpy_batchs_numbers(monkeypatch, weighting):
    """At every step of a cluttered run (gated pairs, pruned pairs, the buffer zone at the range limits, births), the
    compiled update returns the batch's mixtures, births and particle log-likelihoods. Tolerance: the two sum the same
    terms in other orders (numpy's pairwise sums), a few ulps; 1e-9 relative is far below any effect on the run."""
    sc = RfsSimConfig(steps=120, clutter_intensity=0.02)
    log, prof = simulate_rfs(sc, 4), truth_profile(sc)
    update = RBPHD.update  # the compiled kernel when RBPHD.compiled, the numpy pairs otherwise
    steps = []

    def both(self, maps, poses, meas):
        monkeypatch.setattr(RBPHD, "compiled", False)
        ref_maps, ref_ll = update(self, maps, poses, meas)
        monkeypatch.setattr(RBPHD, "compiled", True)
        got_maps, got_ll = update(self, maps, poses, meas)
        np.testing.assert_allclose(got_ll, ref_ll, rtol=1e-9, atol=1e-9)
        for a, b in ((got_maps.gm, ref_maps.gm), (got_maps.birth, ref_maps.birth)):
            assert a.w.shape == b.w.shape
            for x, y in ((a.w, b.w), (a.mu, b.mu), (a.cov, b.cov)):
                np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-12)
        assert (got_maps.merged is None) == (ref_maps.merged is None)
        if ref_maps.merged is not None:
            np.testing.assert_array_equal(got_maps.merged, ref_maps.merged)
        steps.append(int(len(meas)))
        return ref_maps, ref_ll

    monkeypatch.setattr(RBPHD, "update", both)
    cfg = SlamConfig.model_validate({"particles": 6, "filter": {"kind": "rbphd", "weighting": weighting}})
    run_slam(log, prof, cfg, 0)
    assert len(steps) == sc.steps and sum(steps) > 1000  # every step checked, measurements and clutter among them
