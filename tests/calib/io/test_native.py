import zipfile

import numpy as np
import pytest

from calib.io.native import read_native, write_native
from detectors.sensor_log import (
    Detections,
    Landmarks,
    Mount,
    Odometry,
    PointClouds,
    ReferencePoses,
    ScanBatch,
    SensorLog,
    SensorModel,
    Vehicle,
)
from profiles.errors import DataError, UsageError


def full_log() -> SensorLog:
    rng = np.random.default_rng(3)
    r = rng.uniform(0, 10, (5, 7)).astype(np.float32)
    r[1, 3] = np.nan
    return SensorLog(
        "full",
        sensor=SensorModel(n_beams=7, angle_min=-0.3, angle_increment=0.1, range_max=10.0, range_sigma=0.01, mount=Mount(x=0.5, theta=0.1)),
        scans=ScanBatch(np.arange(5) * 100_000_001, r, rng.uniform(size=(5, 7)), rng.normal(size=(5, 3))),
        odometry=Odometry("increment", np.arange(9) * 50_000_000, rng.normal(size=(9, 3))),
        reference={
            "ground_truth": ReferencePoses("ground_truth", np.arange(3), rng.normal(size=(3, 3))),
            "gps": ReferencePoses("gps", np.arange(2), np.array([[1.0, 2.0, np.nan], [3.0, 4.0, np.nan]]), point=(3.78, -0.5)),
        },
        landmarks=Landmarks(np.array([4, 9]), rng.normal(size=(2, 2)), np.array([0.2, np.nan])),
        detections=Detections(np.array([7, 8, 9]), np.array([0, 0, 2]), np.ones(3), np.zeros(3), {"barcode": np.array([5, 14, 90]), "d": np.ones(3) / 3}),
        clouds=PointClouds(np.array([0, 1]), np.array([0, 2, 3]), rng.normal(size=(3, 4))),
        vehicle=Vehicle(wheelbase=2.83, encoder_offset=0.76),
        source={"reader": "test", "nested": {"a": [1, 2]}},
    )


def assert_logs_equal(a: SensorLog, b: SensorLog) -> None:
    assert a.name == b.name and a.sensor == b.sensor and a.vehicle == b.vehicle
    assert a.streams() == b.streams()

    def same(x, y):
        assert (x is None) == (y is None)
        if x is not None:
            assert x.dtype == y.dtype and x.shape == y.shape
            np.testing.assert_array_equal(x, y)  # NaN == NaN here; exact otherwise

    for s in ("scans", "odometry", "landmarks", "detections", "clouds"):
        xa, xb = getattr(a, s), getattr(b, s)
        assert (xa is None) == (xb is None)
        if xa is None:
            continue
        for f in xa.__dataclass_fields__:
            va, vb = getattr(xa, f), getattr(xb, f)
            if isinstance(va, dict):
                assert sorted(va) == sorted(vb)
                for k in va:
                    same(va[k], vb[k])
            elif isinstance(va, np.ndarray) or va is None:
                same(va, vb)
            else:
                assert va == vb
    assert sorted(a.reference) == sorted(b.reference)
    for k in a.reference:
        same(a.reference[k].stamp, b.reference[k].stamp)
        same(a.reference[k].poses, b.reference[k].poses)
        assert a.reference[k].point == b.reference[k].point


def test_round_trip_is_lossless(tmp_path):
    log = full_log()
    write_native(log, tmp_path / "a.dlog")
    assert_logs_equal(log, read_native(tmp_path / "a.dlog"))


def test_same_log_same_bytes(tmp_path):
    write_native(full_log(), tmp_path / "a.dlog")
    write_native(full_log(), tmp_path / "b.dlog")
    assert (tmp_path / "a.dlog").read_bytes() == (tmp_path / "b.dlog").read_bytes()


def test_existing_file_not_overwritten_without_force(tmp_path):
    p = tmp_path / "a.dlog"
    p.write_text("keep me")
    with pytest.raises(UsageError, match="already exists"):
        write_native(full_log(), p)
    assert p.read_text() == "keep me"
    # --force replaces only a log detcal wrote, never another file or a folder
    with pytest.raises(UsageError, match="a.dlog: is not a native log detcal wrote; --force replaces only a native log"):
        write_native(full_log(), p, overwrite=True)
    assert p.read_text() == "keep me"
    (tmp_path / "d.dlog").mkdir()
    with pytest.raises(UsageError, match="d.dlog: is a folder; --force replaces only a file detcal wrote"):
        write_native(full_log(), tmp_path / "d.dlog", overwrite=True)
    p.unlink()
    write_native(full_log(), p)
    write_native(full_log(), p, overwrite=True)
    assert read_native(p).name == "full"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.dlog", "d.dlog"]  # no temporary left behind


def test_truncated_file_is_a_clear_error(tmp_path):
    p = tmp_path / "a.dlog"
    write_native(full_log(), p)
    data = p.read_bytes()
    (tmp_path / "cut.dlog").write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match=r"cut.dlog: not a detcal log or truncated"):
        read_native(tmp_path / "cut.dlog")


def test_corrupt_member_is_named(tmp_path):
    p = tmp_path / "a.dlog"
    write_native(full_log(), p)
    data = bytearray(p.read_bytes())
    with zipfile.ZipFile(p) as zf:
        info = zf.getinfo("scan/ranges.npy")
    start = info.header_offset + 30 + len(info.filename) + len(info.extra) + 5
    data[start : start + 20] = bytes(20)
    (tmp_path / "bad.dlog").write_bytes(bytes(data))
    with pytest.raises(DataError, match=r"member scan/ranges.npy is truncated or corrupt"):
        read_native(tmp_path / "bad.dlog")


def test_wrong_version_and_missing_file(tmp_path):
    p = tmp_path / "v.dlog"
    with zipfile.ZipFile(p, "w") as zf:
        zf.writestr("meta.json", '{"format": "detcal-log", "version": 99, "streams": {}}')
    with pytest.raises(DataError, match="log format version 99 is not supported"):
        read_native(p)
    with pytest.raises(UsageError, match="nope.dlog: no such file"):
        read_native(tmp_path / "nope.dlog")


def test_failed_write_leaves_nothing(tmp_path, monkeypatch):
    import calib.io.native as native

    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(native.np.lib.format, "write_array", boom)
    with pytest.raises(RuntimeError):
        write_native(full_log(), tmp_path / "a.dlog")
    assert list(tmp_path.iterdir()) == []


def forge(tmp_path, edit_meta=None, arrays=None, name="f.dlog"):
    """A .dlog written by hand from full_log's members: meta.json and arrays edited as asked."""
    import io
    import json

    src = tmp_path / "src.dlog"
    if not src.exists():
        write_native(full_log(), src)
    with zipfile.ZipFile(src) as zf:
        members = {n: zf.read(n) for n in zf.namelist()}
    meta = json.loads(members["meta.json"])
    if edit_meta is not None:
        meta = edit_meta(meta)
    members["meta.json"] = json.dumps(meta).encode() if not isinstance(meta, bytes) else meta
    for key, arr in (arrays or {}).items():
        if isinstance(arr, bytes):
            members[f"{key}.npy"] = arr
        else:
            buf = io.BytesIO()
            np.lib.format.write_array(buf, arr, allow_pickle=False)
            members[f"{key}.npy"] = buf.getvalue()
    out = tmp_path / name
    with zipfile.ZipFile(out, "w") as zf:
        for n, b in members.items():
            zf.writestr(n, b)
    return out


def huge_header() -> bytes:
    """An .npy header claiming 10^11 float32 values, followed by 16 bytes."""
    import io

    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f4", "fortran_order": False, "shape": (10**9, 100)})
    return buf.getvalue() + bytes(16)


@pytest.mark.parametrize(
    ("meta", "arrays", "match"),
    [
        (lambda m: [1, 2], None, r"f.dlog: meta.json is a list, expected an object"),
        (lambda m: b"\xff\xfe\x00garbage", None, r"f.dlog: meta.json is unreadable"),
        (lambda m: {k: v for k, v in m.items() if k != "streams"}, None, r"f.dlog: meta.json has no streams section"),
        (lambda m: {**m, "colour": "red"}, None, r"f.dlog: meta.json colour: unknown key"),
        (lambda m: {**m, "streams": {**m["streams"], "sonar": {"n": 1}}}, None, r"f.dlog: meta.json streams.sonar: unknown key"),
        (lambda m: {**m, "streams": {**m["streams"], "scan": {**m["streams"]["scan"], "n": 6}}}, None, r"f.dlog: meta.json streams.scan.n is 6 but the arrays hold 5"),
        (lambda m: {**m, "streams": {**m["streams"], "odometry": {"n": 9}}}, None, r"f.dlog: meta.json streams.odometry.kind: Field required"),
        (lambda m: {**m, "streams": {**m["streams"], "scan": {**m["streams"]["scan"], "n": "5"}}}, None, r"meta.json streams.scan.n: Input should be a valid integer"),
        (lambda m: {**m, "sensor": {**m["sensor"], "angle_min": None, "n_beams": 7, "geometries": []}}, None, r"f.dlog: meta.json sensor: Value error, geometries lists two or more beam layouts"),
        (lambda m: {**m, "name": 5}, None, r"meta.json name must be a string"),
        (None, {"scan/stamp": np.arange(5) * 0.1}, r"member scan/stamp.npy has dtype float64, expected int64"),
        (None, {"scan/ranges": np.full((5, 7), "1.0")}, r"member scan/ranges.npy has dtype <U3, expected float32"),
        (None, {"scan/ranges": huge_header()}, r"member scan/ranges.npy claims shape \(1000000000, 100\)"),
        (None, {"detections/descriptors/barcode": np.array(["a", "b", "c"])}, r"descriptors/barcode.npy has dtype <U1, expected numbers"),
        (None, {"odometry/stamp": np.arange(9)[::-1].copy() * 50_000_000}, r"f.dlog: odometry.stamp\[1\]: time goes backwards"),
        (None, {"scan/ranges": np.full((5, 6), 1.0, dtype=np.float32)}, r"f.dlog: scans.intensities: expected shape \(5, 6\), got \(5, 7\)"),
    ],
)
def test_forged_and_corrupt_native_logs_are_refused(tmp_path, meta, arrays, match):
    with pytest.raises(DataError, match=match):
        read_native(forge(tmp_path, meta, arrays))
