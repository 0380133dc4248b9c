"""The C++ RFS-SLAM simulator's export folder (calib.io.rfsslam), written here from a seeded rfs-sim run in the
simulator's own layout, read back; and the stated odometry noise through the native format."""

import numpy as np
import pytest

from calib.io.native import read_native, write_native
from calib.io.registry import ReadOptions, read_log
from calib.io.rfsslam import read_rfsslam, scenario
from calib.sim.rfs import simulate_rfs
from profiles.errors import DataError, UsageError
from profiles.parameters import RfsSimConfig
from tests.data.rfsslam_export import SHIPPED, shipped_export, write_export

def export(tmp_path, log, steps, landmarks):
    """The simulator's files of a detcal rfs-sim log, in ``tmp_path/export``."""
    return write_export(tmp_path / "export", log, steps, landmarks)


@pytest.fixture()
def folder(tmp_path):
    sc = RfsSimConfig(steps=120, landmarks=10)
    log = simulate_rfs(sc, 2)
    return export(tmp_path, log, 120, 10), log, sc


def test_the_export_reads_as_the_log_it_came_from(folder):
    """Frames, detections (frame by frame, to the printed precision), odometry with its stated noise, truth and
    landmarks; the format is found from the folder; the configuration reads as the rfs-sim scenario's settings."""
    d, log, sc = folder
    got = read_log(d, None, ReadOptions())
    assert got.source["reader"] == "rfsslam"
    np.testing.assert_array_equal(got.frame_stamps(), log.frame_stamps())
    np.testing.assert_array_equal(got.detections.frame, log.detections.frame)
    np.testing.assert_allclose(got.detections.range, log.detections.range, atol=1e-6)
    np.testing.assert_allclose(got.odometry.values, log.odometry.values, atol=1e-6)
    np.testing.assert_allclose(got.reference["ground_truth"].poses, log.reference["ground_truth"].poses, atol=1e-6)
    np.testing.assert_allclose(got.landmarks.xy, log.landmarks.xy, atol=1e-6)
    assert got.odometry.sigma == pytest.approx(log.odometry.sigma)
    assert (got.sensor.range_min, got.sensor.range_max) == (0.5, 2.5)
    s = scenario(d)
    assert (s.steps, s.landmarks, s.pd, s.var_range, s.clutter_intensity) == (120, 10, sc.pd, sc.var_range, sc.clutter_intensity)


def test_a_missing_file_is_named(folder):
    d, _, _ = folder
    (d / "odometry.dat").unlink()
    with pytest.raises(UsageError, match=r"odometry.dat: missing"):
        read_rfsslam(d)


def test_a_broken_configuration_is_named(folder):
    d, _, _ = folder
    (d / "simSettings.xml").write_text("<config><timesteps>12</timesteps>")
    with pytest.raises(DataError, match=r"simSettings.xml: not readable XML"):
        read_rfsslam(d)


def test_a_setting_that_is_not_a_number_is_named(folder):
    d, _, _ = folder
    x = d / "simSettings.xml"
    x.write_text(x.read_text().replace("<varzr>0.0005</varzr>", "<varzr>much</varzr>"))
    with pytest.raises(DataError, match=r"config/measurements/varzr: expected a number"):
        read_rfsslam(d)


def test_a_measurement_between_steps_is_named(folder):
    d, _, _ = folder
    m = d / "measurement.dat"
    lines = m.read_text().splitlines()
    t, *rest = lines[3].split()
    lines[3] = " ".join([f"{float(t) + 0.05:f}", *rest])
    m.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"measurement.dat:4: t range bearing: time at no time step"):
        read_rfsslam(d)


def test_the_stated_odometry_noise_survives_the_native_format(tmp_path):
    log = simulate_rfs(RfsSimConfig(steps=80, landmarks=5), 1)
    assert log.odometry.sigma is not None
    p = write_native(log, tmp_path / "l.dlog")
    assert read_native(p).odometry.sigma == log.odometry.sigma


def test_the_shipped_export_is_the_one_its_script_writes(tmp_path):
    """tests/data/rfsslam-sim (read by the log-format how-to) is rebuilt by its script to the same bytes."""
    d = shipped_export(tmp_path / "again")
    for f in sorted(SHIPPED.iterdir()):
        assert (d / f.name).read_bytes() == f.read_bytes(), f.name
    assert sorted(p.name for p in d.iterdir()) == sorted(p.name for p in SHIPPED.iterdir())
