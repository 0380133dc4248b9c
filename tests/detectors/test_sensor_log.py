import numpy as np
import pytest

from detectors.sensor_log import (
    Detections,
    Landmarks,
    Odometry,
    ReferencePoses,
    ScanBatch,
    SensorLog,
    SensorModel,
    wrap_angle,
)
from profiles.errors import DataError


def _sensor(n=4):
    return SensorModel(n_beams=n, angle_min=-0.5, angle_increment=1 / 3, range_max=10.0)


def test_wrap_angle_is_half_open_at_minus_pi():
    out = wrap_angle(np.array([np.pi, -np.pi, 3 * np.pi, 0.1 - 2 * np.pi]))
    np.testing.assert_allclose(out, [np.pi, np.pi, np.pi, 0.1], atol=1e-12)


def test_scan_time_backwards_names_index():
    with pytest.raises(DataError, match=r"scans.stamp\[2\]: time goes backwards"):
        ScanBatch(np.array([0, 10, 5]), np.zeros((3, 4)))


def test_negative_and_infinite_ranges_refused():
    r = np.ones((2, 4), np.float32)
    r[1, 2] = -1
    with pytest.raises(DataError, match=r"scans.ranges\[1\]: negative range"):
        ScanBatch(np.array([0, 1]), r)
    r[1, 2] = np.inf
    with pytest.raises(DataError, match="infinite range"):
        ScanBatch(np.array([0, 1]), r)


def test_beam_count_must_match_sensor():
    scans = ScanBatch(np.array([0, 1]), np.ones((2, 5)))
    with pytest.raises(DataError, match="5 beams per scan but the sensor model declares n_beams=4"):
        SensorLog("x", sensor=_sensor(4), scans=scans)


def test_odometry_kind_and_columns_checked():
    with pytest.raises(DataError, match="odometry.kind"):
        Odometry("wheels", np.array([0]), np.zeros((1, 2)))
    with pytest.raises(DataError, match=r"odometry.values: expected shape \(1, 2\)"):
        Odometry("velocity", np.array([0]), np.zeros((1, 3)))
    with pytest.raises(DataError, match=r"odometry.values\[0\]: not a finite number"):
        Odometry("velocity", np.array([0]), np.array([[np.nan, 0.0]]))


def test_landmark_ids_unique_and_reference_source():
    with pytest.raises(DataError, match="not unique"):
        Landmarks(np.array([1, 1]), np.zeros((2, 2)))
    with pytest.raises(DataError, match="reference.source"):
        ReferencePoses("vicon", np.array([0]), np.zeros((1, 3)))


def test_events_merge_streams_in_time_order_with_odometry_first_on_ties():
    log = SensorLog(
        "x",
        sensor=_sensor(),
        scans=ScanBatch(np.array([10, 20]), np.ones((2, 4))),
        odometry=Odometry("increment", np.array([5, 10, 15, 20]), np.zeros((4, 3))),
        reference={"gps": ReferencePoses("gps", np.array([12]), np.array([[0.0, 0.0, np.nan]]))},
    )
    ev = [(e.stamp, e.stream, e.index) for e in log.events()]
    assert ev == [
        (5, "odometry", 0),
        (10, "odometry", 1),
        (10, "scan", 0),
        (12, "reference:gps", 0),
        (15, "odometry", 2),
        (20, "odometry", 3),
        (20, "scan", 1),
    ]


def test_frames_give_odometry_since_previous_frame_and_detection_slices():
    det = Detections(
        np.array([10, 20, 30]), np.array([0, 0, 2]), np.array([1.0, 2.0, 3.0]), np.zeros(3), {"d": np.arange(3)}
    )
    log = SensorLog("x", odometry=Odometry("velocity", np.array([5, 10, 25]), np.zeros((3, 2))), detections=det)
    frames = list(log.frames())
    assert [f.rows for f in frames] == [slice(0, 2), slice(2, 2), slice(2, 3)]
    assert [f.odometry for f in frames] == [slice(0, 2), slice(2, 2), slice(2, 3)]
    assert [f.kind for f in frames] == ["detections"] * 3


def test_detections_frame_index_checked():
    with pytest.raises(DataError, match="detections.frame"):
        Detections(np.array([1, 2]), np.array([1, 0]), np.ones(2), np.zeros(2))
    with pytest.raises(DataError, match=r"descriptors\['d'\]"):
        Detections(np.array([1]), np.array([0]), np.ones(1), np.zeros(1), {"d": np.ones(2)})
