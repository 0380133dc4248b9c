"""Lasers whose scans do not all share one beam layout (interlaced SICK scanners, ROBOTLASER1 lines).

The truth: a simulated park scanned at 0.5 degrees (361 beams) is turned into an
interlaced laser by giving even scans the even beams (181 from -90 degrees every
degree) and odd scans the odd beams (180 from -89.5 degrees): each scan is then
exactly what such a scanner would have measured of the same world, and each
scan's own layout is known.
"""

import dataclasses

import numpy as np
import pytest

from calib.calibrate import CalibrateConfig, calibrate, scan_sensor_poses
from calib.io.carmen import read_carmen
from calib.io.native import read_native, write_native
from calib.io.registry import read_log, write_log
from detectors.circle import detect_circles
from detectors.sensor_log import BeamGeometry, ScanBatch, SensorLog
from detectors.raytrace import count_unoccluded, expected_unoccluded
from profiles.errors import DataError
from tests.calib.io.test_carmen import odom, write
from tests.calib.io.test_native import assert_logs_equal
from tests.calib.test_calibrate import park


def interlace(log: SensorLog) -> SensorLog:
    s, sen = log.scans, log.sensor
    assert sen.n_beams == 361
    n = len(s)
    ranges = np.full((n, 181), np.nan, dtype=np.float32)
    ranges[0::2] = s.ranges[0::2, 0::2]
    ranges[1::2, :180] = s.ranges[1::2, 1::2]
    inc = 2 * sen.angle_increment
    geoms = (
        BeamGeometry(n_beams=180, angle_min=sen.angle_min + sen.angle_increment, angle_increment=inc),
        BeamGeometry(n_beams=181, angle_min=sen.angle_min, angle_increment=inc),
    )
    sensor = type(sen).model_validate({**sen.model_dump(), "n_beams": 181, "angle_min": None, "angle_increment": None, "geometries": geoms})
    which = np.where(np.arange(n) % 2 == 0, 1, 0)
    return dataclasses.replace(log, name=log.name + "_interlaced", sensor=sensor, scans=ScanBatch(s.stamp, ranges, None, None, which))


@pytest.fixture(scope="module")
def interlaced():
    return park(35, 1.0), interlace(park(35, 1.0))


def test_scan_angles_are_each_scans_own(interlaced):
    full, log = interlaced
    a = log.scan_angles()
    assert a.shape == (len(log.scans), 181)
    np.testing.assert_allclose(a[0], full.sensor.angles()[0::2])
    np.testing.assert_allclose(a[1, :180], full.sensor.angles()[1::2])
    assert np.isnan(a[1, 180]) and np.isnan(log.scan_angles(1)[180])
    with pytest.raises(DataError, match="use 2 beam geometries; take each scan's angles from the log"):
        log.sensor.angles()
    assert log.sensor.field_of_view == pytest.approx(np.pi)


def test_readings_past_a_scans_beams_are_refused(interlaced):
    _, log = interlaced
    bad = log.scans.ranges.copy()
    bad[1, 180] = 3.0  # scan 1 has 180 beams
    with pytest.raises(DataError, match=r"scans.ranges\[1\]: readings past the scan's 180 beams"):
        dataclasses.replace(log, scans=ScanBatch(log.scans.stamp, bad, None, None, log.scans.geometry))


def test_detection_and_n_p_per_scan_equal_each_layout_alone(interlaced):
    """Batched over scans of both layouts = every scan processed with its own angles only."""
    _, log = interlaced
    params = CalibrateConfig().detector
    rows = np.arange(40)
    det = detect_circles(log.scans.ranges[rows], log.scan_angles(rows), params)
    sp, _ = scan_sensor_poses(log, "reference")
    lm = log.landmarks
    n_p, n_exp = count_unoccluded(sp[rows], log.scan_angles(rows), log.scans.ranges[rows], lm.xy, lm.radius, range_sigma=0.02, range_max=80.0)
    for i in rows:
        b = log.sensor.geometries[log.scans.geometry[i]].n_beams
        ang = log.scan_angles(int(i))[:b]
        one = detect_circles(log.scans.ranges[i, :b], ang, params)
        mine = det.scan == i
        np.testing.assert_allclose(det.x[mine], one.x)
        np.testing.assert_array_equal(det.last[mine], one.last)
        assert det.last[mine].max(initial=0) < b
        p1, e1 = count_unoccluded(sp[i], ang, log.scans.ranges[i, :b], lm.xy, lm.radius, range_sigma=0.02, range_max=80.0)
        np.testing.assert_array_equal(n_p[i], p1[0])
        np.testing.assert_array_equal(n_exp[i], e1[0])
        # the filter's phase-averaged count takes a NaN-padded row as the scan's own beams
        padded = expected_unoccluded(sp[i : i + 1], log.scan_angles(int(i)), log.scans.ranges[i], lm.xy[None], 0.2, range_sigma=0.02)
        trimmed = expected_unoccluded(sp[i : i + 1], ang, log.scans.ranges[i, :b], lm.xy[None], 0.2, range_sigma=0.02)
        np.testing.assert_allclose(padded, trimmed)


def test_round_trips_keep_each_scans_layout(tmp_path, interlaced):
    _, log = interlaced
    write_native(log, tmp_path / "i.dlog")
    back = read_native(tmp_path / "i.dlog")
    assert_logs_equal(log, back)
    np.testing.assert_array_equal(back.scans.geometry, log.scans.geometry)
    write_log(log, tmp_path / "bag")
    assert_logs_equal(log, read_log(tmp_path / "bag"))


def even_beams(log: SensorLog) -> SensorLog:
    """The same park seen by a one-layout laser of the same resolution (every scan: the even beams)."""
    s, sen = log.scans, log.sensor
    sensor = type(sen).model_validate({**sen.model_dump(), "n_beams": 181, "angle_increment": 2 * sen.angle_increment})
    return dataclasses.replace(log, sensor=sensor, scans=ScanBatch(s.stamp, s.ranges[:, 0::2]))


def test_calibration_on_an_interlaced_laser(interlaced):
    """Interlaced scans calibrate like a one-layout laser of the same resolution.

    The reference sees the same trees with the even beams in every scan. If a
    scan were given another layout's angles, its returns would be placed half
    a beam (0.5 degrees: 9 cm at 10 m) off: detections would land farther from
    their trees than the reference's and fail the support test. So: as many
    true detections (within 15 %: odd scans sample the trees at other angles),
    the same distance to the true tree (median within 25 %), and P_D rising
    above 0.9.
    """
    full, log = interlaced
    cfg = CalibrateConfig()
    cfg.pd.min_count = 50
    cal = calibrate([log], cfg, name="interlaced", version="1.0.0")
    ref = calibrate([even_beams(full)], cfg, name="even", version="1.0.0")
    p = cal.profile
    assert p.sensor.geometries is not None and len(p.sensor.geometries) == 2
    assert max(p.pd.pd) > 0.9 and cal.summary["true_inside_ellipsoid"] > 0.98
    assert cal.summary["true_detections"] == pytest.approx(ref.summary["true_detections"], rel=0.15)
    d = cal.labelled.detections
    dr = ref.labelled.detections
    assert d.loc[d.landmark >= 0, "distance"].median() == pytest.approx(dr.loc[dr.landmark >= 0, "distance"].median(), rel=0.25)
    assert cal.labelled.pairs["n_expected"].mean() == pytest.approx(ref.labelled.pairs["n_expected"].mean(), rel=0.05)
    # and SLAM runs on it with each scan's own layout (detection and ray-traced P_D): over the first 80
    # scans its map of the trees is as good as the one-layout laser's (OSPA within 0.1), its path as close
    from slam_runtime.config import SlamConfig, override
    from slam_runtime.run import evaluate, run_slam

    cfg_s = override(SlamConfig(), particles=10)
    m = evaluate(log, run_slam(log, p, cfg_s, 0, max_frames=80))
    m_ref = evaluate(even_beams(full), run_slam(even_beams(full), ref.profile, cfg_s, 0, max_frames=80))
    assert m["map_ospa"] < m_ref["map_ospa"] + 0.1
    assert m["trajectory_rmse_vs_ground_truth_m"] < max(1.5 * m_ref["trajectory_rmse_vs_ground_truth_m"], 0.1)


def test_carmen_interlaced_flaser_and_robotlaser(tmp_path):
    from tests.calib.io.test_carmen import flaser

    lines = [odom(1.0), flaser(1.05, [1.0] * 181), flaser(1.15, [2.0] * 180), flaser(1.25, [3.0] * 181)]
    log = read_carmen(write(tmp_path, lines))
    assert [g.n_beams for g in log.sensor.geometries] == [180, 181] and log.scans.geometry.tolist() == [1, 0, 1]
    np.testing.assert_allclose(log.scan_angles(1)[[0, 179]], [-np.pi / 2, np.pi / 2 - np.pi / 180])
    np.testing.assert_allclose(log.scan_angles(0)[[0, 180]], [-np.pi / 2, np.pi / 2])

    def robotlaser(t, start, n):
        r = " ".join(["2.0"] * n)
        return f"ROBOTLASER1 0 {start} 3.14159 0.0174533 30.0 0.01 0 {n} {r} 0 0 0 0 1 2 0.3 0 0 0 0 0 {t} nohost {t}"

    log = read_carmen(write(tmp_path, [robotlaser(1.0, -1.5708, 181), robotlaser(1.1, -1.5664, 180), robotlaser(1.2, -1.5708, 181)], "r.clf"))
    assert [(g.n_beams, g.angle_min) for g in log.sensor.geometries] == [(180, -1.5664), (181, -1.5708)]
    assert log.scans.geometry.tolist() == [1, 0, 1] and np.isnan(log.scans.ranges[1, 180])
