import numpy as np
import pytest
from scipy.stats import chi2

from detectors.sensor_log import SensorModel
from detectors.model import DetectionModel, fov_volume
from profiles.errors import DataError
from profiles.schema import ClutterParams, HotellingParams, PdTable

SENSOR = SensorModel(n_beams=361, angle_min=-np.pi / 2, angle_increment=np.pi / 360, range_max=80.0, range_sigma=0.02)
TABLE = PdTable(edges=[0, 1, 2, 3, 4, 5, 6, 7], pd=[0.0, 0.0, 0.0, 0.36, 0.76, 0.89, 0.9])
H = HotellingParams(
    names=["fit_error", "radius", "convexity"],
    mean=[0.001, 0.2, 0.15],
    covariance=[[1e-6, 0.0, 0.0], [0.0, 0.01, 0.004], [0.0, 0.004, 0.005]],
    gamma=float(chi2.ppf(0.999, 3)),
)


def model(**kw):
    clutter = ClutterParams(rate=6.18, volume=fov_volume(SENSOR))
    return DetectionModel(TABLE, clutter, SENSOR, hotelling=H, **kw)


def test_pd_table_lookup_and_clamping_semantics():
    assert TABLE.lookup(np.array([-1, 0, 2, 3, 6, 50])).tolist() == [0.0, 0.0, 0.0, 0.36, 0.9, 0.9]
    with pytest.raises(ValueError, match="pd has 2 entries for 3 bins"):
        PdTable(edges=[0, 1, 2, 3], pd=[0.1, 0.2])


def test_pd_of_landmarks_through_n_p():
    m = model()
    meas = np.full(361, np.nan)
    pd, buf = m.pd_landmarks(np.zeros(3), meas, np.array([[3.0, 0.0], [60.0, 0.0], [-5.0, 0.0]]), 0.2)
    assert pd[0] == pytest.approx(0.9) and pd[1] == 0.0 and pd[2] == 0.0  # close; far; behind the sensor
    assert not buf.any()


def test_clutter_intensity_integrates_to_the_rate():
    m = model()
    rng = np.random.default_rng(0)
    z = np.column_stack([rng.uniform(0, 100, 200_000), rng.uniform(-np.pi, np.pi, 200_000)])
    box = 100 * 2 * np.pi
    integral = m.clutter_intensity(z).mean() * box
    assert integral == pytest.approx(6.18, rel=0.01)  # Monte Carlo s.e. ~0.4 %
    assert m.clutter_intensity(np.array([[10.0, 2.0]]))[0] == 0.0  # outside the 180 deg field of view


def test_descriptor_likelihoods_integrate_to_one_over_the_ellipsoid():
    m = model()
    rng = np.random.default_rng(1)
    cov = np.asarray(H.covariance)
    # sample the bounding box of the ellipsoid and integrate both densities
    half = np.sqrt(np.diag(cov) * H.gamma)
    lo, hi = np.asarray(H.mean) - half, np.asarray(H.mean) + half
    x = rng.uniform(lo, hi, (400_000, 3))
    vol = np.prod(hi - lo)
    assert m.g_true(x).mean() * vol == pytest.approx(1.0, rel=0.02)
    assert m.g_false(x).mean() * vol == pytest.approx(1.0, rel=0.02)
    far = np.array([[1.0, 5.0, 5.0]])
    assert m.g_true(far)[0] == 0.0 and m.g_false(far)[0] == 0.0


def test_model_needs_what_its_table_needs():
    with pytest.raises(DataError, match="needs the sensor's range_sigma"):
        DetectionModel(TABLE, ClutterParams(rate=1.0, volume=1.0), SensorModel(n_beams=3, angle_min=0, angle_increment=0.1, range_max=5))
    m = DetectionModel(TABLE, ClutterParams(rate=1.0, volume=1.0), SENSOR)
    with pytest.raises(DataError, match="no Hotelling model"):
        m.g_true(np.zeros((1, 3)))


def test_model_from_the_bundled_profile():
    from profiles.store import resolve

    m = DetectionModel.from_profile(resolve("sim-park-laser@1.0.0"))
    assert m.clutter.kappa == pytest.approx(m.clutter.rate / fov_volume(m.sensor))
    pd, _ = m.pd_landmarks(np.zeros(3), np.full(361, np.nan), np.array([[4.0, 0.0]]), 0.3)
    assert pd[0] > 0.9
    assert m.g_true(np.asarray([m.hotelling.mean]))[0] > m.g_false(np.asarray([m.hotelling.mean]))[0]


CAMERA = SensorModel(kind="camera", fov=np.deg2rad(60), range_max=6.0)


def test_pd_at_for_a_range_table_and_a_range_bearing_grid():
    rt = PdTable(covariate="range", edges=[0, 2, 4, 6], pd=[0.8, 0.5, 0.2])
    m = DetectionModel(rt, ClutterParams(rate=1.0, volume=6.0), CAMERA)
    z = np.array([[1.0, 0.0], [3.0, 0.4], [5.0, -0.4], [5.0, 0.6], [6.5, 0.0]])
    assert m.pd_at(z).tolist() == [0.8, 0.5, 0.2, 0.0, 0.0]  # 0.6 rad is outside 30 deg; 6.5 m beyond range_max
    grid = PdTable(covariate="range_bearing", edges=[0, 3, 6], bearing_edges=[-0.5, 0.0, 0.5], pd=[[0.1, 0.2], [0.3, 0.4]])
    g = DetectionModel(grid, ClutterParams(rate=1.0, volume=6.0), SensorModel(kind="camera", fov=1.0, range_max=6.0))
    zz = np.array([[[1.0, -0.2], [1.0, 0.2]], [[4.0, -0.2], [4.0, 0.2]]])  # (2, 2, 2): any leading shape
    np.testing.assert_array_equal(g.pd_at(zz), [[0.1, 0.2], [0.3, 0.4]])
    assert g.pd_at(np.array([4.0, 0.51])) == 0.0  # beyond the field of view (the grid spans it)
    with pytest.raises(DataError, match=r"P_D of a n_p table needs the scan \(pd_points\)"):
        model().pd_at(z)
    with pytest.raises(DataError, match=r"z must have shape \(..., 2\)"):
        m.pd_at(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="pd has shape \\(2, 3\\) for a 2x2 table"):
        PdTable(covariate="range_bearing", edges=[0, 3, 6], bearing_edges=[-0.5, 0.0, 0.5], pd=[[0.1, 0.2, 0.3], [0.3, 0.4, 0.5]])


def test_pd_points_buffer_band_at_the_edges_of_the_field_of_view():
    """A 90 deg camera to 10 m, measured noise 0.1 m / 0.01 rad: the band is 2 sigma of that noise
    combined with the feature's own spread, at the range limit and at both bearing edges."""
    from profiles.schema import MeasurementNoise

    sensor = SensorModel(kind="camera", fov=np.pi / 2, range_max=10.0)
    noise = MeasurementNoise(range_sigma=0.1, bearing_sigma=0.01)
    m = DetectionModel(PdTable(covariate="range", edges=[0.0, 5.0, 10.0], pd=[0.8, 0.4]), ClutterParams(rate=1.0, volume=1.0), sensor, noise=noise)
    ang = np.array([0.0, 0.0, 0.0, np.pi / 4 - 0.015, np.pi / 4 + 0.015, -np.pi / 4 + 0.05, 0.0])
    rng_ = np.array([3.0, 9.85, 10.15, 6.0, 6.0, 6.0, 10.3])
    mu = np.column_stack([rng_ * np.cos(ang), rng_ * np.sin(ang)])[None]
    cov = np.tile(np.eye(2) * 1e-6, (1, len(ang), 1, 1))
    pd, buf = m.pd_points(np.zeros((1, 3)), mu, cov)
    np.testing.assert_array_equal(buf[0], [False, True, True, True, True, False, False])
    np.testing.assert_allclose(pd[0], [0.8, 0.4, 0.4, 0.4, 0.4, 0.4, 0.0])
    # a feature known only to 0.2 m along the line of sight widens the band: 10.3 m is then within it
    wide = cov.copy()
    wide[0, -1] = np.eye(2) * 0.04
    _, buf = m.pd_points(np.zeros((1, 3)), mu, wide)
    assert buf[0, -1]
    const = DetectionModel(m.pd_table, m.clutter, sensor, noise=noise, constant_pd=0.9, buffer=False)
    pd, buf = const.pd_points(np.zeros((1, 3)), mu, cov)
    np.testing.assert_allclose(pd[0], [0.9, 0.9, 0.0, 0.9, 0.0, 0.9, 0.0])
    assert not buf.any()


def test_pd_points_of_a_range_bearing_grid_keep_the_edge_cells_value_in_the_band():
    """A grid is reached through pd_points as through pd_at; a feature just beyond a bearing edge,
    within the buffer band, gets the edge cell's P_D (so a detection can still update it)."""
    grid = PdTable(covariate="range_bearing", edges=[0, 3, 6], bearing_edges=[-0.5, 0.0, 0.5], pd=[[0.1, 0.2], [0.3, 0.4]])
    sensor = SensorModel(kind="camera", fov=1.0, range_max=6.0)
    from profiles.schema import MeasurementNoise

    g = DetectionModel(grid, ClutterParams(rate=1.0, volume=6.0), sensor, noise=MeasurementNoise(range_sigma=0.05, bearing_sigma=0.01))
    ang = np.array([-0.2, 0.2, 0.51, 0.7])
    mu = np.column_stack([4.0 * np.cos(ang), 4.0 * np.sin(ang)])[None]
    pd, buf = g.pd_points(np.zeros((1, 3)), mu, np.tile(np.eye(2) * 1e-6, (1, 4, 1, 1)))
    np.testing.assert_allclose(pd[0], [0.3, 0.4, 0.4, 0.0])
    np.testing.assert_array_equal(buf[0], [False, False, True, False])


def test_the_occlusion_tolerance_at_run_time():
    """detection.occlusion_sigmas replaces the profile's k_sigma in the filter's ray tracer (default: the profile's).
    A landmark 4 m ahead whose beams return 5 range sigmas short of its surface (a bush's front, say, before a
    trunk-sized circle): occluded with the calibration's 3 sigmas (P_D 0), seen with 6."""
    from profiles.store import resolve
    from slam_runtime.config import DetectionOptions, detection_model

    prof = resolve("sim-park-laser@1.0.0")
    m3 = detection_model(prof, DetectionOptions(buffer_zone=False))
    m6 = detection_model(prof, DetectionOptions(buffer_zone=False, occlusion_sigmas=6.0))
    assert m3.k_sigma == prof.detector.k_sigma == 3.0 and m6.k_sigma == 6.0
    sig = float(prof.sensor.range_sigma)
    scan = np.full(prof.sensor.n_beams, np.nan)
    ang = prof.sensor.angles()
    ahead = np.abs(ang) < 0.2
    scan[ahead] = 4.0 - 0.3 - 5 * sig  # the surface of a 0.3 m circle at 4 m, less 5 sigmas
    pd3, _ = m3.pd_landmarks(np.zeros(3), scan, np.array([[4.0, 0.0]]), 0.3)
    pd6, _ = m6.pd_landmarks(np.zeros(3), scan, np.array([[4.0, 0.0]]), 0.3)
    assert pd3[0] == 0.0 and pd6[0] > 0.9


def test_an_infinite_occlusion_tolerance_turns_the_test_off():
    """occlusion_sigmas: .inf (from YAML) hides nothing: a landmark behind a wall 1 m in front of it gets the P_D of
    the beams it would get with no wall, on the integer-count and the filter's (phase-averaged) paths, without a
    floating-point warning (an infinite tolerance minus an infinite expected range would be NaN)."""
    import warnings

    import yaml

    from profiles.store import resolve
    from slam_runtime.config import DetectionOptions, detection_model

    prof = resolve("sim-park-laser@1.0.0")
    opts = yaml.safe_load("{buffer_zone: false, occlusion_sigmas: .inf}")
    off = detection_model(prof, DetectionOptions(**opts))
    on = detection_model(prof, DetectionOptions(buffer_zone=False))
    ang = prof.sensor.angles()
    wall = np.where(np.abs(ang) < 0.3, 3.0, np.nan)  # returns 1 m in front of a landmark at 4 m
    free = np.full(ang.size, np.nan)
    centre = np.array([[4.0, 0.0]])
    cov = np.diag([0.01, 0.01])[None, None]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pd_wall, _ = off.pd_landmarks(np.zeros(3), wall, centre, 0.3)
        pd_free, _ = off.pd_landmarks(np.zeros(3), free, centre, 0.3)
        pts_wall, _ = off.pd_points(np.zeros((1, 3)), centre[None], cov, wall, ang)
        pts_free, _ = off.pd_points(np.zeros((1, 3)), centre[None], cov, free, ang)
    assert pd_wall[0] == pd_free[0] > 0.9 and pts_wall[0, 0] == pts_free[0, 0] > 0.9
    assert on.pd_landmarks(np.zeros(3), wall, centre, 0.3)[0][0] == 0.0
    assert on.pd_points(np.zeros((1, 3)), centre[None], cov, wall, ang)[0][0, 0] == 0.0


def test_the_occlusion_tolerance_defaults_per_filter(small_sim):
    """With no detection.occlusion_sigmas, RB-PHD takes the profile's tolerance and the labelled filters none
    (MapFilter.occlusion_default); 'profile' and a number are taken as given by every filter. Checked on the model the
    run's factory (slam_runtime.run.build) gives each filter for a park log."""
    import pydantic
    import yaml

    from profiles.store import resolve
    from slam_runtime.config import DetectionOptions, SlamConfig, with_settings
    from slam_runtime.run import build

    prof = resolve("sim-park-laser@1.0.0")
    got = {}
    for kind in ("rbphd", "lmb", "glmb"):
        for occ in (None, "profile", 6.0):
            cfg = with_settings(SlamConfig(), {"filter.kind": kind, "detection.occlusion_sigmas": occ})
            got[kind, occ] = build(small_sim.log, prof, cfg).mapfilter.detection.k_sigma
    assert got["rbphd", None] == got["rbphd", "profile"] == got["lmb", "profile"] == got["glmb", "profile"] == prof.detector.k_sigma == 3.0
    assert got["lmb", None] == got["glmb", None] == np.inf
    assert all(got[k, 6.0] == 6.0 for k in ("rbphd", "lmb", "glmb"))
    # 'profile' from YAML; a misspelt word, a tolerance of 0 or below, NaN or a boolean refused with one message
    assert DetectionOptions(**yaml.safe_load("{occlusion_sigmas: profile}")).occlusion_sigmas == "profile"
    for bad in ("profiel", 0.0, -1, float("nan"), True):
        with pytest.raises(pydantic.ValidationError, match=r"occlusion_sigmas\n.*above 0, \.inf or 'profile', not "):
            DetectionOptions(occlusion_sigmas=bad)
