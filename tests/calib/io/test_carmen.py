import bz2
import gzip
import lzma

import numpy as np
import pytest

from calib.io.carmen import read_carmen
from profiles.errors import DataError, UsageError
from tests.conftest import shared


def flaser(t: float, ranges, pose=(0.0, 0.0, 0.0)) -> str:
    r = " ".join(f"{x:.2f}" for x in ranges)
    p = " ".join(f"{x:.6f}" for x in pose)
    return f"FLASER {len(ranges)} {r} {p} {p} {t:.6f} nohost {t:.6f}"


def odom(t: float, x=0.0) -> str:
    return f"ODOM {x:.6f} 0.000000 0.000000 0.1 0.0 0.0 {t:.6f} nohost {t:.6f}"


def write(tmp_path, lines, name="t.clf"):
    p = tmp_path / name
    text = "\n".join(["# header", "PARAM robot_frontlaser_offset 0.1 nohost 0", *lines]) + "\n"
    if name.endswith(".gz"):
        p.write_bytes(gzip.compress(text.encode()))
    elif name.endswith(".bz2"):
        p.write_bytes(bz2.compress(text.encode()))
    elif name.endswith(".xz"):
        p.write_bytes(lzma.compress(text.encode()))
    else:
        p.write_text(text)
    return p


BASE = [odom(1.0), flaser(1.05, [1.0, 2.0, 81.83, 3.0]), odom(1.1, 0.1), flaser(1.15, [1.5, 81.83, 2.5, 3.5])]


@pytest.mark.parametrize("name", ["t.clf", "t.clf.gz", "t.clf.bz2", "t.clf.xz", "t.log.xz"])
def test_reads_plain_and_compressed(tmp_path, name):
    log = read_carmen(write(tmp_path, BASE, name), range_max=80.0)
    assert len(log.scans) == 2 and log.scans.n_beams == 4 and len(log.odometry) == 2
    assert log.scans.stamp[0] == 1_050_000_000  # exact decimal -> ns
    assert np.isnan(log.scans.ranges[0, 2]) and log.scans.ranges[0, 3] == np.float32(3.0)
    assert log.sensor.mount.x == pytest.approx(0.1)
    assert log.sensor.angle_increment == pytest.approx(np.pi / 4)  # even beam count: pi / n
    assert log.odometry.kind == "pose"


def test_saturated_reading_is_no_return_by_default(tmp_path):
    log = read_carmen(write(tmp_path, BASE))
    assert log.sensor.range_max == pytest.approx(81.83)
    assert np.isnan(log.scans.ranges).sum() == 2


@pytest.mark.parametrize(
    ("line", "match"),
    [
        ("FLASER 4 1.0 2.0 3.0 0 0 0 0 0 0 1.2 nohost 1.2", r"t.clf:7: FLASER declares 4 beams but has 14 fields"),
        (flaser(1.2, [1.0, 2.0, 3.0, 4.0]).replace("3.00", "nan"), r"t.clf:7: range reading: NaN value"),
        (flaser(1.2, [1.0, -2.0, 3.0, 4.0]), r"t.clf:7: range reading 2 is negative"),
        (flaser(1.2, [1.0, 2.0, 3.0, 4.0]).replace("3.00", "x3"), r"t.clf:7: range reading: 'x3' is not a number"),
        ("ODOM 0 0 0 1.2 nohost", r"t.clf:7: ODOM has 6 fields, expected 10"),
        ("FLASER abc", r"t.clf:7: FLASER beam count missing or not an integer"),
        (flaser(0.0, [1.0, 2.0, 3.0, 4.0]), r"t.clf:7: FLASER time goes backwards by 1.150000 s"),
    ],
)
def test_malformed_lines_name_file_and_line(tmp_path, line, match):
    with pytest.raises(DataError, match=match):
        read_carmen(write(tmp_path, [*BASE, line]))


def test_small_backsteps_are_resorted_and_strict_mode_refuses(tmp_path):
    p = write(tmp_path, [*BASE, flaser(1.12, [1.0, 2.0, 3.0, 4.0])])
    log = read_carmen(p)
    assert np.all(np.diff(log.scans.stamp) >= 0) and log.source["reordered"]["scan"] == 2
    with pytest.raises(DataError, match=r"t.clf:7: FLASER time goes backwards by 0.030000 s \(more than the tolerated 0 s\); --max-backstep"):
        read_carmen(p, max_backstep=0.0)


def test_stamps_collapsed_to_few_values_are_reported(tmp_path):
    # a "corrected" log rewritten by a SLAM tool: 40 scans sharing two stamps, 10,000 s apart
    lines = [flaser(1000.0 if k < 20 else 11000.0, [1.0, 2.0, 3.0, 4.0]) for k in range(40)]
    log = read_carmen(write(tmp_path, lines))
    assert log.source["collapsed_stamps"] == {"scan": {"distinct": 2, "records": 40}}
    assert "collapsed_stamps" not in read_carmen(write(tmp_path, BASE * 5, "u.clf")).source  # distinct stamps: nothing to say


def test_truncated_compressed_log(tmp_path):
    p = write(tmp_path, BASE * 50, "t.clf.bz2")
    p.write_bytes(p.read_bytes()[:-40])
    with pytest.raises(DataError, match="compressed stream is truncated or corrupt"):
        read_carmen(p)


def test_missing_file_and_empty_log(tmp_path):
    with pytest.raises(UsageError, match="no such file"):
        read_carmen(tmp_path / "none.clf")
    with pytest.raises(DataError, match="no FLASER/ROBOTLASER1 or ODOM lines"):
        read_carmen(write(tmp_path, ["PARAM a b c d"]))


def test_robotlaser1_carries_its_geometry(tmp_path):
    n = 5
    ranges = " ".join(["2.0"] * n)
    line = f"ROBOTLASER1 0 -1.0 2.0 0.5 30.0 0.01 0 {n} {ranges} 0 0 0 0 1 2 0.3 0 0 0 0 0 1.5 nohost 1.5"
    log = read_carmen(write(tmp_path, [line]))
    assert log.sensor.angle_min == -1.0 and log.sensor.angle_increment == 0.5 and log.scans.n_beams == 5
    np.testing.assert_allclose(log.scans.odom_pose[0], [1, 2, 0.3])


@pytest.mark.parametrize(("name", "scans", "odom"), [("intel", 13631, 26915), ("aces", 7374, 7375)])
def test_real_radish_logs(name, scans, odom):
    log = read_carmen(shared(f"radish/{name}.clf.bz2"))
    assert len(log.scans) == scans and log.scans.n_beams == 180 and len(log.odometry) == odom
    assert np.all(np.diff(log.scans.stamp) >= 0)


def test_odom_lines_stamped_0_are_placed_by_their_order(tmp_path):
    """SLAM tools write ODOM lines stamped 0: each takes the time of its place in the file."""
    zero = [odom(0.0, 0.1), odom(0.0, 0.2)]
    lines = [flaser(100.0, [1.0] * 4), *zero, flaser(100.3, [1.0] * 4), odom(0.0, 0.3), flaser(100.4, [1.0] * 4)]
    log = read_carmen(write(tmp_path, lines))
    assert log.source["untimed"] == {"odometry": 3}
    # lines 4 and 5 lie a third and two thirds of the way from line 3 (100.0 s) to line 6 (100.3 s)
    np.testing.assert_array_equal(log.odometry.stamp, [100_100_000_000, 100_200_000_000, 100_350_000_000])
    np.testing.assert_allclose(log.odometry.values[:, 0], [0.1, 0.2, 0.3])
    span = log.time_span()
    assert (span[1] - span[0]) / 1e9 == pytest.approx(0.4)  # not 1e11 s from the epoch


def test_a_clock_that_starts_at_0_is_real_time(tmp_path):
    log = read_carmen(write(tmp_path, [odom(0.0), flaser(0.05, [1.0] * 4), odom(0.1, 0.1)]))
    assert "untimed" not in log.source and log.odometry.stamp.tolist() == [0, 100_000_000]


def test_time_order_error_names_the_first_offending_line(tmp_path):
    lines = [*BASE, flaser(0.5, [1.0] * 4), flaser(1.3, [1.0] * 4), flaser(0.0, [1.0] * 4)]
    with pytest.raises(DataError, match=r"t.clf:7: FLASER time goes backwards by 0.650000 s"):
        read_carmen(write(tmp_path, lines), max_backstep=0.5)


@pytest.mark.parametrize(
    ("stamp", "match"),
    [("1e300", r"t.clf:7: timestamp '1e300' is out of range"), ("nan", r"t.clf:7: timestamp 'nan' is not a number"),
     ("1_000.5", r"t.clf:7: timestamp '1_000.5' is not a number"), ("99999999999.0", r"t.clf:7: timestamp '99999999999.0' is out of range")],
)  # fmt: skip
def test_timestamps_out_of_range(tmp_path, stamp, match):
    line = flaser(1.2, [1.0] * 4).replace("1.200000", stamp, 1)
    with pytest.raises(DataError, match=match):
        read_carmen(write(tmp_path, [*BASE, line]))


@pytest.mark.parametrize("name", ["t.clf.xz", "t.log.gz", "t.carmen.bz2"])
def test_compressed_logs_are_recognised_without_format(tmp_path, name):
    """The format comes from the name for every compression the reader opens (a .clf.xz was refused without --format)."""
    from calib.io.registry import detect_format, read_log

    p = write(tmp_path, BASE, name)
    assert detect_format(p) == "carmen"
    assert len(read_log(p).scans) == 2
