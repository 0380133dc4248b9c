"""detcal calibrate as one step: conflicts found before any work, reruns that are no conflict, no shadowing."""

import dataclasses
import os

import numpy as np
import pytest
import yaml

import calib.calibrate
from calib.io.native import write_native
from calib.truth import check_within_truth, trim_to_truth
from detectors.sensor_log import ReferencePoses
from profiles.errors import DataError
from profiles.store import BUILTIN
from tests.calib.test_calibrate import park
from tests.detcal.cli.test_cli import assert_one_line_error, run


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """One calibration of a small park: its log, profile folder and run folder."""
    from detcal.cli import main

    d = tmp_path_factory.mktemp("pipeline")
    log = write_native(park(41, 0.5), d / "a.dlog")
    (d / "c.yaml").write_text("pd: {min_count: 30}\n")
    args = ["calibrate", str(log), "--name", "small", "--config", str(d / "c.yaml"), "--profiles-dir", str(d / "profiles")]
    assert main([*args, "--out", str(d / "run")]) == 0
    return d, args


def no_work(monkeypatch):
    def refuse(*a, **k):
        raise AssertionError("the calibration ran although the request conflicts")

    monkeypatch.setattr(calib.calibrate, "calibrate", refuse)


def test_another_request_under_an_existing_version_is_refused_before_any_work(calibrated, capsys, monkeypatch):
    d, args = calibrated
    no_work(monkeypatch)
    other = write_native(park(42, 0.5), d / "b.dlog")
    code, _, err = run(capsys, "calibrate", str(other), *args[2:], "--out", str(d / "run_b"))
    assert code == 2
    assert_one_line_error(err, "profile small@1.0.0 exists with other content; bump the version")
    # other parameters are another request too
    (d / "c2.yaml").write_text("pd: {min_count: 31}\n")
    code, _, err = run(capsys, *args[:5], str(d / "c2.yaml"), *args[6:], "--out", str(d / "run_c"))
    assert code == 2 and "exists with other content" in err
    assert not (d / "run_b").exists() and not (d / "run_c").exists()


def test_a_rerun_of_the_same_request_is_no_conflict(calibrated, capsys, monkeypatch):
    """Another creation time and another command line (--out) do not make another profile."""
    d, args = calibrated
    before = (d / "profiles/small@1.0.0.yaml").read_bytes()
    monkeypatch.delenv("SOURCE_DATE_EPOCH")
    code, out, err = run(capsys, *args, "--out", str(d / "run2"))
    assert code == 0, err
    assert "small@1.0.0 (unchanged" in out and (d / "run2/profile.yaml").is_file()
    assert (d / "profiles/small@1.0.0.yaml").read_bytes() == before
    # the existing run folder of the same request is left alone, without --force
    mtime = (d / "run/profile.yaml").stat().st_mtime_ns
    code, out, err = run(capsys, *args, "--out", str(d / "run"))
    assert code == 0, err
    assert "(unchanged)" in out and (d / "run/profile.yaml").stat().st_mtime_ns == mtime


def test_a_run_folder_of_another_request_is_refused(calibrated, capsys, monkeypatch):
    d, args = calibrated
    no_work(monkeypatch)
    code, _, err = run(capsys, *args[:3], "other", *args[4:], "--out", str(d / "run"))
    assert code == 2
    assert_one_line_error(err, "run: already exists (use --force to replace it)")


def test_force_never_replaces_what_detcal_did_not_write(calibrated, capsys, monkeypatch):
    d, args = calibrated
    no_work(monkeypatch)
    (d / "mine").mkdir()
    (d / "mine/thesis.tex").write_text("years of work")
    code, _, err = run(capsys, *args, "--out", str(d / "mine"), "--force")
    assert code == 2
    assert_one_line_error(err, "mine: was not written by detcal (no .detcal-output inside); --force does not replace it")
    (d / "afile").write_text("x")
    code, _, err = run(capsys, *args, "--out", str(d / "afile"), "--force")
    assert code == 2
    assert_one_line_error(err, "afile: exists and is not a folder; --force replaces only a folder detcal wrote")
    assert (d / "mine/thesis.tex").read_text() == "years of work" and (d / "afile").read_text() == "x"


def test_a_bundled_profile_is_never_shadowed(calibrated, capsys, monkeypatch):
    d, args = calibrated
    no_work(monkeypatch)
    code, _, err = run(capsys, *args[:3], "sim-park-laser", *args[4:], "--out", str(d / "run_s"))
    assert code == 2
    assert_one_line_error(err, "profile sim-park-laser@1.0.0 is bundled with detcal with other content")
    # a copy left in a user folder by hand is shown as shadowing, and resolve says which file wins
    user = d / "user"
    user.mkdir()
    (user / "sim-park-laser@1.0.0.yaml").write_bytes((BUILTIN / "sim-park-laser@1.0.0.yaml").read_bytes())
    monkeypatch.setenv("DETCAL_PROFILES", str(user))
    code, out, _ = run(capsys, "profile", "list")
    assert code == 0
    rows = [ln for ln in out.splitlines() if "sim-park-laser@1.0.0" in ln]
    assert any("builtin" in r and "shadowed by" in r for r in rows) and any("user" in r and "active" in r for r in rows)


def test_the_list_marks_files_that_do_not_hold_what_their_name_says(tmp_path, capsys, monkeypatch):
    user = tmp_path / "user"
    user.mkdir()
    (user / "newer@1.0.0.yaml").write_text("schema_version: 4\nname: newer\nversion: 1.0.0\n")
    (user / "other@2.0.0.yaml").write_bytes((BUILTIN / "sim-park-laser@1.0.0.yaml").read_bytes())
    monkeypatch.setenv("DETCAL_PROFILES", str(user))
    from detcal.cli.common import out

    monkeypatch.setattr(out, "width", 300)  # one table row per line
    code, out, _ = run(capsys, "profile", "list")
    assert code == 0
    row = {p: next(ln for ln in out.splitlines() if p in ln) for p in ("newer@1.0.0", "other@2.0.0", "sim-park-laser@1.0.0")}
    assert "unreadable (schema_version 4 is newer than this detcal reads" in row["newer@1.0.0"]
    assert "holds sim-park-laser@1.0.0, not what its file name says" in row["other@2.0.0"]
    assert "active" in row["sim-park-laser@1.0.0"]
    # a DETCAL_PROFILES entry that is a file is said, not silently listed as empty
    (tmp_path / "notes.txt").write_text("x")
    monkeypatch.setenv("DETCAL_PROFILES", f"{user}{os.pathsep}{tmp_path / 'notes.txt'}")
    code, _, err = run(capsys, "profile", "list")
    assert code == 0 and "notes.txt: a user profile folder is a file; skipped" in err


def test_records_outside_the_truth_span(capsys, tmp_path):
    """The library refuses them; the command line drops them and says how many."""
    log = park(43, 0.5)
    ref = log.reference["ground_truth"]
    late = dataclasses.replace(log, reference={"ground_truth": ReferencePoses("ground_truth", ref.stamp[40:], ref.poses[40:])})
    first_kept = int(np.searchsorted(log.scans.stamp, ref.stamp[40]))
    with pytest.raises(DataError, match=rf"{first_kept} scans lie outside the ground truth's time span"):
        check_within_truth(late)
    trimmed, dropped = trim_to_truth(late)
    assert dropped == {"scans": first_kept} and len(trimmed.scans) == len(log.scans) - first_kept
    p = write_native(late, tmp_path / "late.dlog")
    (tmp_path / "c.yaml").write_text("pd: {min_count: 30}\n")
    code, _, err = run(capsys, "calibrate", str(p), "--config", str(tmp_path / "c.yaml"), "--profiles-dir", str(tmp_path / "p"), "--out", str(tmp_path / "r"))
    assert code == 0, err
    assert f"detcal: warning: log 'park_seed43': {first_kept} scans outside the ground truth's time span dropped" in err
    assert yaml.safe_load((tmp_path / "r/summary.yaml").read_text())["scans"] == len(log.scans) - first_kept


@pytest.mark.slow  # end to end: whole simulated runs, tens of CPU seconds; make test-slow (CI) runs it
def test_the_bundled_profile_is_reproduced_from_the_embedded_default(tmp_path, capsys):
    """What `make demo` and `make builtin-profile` do, on this machine's freshly simulated default log.

    The default log is simulated anew into a private cache; its content digest and the calibration's
    parameters must be the bundled profile's, and so must every field of the result but `created`
    and `command`: the store reports the bundled file as the profile (nothing is written beside it).
    """
    from profiles.store import BUILTIN, dump_profile, load_profile_file, same_content

    bundled = BUILTIN / "sim-park-laser@1.0.0.yaml"
    # written by this detcal as it stands (a field added to the schema since would be missing: make builtin-profile)
    assert dump_profile(load_profile_file(bundled)) == bundled.read_text()
    code, out, err = run(capsys, "calibrate", "--out", str(tmp_path / "demo"), "--profiles-dir", str(tmp_path / "p"))
    assert code == 0, err
    assert "(bundled)" in out and not (tmp_path / "p").exists()
    assert same_content(load_profile_file(tmp_path / "demo/profile.yaml"), load_profile_file(BUILTIN / "sim-park-laser@1.0.0.yaml"))


def test_detection_frames_before_the_first_truth_pose():
    """A camera log whose truth starts late: the library refuses it, the trimmed log keeps only frames with a pose."""
    from calib.detlevel import DetectionCalibConfig, calibrate_detections
    from calib.io.registry import read_log
    from tests.conftest import VENDORED

    log = read_log(VENDORED / "utias_dataset1")
    ref = log.reference["ground_truth"]
    start = int(np.searchsorted(ref.stamp, log.detections.frame_stamp[10]))
    late = dataclasses.replace(log, reference={"ground_truth": ReferencePoses("ground_truth", ref.stamp[start:], ref.poses[start:])})
    with pytest.raises(DataError, match=r"detection frames lie outside the ground truth's time span"):
        calibrate_detections([late], DetectionCalibConfig(), name="x", version="1.0.0")
    trimmed, dropped = trim_to_truth(late)
    first = int(np.searchsorted(log.detections.frame_stamp, ref.stamp[start]))
    assert dropped == {"detection frames": first} and trimmed.detections.n_frames == log.detections.n_frames - first
    assert trimmed.detections.frame_stamp[0] >= ref.stamp[start] and len(trimmed.detections) < len(log.detections)
    check_within_truth(trimmed)
