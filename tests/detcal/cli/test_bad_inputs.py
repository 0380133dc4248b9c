"""Every bad input a user may give detcal: one plain line on stderr naming the file, line or field,
exit code 1 (bad data) or 2 (usage), never a traceback, nothing written.

The cases are a table (``CASES``); ``python -m tests.calib.test_bad_inputs`` prints it as Markdown
with the exit code and message of each, as the command line gives them.
"""

from __future__ import annotations

import bz2
import io
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
import yaml

from detcal.cli import main
from tests.calib.io.test_carmen import BASE, flaser, odom
from tests.conftest import VENDORED


def carmen(tmp: Path, *extra: str, name: str = "t.clf", base=BASE) -> str:
    p = tmp / name
    text = "\n".join(["# header", "PARAM robot_frontlaser_offset 0.1 nohost 0", *base, *extra]) + "\n"
    p.write_bytes(bz2.compress(text.encode()) if name.endswith(".bz2") else text.encode())
    return str(p)


def native(tmp: Path, edit_meta=None, arrays=None, name: str = "f.dlog") -> str:
    from tests.calib.io.test_native import forge

    return str(forge(tmp, edit_meta, arrays, name))


def small_log(tmp: Path) -> str:
    from calib.io.native import write_native
    from tests.calib.io.test_native import full_log

    p = tmp / "ok.dlog"
    if not p.exists():
        write_native(full_log(), p)
    return str(p)


def npy(arr) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, arr, allow_pickle=False)
    return buf.getvalue()


def huge() -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f4", "fortran_order": False, "shape": (10**9, 100)})
    return buf.getvalue() + bytes(16)


def text(tmp: Path, name: str, content: str | bytes) -> str:
    p = tmp / name
    p.write_bytes(content if isinstance(content, bytes) else content.encode())
    return str(p)


def profile_doc(**edits) -> dict:
    from profiles.store import BUILTIN

    d = yaml.safe_load((BUILTIN / "sim-park-laser@1.0.0.yaml").read_text())
    for path, value in edits.items():
        node = d
        keys = path.split("__")
        for k in keys[:-1]:
            node = node[k]
        node[keys[-1]] = value
    return d


def sim_config(t: Path, scenario: str, config: str) -> list[str]:
    """``detcal simulate SCENARIO`` with a config file of the text ``config``."""
    return ["simulate", scenario, "--out", str(t / "s"), "--config", text(t, "c.yaml", config)]


def _vendored_copy(tmp: Path, source: str, name: str, edit=None) -> str:
    """A copy of a vendored data folder as ``tmp / name``, edited by ``edit(folder)``."""
    import shutil

    dst = tmp / name
    shutil.copytree(VENDORED / source, dst)
    if edit:
        edit(dst)
    return str(dst)


def utias_copy(tmp: Path, edit=None) -> str:
    return _vendored_copy(tmp, "utias_dataset1", "utias", edit)


def vp_copy(tmp: Path, edit=None) -> str:
    return _vendored_copy(tmp, "victoria_park", "vp", edit)


def _edit_row(name: str, row: int, column: int, value: str):
    """An edit of a copied data folder: data row ``row`` (0-based, after the comments) of ``name`` gets ``value`` in ``column``."""

    def edit(d: Path) -> None:
        p = d / name
        lines = p.read_text().splitlines()
        i = [k for k, ln in enumerate(lines) if ln and not ln.startswith("#")][row]
        cells = lines[i].split()
        cells[column] = value
        lines[i] = " ".join(cells)
        p.write_text("\n".join(lines) + "\n")

    return edit


class Case(NamedTuple):
    """A case whose command runs in an environment of its own: ``env`` variables set (None: removed), ``patch(mp)``
    a deterministic fault put in place with pytest's monkeypatch (a full disk, say), undone after the case."""

    argv: list[str]
    env: dict[str, str | None] | None = None
    patch: Callable | None = None


def zip_flag(tmp: Path, name: str, *, encrypted: bool = False, method: int | None = None) -> str:
    """A copy of :func:`small_log` whose every member says it is encrypted (flag bit 0) or uses compression ``method``,
    as one flipped bit in each local and central header would."""
    import struct

    data = bytearray(Path(small_log(tmp)).read_bytes())
    for sig, flag_at, method_at in ((b"PK\x03\x04", 6, 8), (b"PK\x01\x02", 8, 10)):
        i = data.find(sig)
        while i >= 0:
            if encrypted:
                data[i + flag_at] |= 1
            if method is not None:
                data[i + method_at : i + method_at + 2] = struct.pack("<H", method)
            i = data.find(sig, i + 4)
    return text(tmp, name, bytes(data))


def damaged_gzip(tmp: Path) -> str:
    """A gzip CARMEN log with one byte of its deflate stream changed so that zlib refuses it (invalid distance);
    deterministic: the same bytes are compressed (mtime 0) and the first such byte is changed."""
    import gzip
    import zlib

    body = "\n".join(["# header", *BASE, *(odom(2.0 + 0.1 * k, 0.01 * k) for k in range(2000))]) + "\n"
    data = gzip.compress(body.encode(), mtime=0)
    for k in range(20, len(data) - 8):
        d = bytearray(data)
        d[k] ^= 0x55
        try:
            gzip.decompress(bytes(d))
        except zlib.error:
            return text(tmp, "d.clf.gz", bytes(d))
        except Exception:  # noqa: BLE001,S112  (other damage: try the next byte)
            continue
    raise AssertionError("no byte gave a zlib error")


def _folder(tmp: Path, name: str) -> Path:
    (tmp / name).mkdir(exist_ok=True)
    return tmp / name


def sparse(tmp: Path, name: str, size: int) -> str:
    """A file of ``size`` bytes of zeros that takes no room on disk (a hole)."""
    p = tmp / name
    with open(p, "wb") as fh:
        fh.truncate(size)
    return str(p)


def same_stamp(d: Path) -> None:
    """Every UTIAS odometry row of robot 1 stamped with the first row's time."""
    p = d / "Robot1_Odometry.dat"
    lines = p.read_text().splitlines()
    rows = [k for k, ln in enumerate(lines) if ln.strip() and not ln.startswith("#")]
    t0 = lines[rows[0]].split()[0]
    for k in rows:
        lines[k] = " ".join([t0, *lines[k].split()[1:]])
    p.write_text("\n".join(lines) + "\n")


def profile_text(t: Path, **edits) -> str:
    return text(t, "p.yaml", yaml.safe_dump(profile_doc(**edits)))


def pd_profile(t: Path, pd: float, **edits) -> str:
    """The bundled profile with every P_D bin set to ``pd`` (and ``edits`` as in :func:`profile_doc`)."""
    d = profile_doc(**edits)
    for b in d["pd"]["bins"]:
        b["pd"] = pd
    return text(t, "p.yaml", yaml.safe_dump(d))


def legacy_profile(t: Path) -> str:
    """A schema-1 profile as an earlier build wrote it (from the legacy corpus)."""
    return text(t, "p.yaml", (VENDORED / "profiles-legacy" / "109d97f_sim-park-laser_1.0.0.yaml").read_text())


def duplicated_key_profile(t: Path) -> str:
    """The bundled profile with ``range_max: 5.0`` added after its own (the second one would win in PyYAML)."""
    from profiles.store import BUILTIN

    src = (BUILTIN / "sim-park-laser@1.0.0.yaml").read_text()
    return text(t, "p.yaml", src.replace("  range_max: 80.0  # m\n", "  range_max: 80.0  # m\n  range_max: 5.0\n", 1))


def full_disk_in(folder_name: str):
    """A fault: every write to a file under a folder named ``folder_name`` fails with ENOSPC, and that folder's file
    system reports no free space (what a full disk does); other folders keep their room."""

    def patch(mp) -> None:
        import errno
        import os

        real_open, real_statvfs = io.open, os.statvfs

        def inside(p) -> bool:
            return folder_name in Path(str(p)).parts

        def fake_open(file, mode="r", *a, **k):
            fh = real_open(file, mode, *a, **k)
            if inside(file) and any(c in mode for c in "wax+"):
                fh.close()
                raise OSError(errno.ENOSPC, "No space left on device")
            return fh

        def fake_statvfs(p):
            st = real_statvfs(p)
            if inside(p):
                return os.statvfs_result((st.f_bsize, st.f_frsize, st.f_blocks, 0, 0, *st[5:]))
            return st

        mp.setattr("builtins.open", fake_open)
        mp.setattr("io.open", fake_open)
        mp.setattr(os, "statvfs", fake_statvfs)

    return patch


def bag_disk_full(after: int):
    """A fault: the ROS 2 bag's database refuses the write of message ``after`` as sqlite does on a full disk."""

    def patch(mp) -> None:
        import sqlite3

        from rosbags.rosbag2 import Writer

        real = Writer.write
        count = {"n": 0}

        def write(self, *a, **k):
            count["n"] += 1
            if count["n"] > after:
                raise sqlite3.OperationalError("database or disk is full")
            return real(self, *a, **k)

        mp.setattr(Writer, "write", write)

    return patch


def interlaced_log(tmp: Path) -> str:
    from calib.io.carmen import read_carmen
    from calib.io.native import write_native

    lines = [odom(1.0), flaser(1.05, [1.0] * 181), flaser(1.15, [2.0] * 180), odom(1.2, 0.1)]
    log = read_carmen(carmen(tmp, *lines, base=[], name="i.clf"))
    return str(write_native(log, tmp / "i.dlog"))


# (id, what, argv builder (tmp -> list[str]), exit code, text the message must contain)
CASES = [
    # ---- CARMEN logs
    ("carmen-fields", "FLASER line with fewer fields than its beam count", lambda t: ["log", "info", carmen(t, "FLASER 4 1 2 3")], 1, "t.clf:7: FLASER declares 4 beams but has 5 fields"),
    ("carmen-backwards", "scan stamped 1.15 s before the previous one", lambda t: ["log", "info", carmen(t, flaser(0.0, [1.0] * 4))], 1, "t.clf:7: FLASER time goes backwards by 1.150000 s"),
    ("carmen-nan", "NaN range reading", lambda t: ["log", "info", carmen(t, flaser(1.2, [1.0, 2.0, 3.0, 4.0]).replace("3.00", "nan"))], 1, "t.clf:7: range reading: NaN value"),
    ("carmen-negative", "negative range reading", lambda t: ["log", "info", carmen(t, flaser(1.2, [1.0, -2.0, 3.0, 4.0]))], 1, "t.clf:7: range reading 2 is negative"),
    ("carmen-text-range", "range reading that is not a number", lambda t: ["log", "info", carmen(t, flaser(1.2, [1.0, 2.0, 3.0, 4.0]).replace("3.00", "x3"))], 1, "t.clf:7: range reading: 'x3' is not a number"),
    ("carmen-1e300", "timestamp of 1e300 s", lambda t: ["log", "info", carmen(t, flaser(1.2, [1.0] * 4).replace("1.200000", "1e300", 1))], 1, "t.clf:7: timestamp '1e300' is out of range"),
    ("carmen-odom-fields", "ODOM line with 6 fields", lambda t: ["log", "info", carmen(t, "ODOM 0 0 0 1.2 nohost")], 1, "t.clf:7: ODOM has 6 fields, expected 10"),
    ("carmen-count", "beam count that is not an integer", lambda t: ["log", "info", carmen(t, "FLASER abc")], 1, "t.clf:7: FLASER beam count missing or not an integer"),
    ("carmen-robotlaser", "truncated ROBOTLASER1 line", lambda t: ["log", "info", carmen(t, "ROBOTLASER1 0 -1.5 3.1 0.5 30 0.01 0 5 1 2", base=[])], 1, "t.clf:3: ROBOTLASER1 is truncated"),
    ("carmen-empty", "CARMEN log without laser or ODOM lines", lambda t: ["log", "info", carmen(t, "PARAM a b", base=[])], 1, "t.clf: no FLASER/ROBOTLASER1 or ODOM lines"),
    ("carmen-all-zero", "every line stamped 0", lambda t: ["log", "info", carmen(t, odom(0.0), odom(0.0, 0.1), base=[])], 1, "t.clf: every line is stamped 0; the log carries no time"),
    ("carmen-truncated-bz2", "truncated .bz2 log", lambda t: ["log", "info", text(t, "c.clf.bz2", Path(carmen(t, *BASE * 40, name="x.clf.bz2")).read_bytes()[:-40])], 1, "c.clf.bz2: compressed stream is truncated or corrupt"),
    ("carmen-strict", "small step back with --max-backstep 0", lambda t: ["log", "info", carmen(t, flaser(1.12, [1.0] * 4)), "--max-backstep", "0"], 1, "t.clf:7: FLASER time goes backwards by 0.030000 s (more than the tolerated 0 s)"),
    # ---- native logs
    ("native-not-zip", "a .dlog that is not a zip file", lambda t: ["log", "info", text(t, "x.dlog", "hello")], 1, "x.dlog: not a detcal log or truncated"),
    ("native-truncated", "a truncated .dlog", lambda t: ["log", "info", text(t, "cut.dlog", Path(small_log(t)).read_bytes()[:3000])], 1, "cut.dlog: not a detcal log or truncated"),
    ("native-meta-list", "meta.json that is a list", lambda t: ["log", "info", native(t, lambda m: [1, 2])], 1, "f.dlog: meta.json is a list, expected an object"),
    ("native-no-streams", "meta.json without streams", lambda t: ["log", "info", native(t, lambda m: {k: v for k, v in m.items() if k != "streams"})], 1, "f.dlog: meta.json has no streams section"),
    ("native-version", "log format version 99", lambda t: ["log", "info", native(t, lambda m: {**m, "version": 99})], 1, "f.dlog: log format version 99 is not supported (this detcal reads version 1)"),
    ("native-float-stamps", "float stamps", lambda t: ["log", "info", native(t, arrays={"scan/stamp": np.arange(5) * 0.1})], 1, "f.dlog: member scan/stamp.npy has dtype float64, expected int64"),
    ("native-string-ranges", "string ranges", lambda t: ["log", "info", native(t, arrays={"scan/ranges": np.full((5, 7), "1.0")})], 1, "f.dlog: member scan/ranges.npy has dtype <U3, expected float32"),
    ("native-counts", "meta.json count that disagrees with the arrays", lambda t: ["log", "info", native(t, lambda m: {**m, "streams": {**m["streams"], "scan": {**m["streams"]["scan"], "n": 6}}})], 1, "f.dlog: meta.json streams.scan.n is 6 but the arrays hold 5"),
    ("native-huge-header", "array header claiming 10^11 elements", lambda t: ["log", "info", native(t, arrays={"scan/ranges": huge()})], 1, "f.dlog: member scan/ranges.npy claims shape (1000000000, 100) (400000000000 bytes) but holds"),
    ("native-missing-member", "member listed in meta.json but absent", lambda t: ["log", "info", _drop_member(t)], 1, "h.dlog: member odometry/values.npy is missing"),
    ("native-bad-sensor", "sensor model with NaN angle_min", lambda t: ["log", "info", native(t, lambda m: {**m, "sensor": {**m["sensor"], "angle_min": float("nan")}})], 1, "f.dlog: meta.json sensor.angle_min: Input should be a finite number"),
    # ---- table logs
    ("utias-1e300", "UTIAS odometry time of 1e300 s", lambda t: ["log", "info", utias_copy(t, _edit_row("Robot1_Odometry.dat", 5, 0, "1e300"))], 1, "Robot1_Odometry.dat:6: t v omega: time 1e+300 s is out of range"),
    ("utias-negative-range", "UTIAS measurement of negative range", lambda t: ["log", "info", utias_copy(t, _edit_row("Robot1_Measurement.dat", 3, 2, "-1.5"))], 1, "Robot1_Measurement.dat:4: t barcode range bearing: negative range"),
    ("utias-no-measurements", "UTIAS robot without measurements", lambda t: ["slam", "run", utias_copy(t, lambda d: (d / "Robot1_Measurement.dat").write_text("")), "--profile", "sim-park-laser"], 1, "utias: the log holds no detections (robot 1)"),
    ("vp-bearing", "Victoria Park bearing of 7.5 rad", lambda t: ["log", "info", vp_copy(t, _edit_row("measurements.dat", 2, 2, "7.5"))], 1, "measurements.dat:3: t range bearing diameter: bearing outside 0..pi rad"),
    ("vp-diameter", "Victoria Park negative diameter", lambda t: ["log", "info", vp_copy(t, _edit_row("measurements.dat", 0, 3, "-0.3"))], 1, "measurements.dat:1: t range bearing diameter: negative diameter"),
    ("utias-robot", "UTIAS robot 9", lambda t: ["log", "info", str(VENDORED / "utias_dataset1"), "--robot", "9"], 2, "--robot: expected 1..5, got 9"),
    # ---- configs
    ("config-utf8", "config that is not UTF-8", lambda t: ["simulate", "park", "--out", str(t / "s"), "--config", text(t, "c.yaml", b"width: \xff\xfe\n")], 2, "c.yaml: not UTF-8 text (byte 7)"),
    ("config-yaml", "config that is not YAML", lambda t: sim_config(t, "park", "width: [1,\n"), 2, "c.yaml:2: not valid YAML"),
    ("config-list", "config that is a list", lambda t: sim_config(t, "park", "- 1\n"), 2, "c.yaml: expected a mapping at the top level"),
    ("config-unknown", "misspelt nested config key", lambda t: sim_config(t, "park", "laser: {beams: 3}\n"), 2, "c.yaml: laser.beams: unknown key"),
    ("config-calibrate", "calibration config with a bad value", lambda t: ["calibrate", small_log(t), "--config", text(t, "c.yaml", "pd: {min_count: -1}\n"), "--out", str(t / "r")], 2, "c.yaml: pd.min_count: Input should be greater than or equal to 1"),
    ("config-missing", "config file that does not exist", lambda t: ["calibrate", small_log(t), "--config", str(t / "none.yaml")], 2, "none.yaml: no such config file"),
    # ---- profiles
    ("profile-utf8", "profile that is not UTF-8", lambda t: ["profile", "validate", text(t, "p.yaml", b"name: \xff\n")], 1, "p.yaml: not UTF-8 text (byte 6)"),
    ("profile-unknown", "profile with an unknown key", lambda t: ["profile", "validate", text(t, "p.yaml", yaml.safe_dump(profile_doc(clutter__lamda=3)))], 1, "p.yaml: clutter.lamda: unknown key"),
    ("profile-parameters", "unknown key under provenance.parameters", lambda t: ["profile", "validate", text(t, "p.yaml", yaml.safe_dump(profile_doc(provenance__parameters__colour="red")))], 1, "p.yaml: provenance.parameters.colour: unknown key"),
    ("profile-parameters-nested", "misspelt key inside provenance.parameters.pd", lambda t: ["profile", "validate", text(t, "p.yaml", yaml.safe_dump(profile_doc(provenance__parameters__pd={"min_cont": 3})))], 1, "p.yaml: provenance.parameters.pd.min_cont: unknown key"),
    ("profile-schema", "profile of schema version 4", lambda t: ["profile", "validate", text(t, "p.yaml", yaml.safe_dump(profile_doc(schema_version=4)))], 1, "p.yaml: schema_version 4 is newer than this detcal reads (3); upgrade detcal"),
    ("profile-not-mapping", "profile that is a list", lambda t: ["profile", "validate", text(t, "p.yaml", "- a\n")], 1, "p.yaml: a profile is a mapping at the top level"),
    ("profile-json", "JSON profile with a syntax error", lambda t: ["profile", "validate", text(t, "p.json", '{"name": ')], 1, "p.json:1: not valid YAML/JSON"),
    ("profile-unknown-ref", "unknown profile name", lambda t: ["profile", "show", "nope@9.9.9"], 2, "no profile 'nope@9.9.9'"),
    ("profile-missing-file", "profile file that does not exist", lambda t: ["profile", "validate", str(t / "none.yaml")], 2, "none.yaml: no such profile file"),
    # ---- options
    ("opt-backstep", "negative --max-backstep", lambda t: ["log", "info", small_log(t), "--max-backstep", "-1"], 2, "--max-backstep: Input should be greater than or equal to 0"),
    ("opt-range-max", "negative --range-max", lambda t: ["log", "info", small_log(t), "--range-max", "-5"], 2, "--range-max: Input should be greater than 0"),
    ("opt-range-sigma", "--range-sigma 0", lambda t: ["log", "info", small_log(t), "--range-sigma", "0"], 2, "--range-sigma: Input should be greater than 0"),
    ("opt-range-sigma-camera", "--range-sigma for a log without a laser", lambda t: ["log", "info", str(VENDORED / "utias_dataset1"), "--range-sigma", "0.01"], 2, "--range-sigma: "),
    ("opt-seed-sim", "negative --seed (simulate)", lambda t: ["simulate", "park", "--out", str(t / "s"), "--seed", "-1"], 2, "--seed: expected a non-negative integer, got -1"),
    ("opt-seed-slam", "negative --seed (slam run)", lambda t: ["slam", "run", small_log(t), "--profile", "sim-park-laser", "--seed", "-1"], 2, "--seed: expected a non-negative integer, got -1"),
    ("opt-seed-selfcal", "negative --seed (selfcal)", lambda t: ["selfcal", small_log(t), "--profile", "sim-park-laser", "--seed", "-1"], 2, "--seed: expected a non-negative integer, got -1"),
    ("opt-version", "--version that is not MAJOR.MINOR.PATCH", lambda t: ["calibrate", "--version", "one", small_log(t)], 2, "--version: 'one' is not MAJOR.MINOR.PATCH"),
    ("opt-name", "--name with a slash", lambda t: ["calibrate", small_log(t), "--name", "a/b"], 2, "--name: 'a/b' must match [a-z0-9][a-z0-9._-]*"),
    ("opt-poses", "--poses foo", lambda t: ["calibrate", small_log(t), "--poses", "foo"], 2, "--poses: expected auto, reference, icp, got 'foo'"),
    ("opt-laser", "--laser middle", lambda t: ["log", "info", carmen(t), "--laser", "middle"], 2, "--laser: expected 'front' or 'rear', got 'middle'"),
    ("opt-format", "--format foo", lambda t: ["log", "info", small_log(t), "--format", "foo"], 2, "--format: expected one of native, carmen, rosbag, victoria, utias, kitti, rfsslam, got 'foo'"),
    ("opt-unknown", "an option that does not exist", lambda t: ["log", "info", small_log(t), "--no-such-option"], 2, "No such option: --no-such-option"),
    ("opt-frames", "--frames 0", lambda t: ["slam", "run", small_log(t), "--profile", "sim-park-laser", "--frames", "0"], 2, "--frames: expected a positive integer, got 0"),
    ("opt-seeds", "--seeds x", lambda t: ["slam", "sweep", small_log(t), "--profile", "sim-park-laser", "--seeds", "x"], 2, "--seeds: expected a count (5), a list (1,3,7) or a range (1-5), got 'x'"),
    ("opt-workers", "negative --workers", lambda t: ["slam", "sweep", small_log(t), "--profile", "sim-park-laser", "--workers", "-2"], 2, "--workers: expected 0 (this process) or a positive number of worker processes, got -2"),
    ("opt-workers-scheduler", "--workers with --scheduler", lambda t: ["calibrate", small_log(t), "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], 2, "--workers: the cluster at --scheduler has its own workers; give one of the two"),
    ("opt-landmarks-missing", "--landmarks file that does not exist", lambda t: ["calibrate", small_log(t), "--landmarks", str(t / "none.csv")], 2, "--landmarks: "),
    ("opt-landmarks-bad", "landmark CSV with a text radius", lambda t: ["calibrate", small_log(t), "--landmarks", text(t, "l.csv", "id,x,y,radius\n1,0,0,big\n")], 1, "l.csv:2: id must be an integer, x, y numbers and radius > 0"),
    ("opt-landmarks-columns", "landmark CSV without a radius column", lambda t: ["calibrate", small_log(t), "--landmarks", text(t, "l.csv", "id,x,y\n1,0,0\n")], 1, "l.csv: missing columns ['radius']"),
    ("opt-to", "--to foo", lambda t: ["log", "convert", small_log(t), str(t / "o"), "--to", "foo"], 2, "--to: expected one of native, ros2, kitti, got 'foo'"),
    ("opt-out-suffix", "output name of no known format", lambda t: ["log", "convert", small_log(t), str(t / "o.txt")], 2, "o.txt: cannot tell the output format"),
    ("input-missing", "log that does not exist", lambda t: ["calibrate", str(t / "missing.dlog")], 2, "missing.dlog: no such file"),
    ("input-folder", "a folder that holds no log", lambda t: ["log", "info", str(t)], 2, "cannot tell the log format from the path"),
    ("input-brackets", "file name with brackets and console markup", lambda t: ["log", "info", _bracketed(t)], 1, "run[v2]/line 100 :100: [b]a[/b].dlog: not a detcal log or truncated"),
    ("slam-geometry", "slam run on a laser of two beam layouts the profile was not calibrated for", lambda t: ["slam", "run", interlaced_log(t), "--profile", "sim-park-laser"], 2, "was calibrated for 361 beams from -90.00 deg every 0.5000 deg; this log's laser has 180"),
    # ---- values that are not finite, settings that contradict each other, streams that hold nothing
    ("opt-clutter-inf", "--clutter inf", lambda t: ["simulate", "glmb-paper", "--out", str(t / "s"), "--clutter", "inf"], 2, "--clutter: Input should be a finite number"),
    ("opt-clutter-huge", "--clutter 1e20", lambda t: ["simulate", "glmb-paper", "--out", str(t / "s"), "--clutter", "1e20"], 2, "--clutter: Input should be less than or equal to 10000"),
    ("config-inf", "simulation config with .inf", lambda t: sim_config(t, "park", "width: .inf\n"), 2, "c.yaml: width: Input should be a finite number"),
    ("config-margin", "park path margin wider than the park", lambda t: sim_config(t, "park", "path: {margin: 100}\n"), 2, "c.yaml: path.margin (100.0 m) leaves no room for the figure-eight"),
    ("config-min-max", "bushes' smallest radius above their largest", lambda t: sim_config(t, "park", "bushes: {min_radius: 2, max_radius: 1}\n"), 2, "c.yaml: bushes: min_radius (2.0) must not exceed max_radius (1.0)"),
    ("config-lawnmower", "lawnmower rows that do not fit the park", lambda t: sim_config(t, "park", "path: {kind: lawnmower, margin: 100}\n"), 2, "c.yaml: path.margin (100.0 m) and path.row_spacing (25.0 m) leave no room for two lawnmower rows"),
    ("config-mount-inf", "laser mount at x = .inf", lambda t: sim_config(t, "park", "laser: {mount: {x: .inf}}\n"), 2, "c.yaml: laser.mount.x: Input should be a finite number"),
    ("config-detector-inf", "detector jump .inf", lambda t: ["calibrate", small_log(t), "--config", text(t, "c.yaml", "detector: {jump: .inf}\n"), "--out", str(t / "r")], 2, "c.yaml: detector.jump: Input should be a finite number"),
    ("config-park-ticks", "a park path so slow it would need 10^13 odometry ticks", lambda t: sim_config(t, "park", "path: {speed: 1.0e-9}\n"), 1, "path.speed (1e-09 m/s) and odometry.rate_hz (20.0) give 1.26e+13 odometry ticks"),
    ("config-park-beams", "a park laser whose scans would hold 10^11 beams", lambda t: sim_config(t, "park", "laser: {n_beams: 100000, rate_hz: 200}\n"), 1, "laser.rate_hz (200.0) and laser.n_beams (100000) over the run give"),
    ("config-rfs-ranges", "rfs-sim range_min above range_max", lambda t: sim_config(t, "rfs-sim", "range_min: 3\nrange_max: 1\n"), 2, "c.yaml: range_min (3.0) must be below range_max (1.0)"),
    ("config-rfs-speeds", "rfs-sim min_dx above max_dx", lambda t: sim_config(t, "rfs-sim", "min_dx: 1\nmax_dx: 0.5\n"), 2, "c.yaml: min_dx (1.0) must not exceed max_dx (0.5)"),
    ("config-waypoint", "glmb-paper path of one waypoint at the start", lambda t: sim_config(t, "glmb-paper", "waypoints: [[0, 0]]\n"), 2, "c.yaml: waypoints: the only waypoint is within arrive (1.0 m) of the start"),
    ("config-street-rings", "street lidar with no rings", lambda t: sim_config(t, "street", "lidar: {vertical_angles_deg: []}\n"), 2, "c.yaml: lidar.vertical_angles_deg: List should have at least 1 item"),
    ("config-calibrate-inf", "calibration gate .inf", lambda t: ["calibrate", small_log(t), "--config", text(t, "c.yaml", "gate: .inf\n"), "--out", str(t / "r")], 2, "c.yaml: gate: Input should be a finite number"),
    ("config-descriptors-twice", "a descriptor named twice", lambda t: ["calibrate", small_log(t), "--config", text(t, "c.yaml", "descriptors: [log_mse, log_mse]\n"), "--out", str(t / "r")], 2, "c.yaml: descriptors: log_mse is named twice"),
    ("config-detector-points", "detector max_points below min_points", lambda t: ["detect", small_log(t), "--config", text(t, "c.yaml", "detector: {min_points: 10, max_points: 3}\n"), "--out", str(t / "r")], 2, "c.yaml: detector: max_points (3) is below min_points (10)"),
    ("config-slam-inf", "SLAM OSPA cut-off .inf", lambda t: ["slam", "run", small_log(t), "--profile", "sim-park-laser", "--config", text(t, "c.yaml", "metric: {ospa_c: .inf}\n")], 2, "c.yaml: metric.ospa_c: Input should be a finite number"),
    ("config-slam-no-kind", "SLAM filter settings without their kind", lambda t: ["slam", "run", small_log(t), "--profile", "sim-park-laser", "--config", text(t, "c.yaml", "filter: {gate: 4}\n")], 2, "c.yaml: filter: missing the key 'kind'"),
    ("opt-tolerance-nan", "--tolerance nan", lambda t: ["selfcal", small_log(t), "--profile", "sim-park-laser", "--tolerance", "nan"], 2, "--tolerance: expected a positive number, got nan"),
    ("opt-seeds-zero", "--seeds 0 (a count of none)", lambda t: ["slam", "sweep", small_log(t), "--profile", "sim-park-laser", "--seeds", "0"], 2, "--seeds: expected a count of at least 1"),
    ("opt-seeds-twice", "--seeds 1,1", lambda t: ["slam", "sweep", small_log(t), "--profile", "sim-park-laser", "--seeds", "1,1"], 2, "--seeds: a seed is listed twice in '1,1'"),
    ("opt-scheduler-address", "--scheduler without a port", lambda t: ["slam", "sweep", small_log(t), "--profile", "sim-park-laser", "--scheduler", "notanaddress", "--out", str(t / "sw")], 2, "--scheduler notanaddress: not a scheduler address"),
    ("input-relations-empty", "benchmark relations file with no relation", lambda t: ["icp", small_log(t), "--relations", text(t, "l.csv", ""), "--out", str(t / "r")], 1, "l.csv: holds no relations"),
    ("input-no-scans", "log whose scan stream is empty", lambda t: ["detect", empty_scans_log(t), "--out", str(t / "r")], 1, "e.dlog: the log holds no scans"),
    ("input-landmarks-empty", "landmark CSV with a header only", lambda t: ["calibrate", small_log(t), "--landmarks", text(t, "l.csv", "id,x,y,radius\n")], 1, "l.csv: holds no landmarks"),
    ("input-landmark-nan", "native log with a NaN landmark position", lambda t: ["log", "info", native(t, arrays={"landmarks/xy": np.array([[np.nan, 0.0], [1.0, 2.0]])})], 1, "f.dlog: landmarks.xy[0]: position is not finite"),
    # ---- outputs
    ("out-exists", "existing output without --force", lambda t: ["log", "convert", small_log(t), small_log(t)], 2, "ok.dlog: already exists (use --force to replace it)"),
    ("out-foreign-dir", "--force over a folder detcal did not write", lambda t: ["simulate", "park", "--out", _foreign_dir(t), "--force"], 2, "mine: was not written by detcal (no .detcal-output inside); --force does not replace it"),
    ("out-dir-for-file", "--force where a folder stands and a file goes", lambda t: ["log", "convert", small_log(t), _foreign_dir(t, "d.dlog"), "--force"], 2, "d.dlog: is a folder; --force replaces only a file detcal wrote"),
    ("out-file-for-dir", "--force where a file stands and a folder goes", lambda t: ["simulate", "park", "--out", text(t, "plain", "x"), "--force"], 2, "plain: exists and is not a folder; --force replaces only a folder detcal wrote"),
    ("out-foreign-file", "--force over a file detcal did not write", lambda t: ["profile", "export", "sim-park-laser", "--out", text(t, "notes.yaml", "my: notes\n"), "--force"], 2, "notes.yaml: is not a profile detcal wrote; --force replaces only a profile"),
    ("out-other-kind", "--force over a file detcal wrote, of another kind", lambda t: ["profile", "export", "sim-park-laser", "--out", small_log(t), "--force"], 2, "ok.dlog: is not a profile detcal wrote; --force replaces only a profile"),
    ("out-holds-input", "--force over the folder that holds the input log", lambda t: ["detect", _run_with_log(t), "--out", str(t / "run"), "--force"], 2, "run: holds the input"),
    ("out-holds-config", "--force over the folder that holds the simulation's config", lambda t: ["simulate", "park", "--config", _run_with_config(t), "--out", str(t / "run"), "--force"], 2, "run: holds the input"),
    ("out-unwritable", "output folder under a plain file", lambda t: ["log", "convert", small_log(t), str(Path(text(t, "plain", "x")) / "o.dlog")], 2, "plain/o.dlog: cannot write here ("),
    ("out-export-dir", "profile export onto a folder", lambda t: ["profile", "export", "sim-park-laser", "--out", str(t)], 2, "already exists (use --force to replace it)"),
    # ---- found by a bad-input campaign (issue 50): tracebacks, believed values, misleading messages
    ("native-encrypted", "a .dlog whose members have the encrypted flag", lambda t: ["log", "info", zip_flag(t, "enc.dlog", encrypted=True)], 1, "enc.dlog: member meta.json is encrypted (zip flag bit 0)"),
    ("native-compression", "a .dlog member of an unknown compression method", lambda t: ["log", "info", zip_flag(t, "cm.dlog", method=99)], 1, "cm.dlog: member meta.json uses zip compression method 99; a detcal log uses stored or deflate"),
    ("carmen-gzip-damaged", "a .clf.gz whose deflate stream zlib refuses", lambda t: ["log", "info", damaged_gzip(t)], 1, "d.clf.gz: compressed stream is truncated or corrupt after line"),
    ("env-source-date-epoch", "SOURCE_DATE_EPOCH that is not an integer", lambda t: Case(["profile", "list"], env={"SOURCE_DATE_EPOCH": "yesterday"}), 2, "SOURCE_DATE_EPOCH: expected whole seconds since 1970-01-01 UTC"),
    ("env-source-date-epoch-huge", "SOURCE_DATE_EPOCH beyond year 9999", lambda t: Case(["profile", "list"], env={"SOURCE_DATE_EPOCH": "99999999999999"}), 2, "SOURCE_DATE_EPOCH: expected whole seconds since 1970-01-01 UTC (0..253402300799"),
    ("opt-scheduler-http", "--scheduler http://... (a dashboard's address)", lambda t: ["slam", "sweep", small_log(t), "--profile", "sim-park-laser", "--scheduler", "http://127.0.0.1:8787", "--out", str(t / "sw")], 2, "--scheduler http://127.0.0.1:8787: detcal reaches a Dask scheduler over tcp://"),
    ("opt-seeds-billion", "--seeds 1000000000", lambda t: ["slam", "sweep", small_log(t), "--profile", "sim-park-laser", "--seeds", "1000000000", "--out", str(t / "sw")], 2, "--seeds: '1000000000' gives 1000000000 seeds, more than one sweep runs (at most 10000)"),
    ("opt-seeds-overflow", "--seeds 10^20 (beyond a machine integer)", lambda t: ["slam", "sweep", small_log(t), "--profile", "sim-park-laser", "--seeds", "100000000000000000000", "--out", str(t / "sw")], 2, "--seeds: '100000000000000000000' gives 100000000000000000000 seeds"),
    ("opt-seeds-range-overflow", "--seeds range of seeds beyond 2^63", lambda t: ["slam", "sweep", small_log(t), "--profile", "sim-park-laser", "--seeds", "99999999999999999999-99999999999999999999", "--out", str(t / "sw")], 2, "--seeds: a seed above 9223372036854775807"),
    ("kitti-huge-frame", "a 1.6 GB KITTI .bin (10^8 points in one frame)", lambda t: ["log", "info", sparse(t, "big.bin", 1_600_000_000)], 1, "big.bin: 100000000 points in one frame (1.6 GB); a lidar frame holds far fewer"),
    ("config-duplicate-key", "config with a key given twice", lambda t: sim_config(t, "park", "width: 60\nbushes: {count: 3}\nwidth: 80\n"), 2, "c.yaml:3: not valid YAML (key 'width' is given twice (first on line 1))"),
    ("config-duplicate-nested-key", "config with a nested key given twice", lambda t: sim_config(t, "park", "path:\n  margin: 5\n  margin: 6\n"), 2, "c.yaml:3: not valid YAML (key 'margin' is given twice (first on line 2))"),
    ("profile-duplicate-key", "profile with range_max given twice", lambda t: ["profile", "validate", duplicated_key_profile(t)], 1, "p.yaml:27: not valid YAML/JSON (key 'range_max' is given twice (first on line 26))"),
    ("profile-json-duplicate-key", "JSON profile with a key given twice", lambda t: ["profile", "validate", text(t, "p.json", '{"name": "a", "name": "b"}')], 1, "p.json: not valid JSON (key 'name' is given twice in one object)"),
    ("profile-range-order", "profile with range_min above range_max", lambda t: ["profile", "validate", profile_text(t, sensor__range_min=100.0)], 1, "p.yaml: sensor: range_min (100 m) must be below range_max (80 m)"),
    ("profile-increment-zero", "profile with angle_increment 0", lambda t: ["profile", "validate", profile_text(t, sensor__angle_increment=0.0)], 1, "p.yaml: sensor: angle_increment is 0: the 361 beams would all point the same way"),
    ("profile-beams-billion", "profile with n_beams 10^9", lambda t: ["profile", "validate", profile_text(t, sensor__n_beams=10**9)], 1, "p.yaml: sensor.n_beams: Input should be less than or equal to 100000"),
    ("profile-fan-turns", "profile whose beams span more than a turn", lambda t: ["profile", "validate", profile_text(t, sensor__angle_increment=0.1)], 1, "p.yaml: sensor: 361 beams every 0.1 rad span 36 rad, more than a full turn"),
    ("profile-angle-min", "profile with angle_min of 7 rad", lambda t: ["profile", "validate", profile_text(t, sensor__angle_min=7.0)], 1, "p.yaml: sensor: angle_min (7 rad) is beyond a full turn"),
    ("utias-barcode-twice", "UTIAS barcode listed for two subjects", lambda t: ["log", "info", utias_copy(t, _edit_row("Barcodes.dat", 7, 1, "27"))], 1, "Barcodes.dat:12: subject barcode: barcode 27 is listed twice (line 11 with subject 7, this line with subject 8)"),
    ("utias-subject-twice", "UTIAS landmark subject listed twice", lambda t: ["log", "info", utias_copy(t, _edit_row("Landmark_Groundtruth.dat", 3, 0, "6"))], 1, "Landmark_Groundtruth.dat:"),
    ("utias-odometry-one-time", "UTIAS odometry all stamped at one time", lambda t: ["slam", "run", utias_copy(t, same_stamp), "--profile", "sim-park-laser"], 1, "Robot1_Odometry.dat: every one of the 1500 odometry records is stamped 0.0 s; the odometry carries no time"),
    ("utias-speed", "UTIAS odometry speed of 1e300 m/s", lambda t: ["log", "info", utias_copy(t, _edit_row("Robot1_Odometry.dat", 5, 1, "1e300"))], 1, "Robot1_Odometry.dat:6: t v omega: speed beyond 2 m/s"),
    ("utias-bearing", "UTIAS bearing of 9 rad", lambda t: ["log", "info", utias_copy(t, _edit_row("Robot1_Measurement.dat", 2, 3, "9"))], 1, "Robot1_Measurement.dat:3: t barcode range bearing: bearing outside -pi..pi rad"),
    ("vp-speed", "Victoria Park speed of 1e300 on one line", lambda t: ["slam", "run", vp_copy(t, _edit_row("inputs.dat", 300, 1, "1e300")), "--profile", "sim-park-laser"], 1, "inputs.dat:301: t speed steering: speed beyond 40 m/s"),
    ("vp-steering", "Victoria Park steering of 3 rad", lambda t: ["log", "info", vp_copy(t, _edit_row("inputs.dat", 10, 2, "3"))], 1, "inputs.dat:11: t speed steering: steering beyond 1 rad"),
    ("vp-range", "Victoria Park range beyond the laser's 80 m", lambda t: ["log", "info", vp_copy(t, _edit_row("measurements.dat", 4, 1, "500"))], 1, "measurements.dat:5: t range bearing diameter: range beyond the laser's 80 m"),
    # ---- physically implausible profiles (profiles.plausibility) and profile migration / rebuilding
    ("profile-covariance-condition", "Hotelling covariance of condition number 1e7", lambda t: ["profile", "validate", profile_text(t, hotelling__covariance=[[1.0, 0.0, 0.0], [0.0, 1e-7, 0.0], [0.0, 0.0, 1.0]])], 1, "p.yaml: hotelling: covariance has condition number 1e+07, beyond 1e+06"),
    ("profile-covariance-indefinite", "Hotelling covariance with a negative eigenvalue", lambda t: ["profile", "validate", profile_text(t, hotelling__covariance=[[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]])], 1, "p.yaml: hotelling: covariance is not positive definite"),
    ("profile-clutter-band", "clutter rate of 20,000 per frame", lambda t: ["profile", "validate", profile_text(t, clutter__rate=20000.0, clutter__kappa=None)], 1, "p.yaml: clutter.rate: 20000 false alarms per frame is beyond the plausible band [0, 10000]"),
    ("profile-clutter-beams", "clutter rate above what a 361-beam scan can hold", lambda t: ["profile", "validate", profile_text(t, clutter__rate=200.0, clutter__kappa=None)], 1, "p.yaml: clutter.rate: 200 false alarms per frame is more than a scan of 361 beams can hold (120.333"),
    ("profile-pd-never", "P_D table of zeros", lambda t: ["slam", "run", small_log(t), "--profile", pd_profile(t, 0.0)], 1, "p.yaml: pd: every P_D bin is 0: the profile says no feature is ever seen"),
    ("profile-pd-always", "P_D 1 everywhere and no clutter", lambda t: ["profile", "validate", pd_profile(t, 1.0, clutter__rate=0.0, clutter__kappa=None)], 1, "p.yaml: pd: every P_D bin is 1 and clutter.rate is 0"),
    ("profile-migrate-over", "profile migrate onto an existing file", lambda t: ["profile", "migrate", legacy_profile(t), "--out", text(t, "notes.yaml", "my: notes\n")], 2, "notes.yaml: exists; a migrated profile is never written over a file"),
    ("profile-rebuild-by-hand", "profile rebuild of a hand-written profile", lambda t: ["profile", "rebuild", str(VENDORED.parents[1] / "benchmarks/profiles/victoria-park-nominal@1.0.0.yaml")], 1, "provenance.command: 'written by hand (nominal assumptions, see description)' is not a detcal command"),
    ("profile-rebuild-keep-over", "profile rebuild --keep onto an existing file", lambda t: ["profile", "rebuild", profile_text(t), "--keep", text(t, "notes.yaml", "my: notes\n")], 2, "notes.yaml: exists; a rebuilt profile is never written over a file"),
    ("out-full-disk", "profile export into a folder whose disk is full", lambda t: Case(["profile", "export", "sim-park-laser", "--out", str(_folder(t, "diskfull") / "p.yaml")], patch=full_disk_in("diskfull")), 2, "diskfull/p.yaml: cannot write (No space left on device)"),
    ("out-bag-disk-full", "ROS 2 bag on a disk that fills while it is written", lambda t: Case(["log", "convert", interlaced_log(t), str(t / "bag")], patch=bag_disk_full(3)), 2, "bag: cannot write (the bag's sqlite3 database: database or disk is full)"),
]  # fmt: skip


def _drop_member(t: Path) -> str:
    src = Path(small_log(t))
    out = t / "h.dlog"
    with zipfile.ZipFile(src) as zf, zipfile.ZipFile(out, "w") as zo:
        for n in zf.namelist():
            if n != "odometry/values.npy":
                zo.writestr(n, zf.read(n))
    return str(out)


def _bracketed(t: Path) -> str:
    d = t / "run[v2]" / "line 100 :100: [b]a["
    d.mkdir(parents=True)
    return text(d, "b].dlog", "x")


def empty_scans_log(t: Path) -> str:
    """A native log whose scan stream holds no scan (the other streams as full_log's)."""
    import dataclasses

    from calib.io.native import write_native
    from detectors.sensor_log import ScanBatch
    from tests.calib.io.test_native import full_log

    log = full_log()
    empty = ScanBatch(np.zeros(0, np.int64), np.zeros((0, log.sensor.n_beams), np.float32))
    write_native(dataclasses.replace(log, scans=empty), t / "e.dlog")
    return str(t / "e.dlog")


def _in_a_run_folder(t: Path, name: str, content: bytes) -> str:
    """A file inside a folder detcal wrote (its marker inside): the input of a command whose --out that folder is."""
    from profiles.atomic import MARKER

    d = t / "run"
    d.mkdir()
    (d / MARKER).write_text("")
    (d / name).write_bytes(content)
    return str(d / name)


def _run_with_log(t: Path) -> str:
    return _in_a_run_folder(t, "ok.dlog", Path(small_log(t)).read_bytes())


def _run_with_config(t: Path) -> str:
    return _in_a_run_folder(t, "c.yaml", b"width: 60\n")


def _foreign_dir(t: Path, name: str = "mine") -> str:
    d = t / name
    d.mkdir(exist_ok=True)
    (d / "thesis.tex").write_text("years of work")
    return str(d)


def run_case(tmp: Path, build, capsys=None) -> tuple[int, str, str]:
    argv = build(tmp)
    if isinstance(argv, Case):
        with pytest.MonkeyPatch.context() as mp:
            for k, v in (argv.env or {}).items():
                if v is None:
                    mp.delenv(k, raising=False)
                else:
                    mp.setenv(k, v)
            if argv.patch is not None:
                argv.patch(mp)
            return run_case(tmp, lambda _t: argv.argv, capsys)
    if capsys is None:
        import contextlib

        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(argv)
        return code, out.getvalue(), err.getvalue()
    code = main(argv)
    cap = capsys.readouterr()
    return code, cap.out, cap.err


@pytest.mark.parametrize(("case", "what", "build", "code", "needle"), CASES, ids=[c[0] for c in CASES])
def test_bad_input(tmp_path, capsys, case, what, build, code, needle):
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    got, _, err = run_case(tmp_path, build, capsys)
    assert "Traceback" not in err
    lines = [x for x in err.splitlines() if x.strip()]
    if case == "opt-unknown":  # typer's own usage error: a short usage block, exit 2
        assert got == 2 and needle in err
        return
    assert got == code, err
    assert len(lines) == 1 and lines[0].startswith("detcal: error: ") and needle in lines[0], err
    after = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    made = [p for p in after if p not in before and not str(p).startswith(".")]
    assert all(p.parts[0] in _inputs_of(case) for p in made), f"left behind: {made}"


def _inputs_of(case: str) -> set[str]:
    """Files a case builds as its input (everything else must not appear)."""
    return {
        "t.clf", "x.clf.bz2", "c.clf.bz2", "i.clf", "i.dlog", "x.dlog", "cut.dlog", "ok.dlog", "src.dlog", "f.dlog", "h.dlog", "c.yaml",
        "p.yaml", "p.json", "l.csv", "utias", "run[v2]", "mine", "d.dlog", "plain", "notes.yaml", "e.dlog", "run", "vp",
        "enc.dlog", "cm.dlog", "d.clf.gz", "big.bin", "diskfull",
    }  # fmt: skip


if __name__ == "__main__":  # the table for a report: what each bad input gives
    import tempfile

    print("| case | bad input | exit | message |\n|---|---|---|---|")
    for case, what, build, _, _ in CASES:
        with tempfile.TemporaryDirectory() as d:
            code, _, err = run_case(Path(d), build)
        msg = " ".join(err.split()).replace(d, "<tmp>").replace("|", "\\|")
        print(f"| {case} | {what} | {code} | {msg[:300]} |")
