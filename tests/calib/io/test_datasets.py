"""Victoria Park, UTIAS MRCLAM and KITTI readers: vendored excerpts always, full logs when present."""

import shutil

import numpy as np
import pytest

from calib.io.kitti import read_kitti
from calib.io.registry import detect_format, read_log
from calib.io.utias import TARGET_LANDMARK, TARGET_ROBOT, read_utias
from calib.io.victoria import read_victoria
from profiles.errors import DataError, UsageError
from tests.conftest import VENDORED, shared


def test_victoria_excerpt_geometry_and_frames():
    log = read_victoria(VENDORED / "victoria_park")
    d = log.detections
    assert len(d) == 300 and d.n_frames == len(np.unique(np.loadtxt(VENDORED / "victoria_park/measurements.dat")[:, 0]))
    # laser bearing 0..pi with pi/2 ahead -> sensor frame, 0 ahead
    assert d.bearing[0] == pytest.approx(0.88575 - np.pi / 2)
    assert d.descriptors["diameter"][0] == pytest.approx(0.35404)
    assert log.odometry.kind == "ackermann" and len(log.odometry) == 400
    assert np.isnan(log.reference["gps"].poses[:, 2]).all()
    assert log.reference["gps"].point == (3.78, 0.5)  # the data set's GPS is compared with the laser's position
    assert log.vehicle.wheelbase == 2.83 and log.sensor.mount.x == 3.78 and log.sensor.mount.y == 0.5


def test_victoria_bad_rows(tmp_path):
    shutil.copytree(VENDORED / "victoria_park", tmp_path / "vp")
    m = tmp_path / "vp/measurements.dat"
    lines = m.read_text().splitlines()
    lines[9] = "   1.0  nan  0.5  0.3"
    m.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"measurements.dat:10: t range bearing diameter: NaN"):
        read_victoria(tmp_path / "vp")
    lines[9] = "   1.0  20.0  0.5"
    m.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"measurements.dat:10: t range bearing diameter: expected 4 columns, got 3"):
        read_victoria(tmp_path / "vp")
    lines[9] = lines[8]
    lines[199] = "   0.5  20.0  0.5  0.3"  # seconds earlier than the rows before
    m.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"measurements.dat:200: measurement time goes backwards"):
        read_victoria(tmp_path / "vp")
    (tmp_path / "vp/inputs.dat").unlink()
    with pytest.raises(UsageError, match=r"inputs.dat: missing"):
        read_victoria(tmp_path / "vp")


def test_utias_excerpt_tells_landmarks_from_robots():
    log = read_utias(VENDORED / "utias_dataset1", robot=1)
    d = log.detections
    code, subj, target = d.descriptors["barcode"], d.descriptors["subject"], d.descriptors["target"]
    robots = np.isin(code, [5, 14, 41, 32, 23])
    assert (target[robots] == TARGET_ROBOT).all() and (target[~robots] == TARGET_LANDMARK).all()
    assert subj[code == 90][0] == 16 and subj[code == 14][0] == 2
    assert len(log.landmarks) == 15 and set(log.landmarks.ids.tolist()) == set(range(6, 21))
    assert log.odometry.kind == "velocity" and log.reference["ground_truth"].poses.shape == (1500, 3)


def test_utias_robot_number_checked():
    with pytest.raises(UsageError, match=r"--robot: expected 1..5, got 7"):
        read_utias(VENDORED / "utias_dataset1", robot=7)
    with pytest.raises(UsageError, match=r"Robot2_Odometry.dat: missing"):
        read_utias(VENDORED / "utias_dataset1", robot=2)


def test_kitti_frames_and_truncation(tmp_path):
    pts = np.arange(40, dtype=np.float32).reshape(10, 4)
    pts.tofile(tmp_path / "000000.bin")
    (pts * 2).tofile(tmp_path / "000001.bin")
    log = read_kitti(tmp_path)
    assert len(log.clouds) == 2
    np.testing.assert_array_equal(log.clouds.frame(1), pts * 2)
    (tmp_path / "000002.bin").write_bytes(pts.tobytes()[:-6])
    with pytest.raises(DataError, match=r"000002.bin: size 154 bytes is not a multiple of 16"):
        read_kitti(tmp_path)


def test_point_clouds_written_as_kitti_frames_read_back_bit_for_bit(tmp_path):
    """`log convert --to kitti`: each frame's float32 points are the file's bytes, so reading them back gives the
    same points; the folder is only written through --to kitti (a folder name alone stays a ROS 2 bag)."""
    from calib.io.registry import output_format, write_log
    from tests.calib.io.test_native import full_log

    log = full_log()
    write_log(log, tmp_path / "velodyne", "kitti")
    assert sorted(p.name for p in (tmp_path / "velodyne").glob("*.bin")) == ["000000.bin", "000001.bin"]
    back = read_kitti(tmp_path / "velodyne")
    np.testing.assert_array_equal(back.clouds.offsets, log.clouds.offsets)
    np.testing.assert_array_equal(back.clouds.points, log.clouds.points)
    assert output_format(tmp_path / "x", None) == "ros2"
    with pytest.raises(UsageError, match="exists"):
        write_log(log, tmp_path / "velodyne", "kitti")


def test_kitti_frames_refused_for_logs_without_clouds_or_with_an_empty_frame(tmp_path, small_sim):
    import dataclasses

    from calib.io.kitti import write_kitti
    from detectors.sensor_log import PointClouds
    from tests.calib.io.test_native import full_log

    with pytest.raises(UsageError, match="has no point clouds to write as KITTI frames"):
        write_kitti(small_sim.log, tmp_path / "a")
    log = full_log()
    c = log.clouds
    empty = dataclasses.replace(log, clouds=PointClouds(c.stamp, np.array([0, 0, c.offsets[-1]]), c.points))
    with pytest.raises(DataError, match="frame 0 of .* has no points"):
        write_kitti(empty, tmp_path / "b")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_format_detection(tmp_path):
    assert detect_format(VENDORED / "victoria_park") == "victoria"
    assert detect_format(VENDORED / "utias_dataset1") == "utias"
    (tmp_path / "x.txt").write_text("hello")
    with pytest.raises(UsageError, match=r"cannot tell the log format from the path; pass --format"):
        detect_format(tmp_path / "x.txt")


def test_real_victoria_park_counts():
    log = read_log(shared("victoria_park"))
    assert (log.detections.n_frames, len(log.detections), len(log.odometry), len(log.reference["gps"])) == (7230, 52974, 61945, 4466)


def test_real_utias_counts_match_the_files():
    root = shared("utias_mrclam/dataset1")
    log = read_log(root, options=None)
    rows = {k: sum(1 for line in (root / f"Robot1_{k}.dat").read_text().splitlines() if line.strip()) for k in ("Odometry", "Measurement", "Groundtruth")}
    assert len(log.odometry) == rows["Odometry"] == 75000
    assert len(log.detections) == rows["Measurement"]
    assert len(log.reference["ground_truth"]) == rows["Groundtruth"]
    assert len(log.landmarks) == 15


def test_real_kitti_frames():
    log = read_kitti(shared("kitti_object/velodyne"))
    assert len(log.clouds) == 3 and 115_000 <= np.diff(log.clouds.offsets).min() and np.diff(log.clouds.offsets).max() <= 127_000
