import dataclasses
import json
import re

import numpy as np
import pytest
import yaml

from calib.io.native import write_native
from tests.calib.test_calibrate import park
from tests.detcal.cli.test_cli import assert_one_line_error, run


@pytest.mark.slow  # end to end: whole simulated runs, tens of CPU seconds; make test-slow (CI) runs it
def test_calibrate_validate_and_profile_commands(tmp_path, capsys):
    a = write_native(park(41, 1.0), tmp_path / "a.dlog")
    b = write_native(park(42, 1.0), tmp_path / "b.dlog")
    (tmp_path / "c.yaml").write_text("pd: {min_count: 50}\n")
    prof_dir = tmp_path / "profiles"
    args = ["calibrate", str(a), "--name", "small", "--config", str(tmp_path / "c.yaml"), "--profiles-dir", str(prof_dir)]
    code, out, err = run(capsys, *args, "--out", str(tmp_path / "run"))
    assert code == 0, err
    assert "small@1.0.0 (written" in out
    files = sorted(p.name for p in (tmp_path / "run").iterdir())
    assert files == sorted(
        [".detcal-output", "profile.yaml", "config.yaml", "summary.yaml", "quality.yaml", "detections.csv.gz", "pairs.csv.gz", "pd_vs_np.png", "roc.png", "clutter.png", "descriptors.png", "map.png", "pd_field.png", "warnings.yaml"]
    )
    saved = prof_dir / "small@1.0.0.yaml"
    assert saved.read_bytes() == (tmp_path / "run/profile.yaml").read_bytes()
    # provenance: the full command with every path as the same command would name it from here (no absolute path of
    # this machine), the source commit when detcal runs from a git checkout, the numerical packages' versions
    from pathlib import Path

    from profiles.store import load_profile_file

    prov = load_profile_file(saved).provenance
    words = prov.command.split()
    assert words[:2] == ["detcal", "calibrate"] and not any(w.startswith("/") for w in words), prov.command
    assert (Path.cwd() / words[2]).resolve() == a.resolve() and "--profiles-dir" in words and "--config" in words
    assert prov.commit is None or re.fullmatch(r"[0-9a-f]{40}(\+dirty)?", prov.commit)
    assert prov.packages["numpy"] == np.__version__ and "scipy" in prov.packages
    code, out, _ = run(capsys, "profile", "show", str(saved))
    assert code == 0 and "P_D against n_p [points]" in out and "probability" in out and "false alarms /" in out
    # same inputs again: the profile is unchanged, not rewritten
    code, out, _ = run(capsys, *args, "--out", str(tmp_path / "run2"))
    assert code == 0 and "unchanged" in out
    # other data under the same version: refused, nothing replaced
    before = saved.read_bytes()
    code, _, err = run(capsys, "calibrate", str(b), *args[2:], "--out", str(tmp_path / "run3"))
    assert code == 2
    assert_one_line_error(err, "profile small@1.0.0 exists with other content; bump the version")
    assert saved.read_bytes() == before
    code, _, _ = run(capsys, "calibrate", str(b), *args[2:], "--out", str(tmp_path / "run3"), "--version", "1.1.0", "--force")
    assert code == 0
    # the registry sees both; validate with the newest
    code, out, err = run(capsys, "validate", str(prof_dir / "small@1.1.0.yaml"), str(a), "--out", str(tmp_path / "val"))
    # its own calibration log: nothing drifted, but one small park pins the profile's clutter rate too loosely to
    # tell a 25 % change (the default tolerance): too little data, exit code 4
    assert code == 4 and "verdict: too little data" in out and "drifted" not in out, out + err
    summary = yaml.safe_load((tmp_path / "val/summary.yaml").read_text())
    assert summary["ece"] < 0.05 and (tmp_path / "val/reliability.png").exists()
    # a log in which the laser saw nothing (every range NaN): no detection where the profile predicts many (n_p is
    # ray-traced from the truth, not read from the ranges); a report that says so, not a crash
    log = park(41, 1.0)
    blind = dataclasses.replace(log, scans=dataclasses.replace(log.scans, ranges=np.full_like(log.scans.ranges, np.nan)))
    code, out, err = run(capsys, "validate", str(prof_dir / "small@1.1.0.yaml"), str(write_native(blind, tmp_path / "blind.dlog")), "--out", str(tmp_path / "val_blind"))
    assert code == 3 and "verdict: drifted: P_D" in out, out + err  # a laser that sees nothing: drift (exit code 3)
    summary = yaml.safe_load((tmp_path / "val_blind/summary.yaml").read_text())
    assert summary["detections_observed"] == 0 and summary["detections_predicted"] > 100
    code, out, _ = run(capsys, "profile", "diff", str(saved), str(prof_dir / "small@1.1.0.yaml"))
    assert code == 0 and "clutter.rate" in out and "version" in out
    code, out, _ = run(capsys, "profile", "export", str(saved), "--format", "json")
    assert code == 0 and json.loads(out)["name"] == "small"
    code, out, _ = run(capsys, "profile", "schema")
    assert code == 0 and "DetectorProfile" in json.loads(out)["title"]
    code, out, _ = run(capsys, "profile", "validate", str(saved))
    assert code == 0 and "valid profile small@1.0.0" in out


def test_profile_errors(tmp_path, capsys):
    (tmp_path / "bad.yaml").write_text("schema_version: 1\nname: x\nversion: 1.0.0\nbogus: 1\n")
    code, _, err = run(capsys, "profile", "validate", str(tmp_path / "bad.yaml"))
    assert code == 1
    assert_one_line_error(err, "bad.yaml: ")
    code, _, err = run(capsys, "profile", "show", "nope@9.9.9")
    assert code == 2
    assert_one_line_error(err, "no profile 'nope@9.9.9'")
    assert "Profiles are searched in the bundled ones and in" in err and "give a profile file by its path" in err
    code, _, err = run(capsys, "calibrate", str(tmp_path / "missing.dlog"))
    assert code == 2
    assert_one_line_error(err, "missing.dlog: no such file")
    code, _, err = run(capsys, "calibrate", "--version", "one", str(tmp_path / "x.dlog"))
    assert code == 2
    assert_one_line_error(err, "--version: 'one' is not MAJOR.MINOR.PATCH")
