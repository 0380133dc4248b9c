"""Occlusion between the features of a detection-level map (a trunk hides what stands behind it)."""

import numpy as np

from detectors.sensor_log import SensorModel
from detectors.model import DetectionModel, _wrap
from detectors.occlusion import occlusion_flags
from profiles.schema import ClutterParams, PdTable

LASER = SensorModel(n_beams=361, angle_min=-np.pi / 2, angle_increment=np.pi / 360, range_max=50.0, range_sigma=0.05)
TABLE = PdTable(covariate="range", edges=[0, 25, 50], pd=[0.8, 0.6])


def test_a_trunk_hides_the_feature_behind_it_and_flags_its_neighbour():
    m = DetectionModel(TABLE, ClutterParams(rate=1.0, volume=100.0), LASER, occluder_radius=0.5, buffer_sigmas=2.0)
    # sensor at the origin looking along +x; a mapped trunk at 10 m straight ahead
    mu = np.array([[[10.0, 0.0], [20.0, 0.0], [20.0, 0.6], [20.0, 3.0], [5.0, 0.0]]])
    cov = np.tile(np.diag([0.01, 0.04]), (1, 5, 1, 1))  # lateral std 0.2 m
    w = np.array([[1.0, 1.0, 1.0, 1.0, 0.2]])  # the 5 m one is not confirmed: it occludes nothing
    pd, buf = m.pd_features(np.zeros((1, 3)), mu, cov, None, w)
    # 20 m straight behind: hidden (half-width asin(0.5/10) = 0.05 rad); 0.6 m aside at 20 m is 0.030 rad off the trunk's
    # bearing, inside the half-width: hidden too; 3 m aside (0.149 rad) is seen; the trunk itself is seen
    np.testing.assert_array_equal(pd[0], [0.8, 0.0, 0.0, 0.8, 0.8])
    # 1.1 m aside at 20 m (0.055 rad): outside the half-width, within it plus 2 lateral sigmas (0.02 rad): buffer zone
    mu2 = np.array([[[10.0, 0.0], [20.0, 1.1]]])
    pd2, buf2 = m.pd_features(np.zeros((1, 3)), mu2, cov[:, :2], None, np.ones((1, 2)))
    assert pd2[0].tolist() == [0.8, 0.8] and buf2[0].tolist() == [False, True]


def _reference(r, b, occluder, in_v, half, margin, rad):
    """The pairwise test written with (P, J, J) arrays: k hides i when nearer by 2 radius and within k's half-width."""
    ahead = r[:, None, :] < r[:, :, None] - 2 * rad
    sep = np.abs(_wrap(b[:, :, None] - b[:, None, :]))
    cand = ahead & occluder[:, None, :]
    hidden = (cand & (sep < half[:, None, :])).any(axis=2) & in_v
    near = (cand & (sep < half[:, None, :] + margin[:, :, None])).any(axis=2) & in_v & ~hidden
    return hidden, near


def test_compiled_occlusion_matches_the_pairwise_form_on_random_maps():
    rng = np.random.default_rng(7)
    seen_hidden = seen_near = 0
    for _ in range(20):
        p, j = 4, int(rng.integers(2, 60))
        r = rng.uniform(1.0, 50.0, (p, j))
        b = rng.uniform(-np.pi, np.pi, (p, j))
        b[:, : j // 3] = np.pi  # bearings at the wrap point
        occluder = rng.random((p, j)) < 0.6
        in_v = rng.random((p, j)) < 0.8
        rad = 0.4
        half = np.arcsin(np.clip(rad / r, 0.0, 1.0)) * rng.uniform(1, 30)  # wide occluders, so that many pairs hit
        margin = rng.uniform(0.0, 0.2, (p, j))
        got = occlusion_flags(r, b, occluder, in_v, half, margin, rad)
        want = _reference(r, b, occluder, in_v, half, margin, rad)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])
        seen_hidden += int(want[0].sum())
        seen_near += int(want[1].sum())
    assert seen_hidden > 100 and seen_near > 10  # both outcomes were exercised

