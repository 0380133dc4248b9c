import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from calib.io.registry import read_log, write_log
from calib.io.rosbag import read_rosbag
from profiles.errors import DataError, UsageError
from tests.calib.io.test_native import assert_logs_equal
from tests.conftest import shared


def _header(T, ros1, stamp, frame):
    t = T["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9)
    if ros1:
        return T["std_msgs/msg/Header"](seq=0, stamp=t, frame_id=frame)
    return T["std_msgs/msg/Header"](stamp=t, frame_id=frame)


def scan_msg(T, ros1, stamp, ranges):
    return T["sensor_msgs/msg/LaserScan"](
        header=_header(T, ros1, stamp, "laser"),
        angle_min=-1.0,
        angle_max=1.0,
        angle_increment=0.5,
        time_increment=0.0,
        scan_time=0.0,
        range_min=0.1,
        range_max=20.0,
        ranges=np.asarray(ranges, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )


def odom_msg(T, ros1, stamp, x, yaw):
    v3 = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    pose = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=x, y=2.0, z=0.0),
        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=np.sin(yaw / 2), w=np.cos(yaw / 2)),
    )
    return T["nav_msgs/msg/Odometry"](
        header=_header(T, ros1, stamp, "odom"),
        child_frame_id="base",
        pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=T["geometry_msgs/msg/Twist"](linear=v3, angular=v3), covariance=np.zeros(36)),
    )


SCANS = [[1.0, np.nan, np.inf, 30.0, 2.0], [1.5, 0.05, 3.0, 4.0, 5.0], [2.0, 2.0, 2.0, 2.0, 2.0]]


def write_bag(path, ros1: bool, scans=SCANS, extra_scan_topic=False, stamps=(10**9, 2 * 10**9, 3 * 10**9)):
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = ts.types
    ser = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    writer = Writer1(path) if ros1 else Writer2(path, version=9)
    with writer:
        cs = writer.add_connection("/front/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        co = writer.add_connection("/wheel/odom", "nav_msgs/msg/Odometry", typestore=ts)
        cx = writer.add_connection("/rear/scan", "sensor_msgs/msg/LaserScan", typestore=ts) if extra_scan_topic else None
        for k, (st, r) in enumerate(zip(stamps, scans, strict=True)):
            rec = (k + 1) * 10**9  # record time in order; the header stamps are what the reader checks
            writer.write(co, rec - 1000, ser(odom_msg(T, ros1, st - 1000, 0.5 * k, 0.3 * k), "nav_msgs/msg/Odometry"))
            writer.write(cs, rec, ser(scan_msg(T, ros1, st, r), "sensor_msgs/msg/LaserScan"))
            if cx is not None:
                writer.write(cx, rec, ser(scan_msg(T, ros1, st, r), "sensor_msgs/msg/LaserScan"))
    return path


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2"])
def test_reads_bags_written_by_rosbags(tmp_path, ros1):
    p = write_bag(tmp_path / ("a.bag" if ros1 else "a"), ros1)
    log = read_log(p)
    assert len(log.scans) == 3 and log.scans.n_beams == 5 and len(log.odometry) == 3
    assert log.sensor.angle_increment == 0.5 and log.sensor.range_max == 20.0
    # REP 117: NaN, inf and readings outside [range_min, range_max] are no returns
    assert np.isnan(log.scans.ranges[0, [1, 2, 3]]).all() and np.isnan(log.scans.ranges[1, 1])
    np.testing.assert_allclose(log.odometry.values[:, 2], [0.0, 0.3, 0.6], atol=1e-12)
    assert log.scans.stamp.tolist() == [10**9, 2 * 10**9, 3 * 10**9]


def test_unknown_topic_lists_what_the_bag_has(tmp_path):
    p = write_bag(tmp_path / "a.bag", True)
    with pytest.raises(UsageError, match=r"unknown scan topic '/scan'; the bag has: /front/scan \(sensor_msgs/msg/LaserScan\)"):
        read_rosbag(p, scan_topic="/scan")
    with pytest.raises(UsageError, match=r"topic '/wheel/odom' is nav_msgs/msg/Odometry, expected sensor_msgs/msg/LaserScan"):
        read_rosbag(p, scan_topic="/wheel/odom")


def test_several_scan_topics_need_a_choice(tmp_path):
    p = write_bag(tmp_path / "a.bag", True, extra_scan_topic=True)
    with pytest.raises(UsageError, match=r"several scan topics \(/front/scan, /rear/scan\); choose one with --scan-topic"):
        read_rosbag(p)
    assert len(read_rosbag(p, scan_topic="/rear/scan").scans) == 3


def test_bad_scans_in_bags(tmp_path):
    bad = [SCANS[0], [1.0, -2.0, 1.0, 1.0, 1.0], SCANS[2]]
    with pytest.raises(DataError, match=r"/front/scan message 1 beam 1: negative range"):
        read_rosbag(write_bag(tmp_path / "neg.bag", True, scans=bad))
    with pytest.raises(DataError, match=r"/front/scan message time goes backwards by 5.000000 s"):
        read_rosbag(write_bag(tmp_path / "back.bag", True, stamps=(10 * 10**9, 5 * 10**9, 11 * 10**9)))


def test_scans_of_several_beam_layouts(tmp_path):
    """A laser whose messages differ in beam count: each scan keeps its own layout, through ROS 2 and back."""
    mixed = [SCANS[0], [1.0, 1.5, 2.5], SCANS[2]]
    log = read_rosbag(write_bag(tmp_path / "beams.bag", True, scans=mixed))
    assert [g.n_beams for g in log.sensor.geometries] == [3, 5] and log.scans.geometry.tolist() == [1, 0, 1]
    assert log.scans.n_beams == 5 and np.isnan(log.scans.ranges[1, 3:]).all()
    np.testing.assert_allclose(log.scan_angles(1), [-1.0, -0.5, 0.0, np.nan, np.nan])
    write_log(log, tmp_path / "bag")
    back = read_log(tmp_path / "bag")
    assert_logs_equal(log, back)
    # the standard /scan topic carries each scan with its own beams, for ROS tools
    again = read_rosbag(tmp_path / "bag", scan_topic="/scan", odom_topic="/odom")
    assert again.sensor.geometries == log.sensor.geometries and again.scans.geometry.tolist() == [1, 0, 1]


def test_damaged_bag_is_a_data_error(tmp_path):
    p = write_bag(tmp_path / "a.bag", True)
    (tmp_path / "cut.bag").write_bytes(p.read_bytes()[:300])
    with pytest.raises(DataError, match=r"cut.bag: "):
        read_rosbag(tmp_path / "cut.bag")


def test_native_to_ros2_to_native_is_lossless_on_a_simulated_log(tmp_path, small_sim):
    log = small_sim.log
    write_log(log, tmp_path / "bag")
    back = read_log(tmp_path / "bag")
    assert_logs_equal(log, back)
    write_log(back, tmp_path / "back.dlog")
    assert_logs_equal(log, read_log(tmp_path / "back.dlog"))


def test_a_written_bag_read_as_a_foreign_one_gives_the_scans_odometry_and_truth(tmp_path, small_sim):
    """The standard topics alone (/scan, /odom, /ground_truth, as ROS tools see them) carry the log: the park's
    odometry increments come back as the running pose whose relative motions are those increments, and the truth
    as the simulator's poses. Tolerances: LaserScan ranges are float32 (relative 1e-7 of up to 80 m); a pose goes
    through a float64 quaternion, so its yaw comes back within 1e-12 rad."""
    from detectors.geometry import relative

    log = small_sim.log
    assert log.odometry.kind == "increment"
    write_log(log, tmp_path / "bag")
    back = read_rosbag(tmp_path / "bag", scan_topic="/scan", odom_topic="/odom", truth_topic="/ground_truth")
    np.testing.assert_allclose(back.scans.ranges, log.scans.ranges, rtol=1e-6, atol=1e-5)
    assert back.odometry.kind == "pose"
    np.testing.assert_array_equal(back.odometry.stamp, log.odometry.stamp)
    steps = relative(back.odometry.values[:-1], back.odometry.values[1:])
    np.testing.assert_allclose(steps, log.odometry.values[1:], atol=1e-9)
    truth = log.reference["ground_truth"]
    np.testing.assert_array_equal(back.reference["ground_truth"].stamp, truth.stamp)
    np.testing.assert_allclose(back.reference["ground_truth"].poses, truth.poses, atol=1e-9)


def test_ros2_bag_metadata_names_only_the_final_folder(tmp_path, small_sim):
    """The bag is written under its final name inside a temporary folder: no temporary name leaks into it."""
    write_log(small_sim.log, tmp_path / "mybag")
    meta = (tmp_path / "mybag/metadata.yaml").read_text()
    assert "mybag.db3" in meta and ".part" not in meta
    assert sorted(p.name for p in (tmp_path / "mybag").iterdir()) == [".detcal-output", "metadata.yaml", "mybag.db3"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mybag"]


def test_ros2_round_trip_of_detection_logs(tmp_path):
    from tests.calib.io.test_native import full_log

    log = full_log()
    object.__setattr__(log, "clouds", None)  # point clouds do not go into bags
    write_log(log, tmp_path / "bag")
    assert_logs_equal(log, read_log(tmp_path / "bag"))


def test_point_clouds_refused_for_bags(tmp_path):
    from tests.calib.io.test_native import full_log

    with pytest.raises(UsageError, match="writing point clouds to a ROS 2 bag is not supported"):
        write_log(full_log(), tmp_path / "bag")
    assert not (tmp_path / "bag").exists()


def test_real_victoria_park_through_ros2(tmp_path):
    log = read_log(shared("victoria_park"))
    write_log(log, tmp_path / "vp")
    assert_logs_equal(log, read_log(tmp_path / "vp"))


def test_a_message_deleted_from_a_bag_is_counted_with_its_gap(tmp_path, capsys):
    """A scan row deleted from a ROS 2 bag's database: the index still lists it; the reader keeps the rest, records
    what is missing and the command warns with the gap it leaves (it was read as one scan fewer, silently)."""
    import sqlite3

    from detcal.cli import main

    stamps = tuple(k * 10**8 for k in range(1, 11))  # 10 Hz
    bag = write_bag(tmp_path / "b", False, scans=[[1.0] * 5] * 10, stamps=stamps)
    db = next(bag.glob("*.db3"))
    with sqlite3.connect(db) as c:
        tid = c.execute("SELECT id FROM topics WHERE name = '/front/scan'").fetchone()[0]
        c.execute("DELETE FROM messages WHERE topic_id = ? AND timestamp = (SELECT timestamp FROM messages WHERE topic_id = ? "
                  "ORDER BY timestamp LIMIT 1 OFFSET 4)", (tid, tid))  # fmt: skip
    log = read_rosbag(bag)
    assert len(log.scans) == 9
    missing = log.source["missing"]["/front/scan"]
    # stamps 0.1 .. 1.0 s without 0.5 s: the longest step 0.2 s, from 0.4 s (0.3 s after the first), median 0.1 s
    assert (missing["declared"], missing["found"]) == (10, 9)
    assert missing["longest_s"] == pytest.approx(0.2) and missing["after_s"] == pytest.approx(0.3) and missing["median_s"] == pytest.approx(0.1)
    assert main(["log", "info", str(bag)]) == 0
    err = capsys.readouterr().err
    assert "topic /front/scan holds 9 of the 10 messages the bag's index lists; the longest gap is 0.2 s, 0.3 s into the log" in err
    # a whole bag says nothing of the kind
    whole = read_rosbag(write_bag(tmp_path / "w", False))
    assert "missing" not in whole.source
