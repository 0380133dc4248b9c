import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import yaml

from profiles.errors import DataError, UsageError
from profiles.profile import DetectorProfile
from profiles.store import diff_profiles, dump_profile, load_profile_file, profile_path, registry, resolve, save_profile
from profiles.override import updated


def make_profile(version="1.0.0", rate=5.5, **kw) -> DetectorProfile:
    return DetectorProfile.model_validate(
        {
            "name": "test-laser",
            "version": version,
            "detector": {"kind": "circle2d"},
            "sensor": {"kind": "laser2d", "n_beams": 361, "angle_min": -1.5707963267948966, "angle_increment": 0.008726646259971648, "range_max": 80.0, "range_sigma": 0.02},
            "hotelling": {"names": ["log_radius", "rel_convexity"], "mean": [-1.3, 0.75], "covariance": [[0.2, 0.01], [0.01, 0.03]], "gamma": 13.815510557964274},
            "pd": {"edges": [0, 1, 2, 3, 4], "pd": [0.0, 0.0, 0.3, 0.1 / 3], "counts": [10, 20, 30, 40]},
            "clutter": {"rate": rate, "volume": 251.32741228718345, "p_value": 1e-240},
            "provenance": {"detcal_version": "0.1.0", "created": "2026-11-21T00:00:00Z", "inputs": [{"name": "a", "sha256": "0" * 64}]},
            **kw,
        }
    )


def test_yaml_and_json_round_trips_are_lossless_once_written(tmp_path):
    """A written profile holds its fitted figures to six significant digits; reading it back and writing it again
    gives the same bytes, in YAML and in JSON, and the given figures (the sensor) are kept exactly."""
    p = make_profile()
    path, status = save_profile(p, tmp_path)
    assert status == "written" and path.name == "test-laser@1.0.0.yaml"
    back = load_profile_file(path)
    assert back.pd.pd[3] == 0.0333333 and back.clutter.p_value == 1e-240 and back.sensor.angle_increment == 0.008726646259971648
    assert dump_profile(back) == dump_profile(p) == path.read_text()
    (tmp_path / "p.json").write_text(dump_profile(p, "json"))
    assert load_profile_file(tmp_path / "p.json") == back
    assert dump_profile(load_profile_file(tmp_path / "p.json"), "json") == dump_profile(p, "json")


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d["clutter"].update(lamda=3), r"clutter.lamda: unknown key"),
        (lambda d: d["sensor"]["mount"].update(z=1.0), r"sensor.mount.z: unknown key"),
        (lambda d: d.update(colour="red"), r"colour: unknown key"),
        (lambda d: d["pd"]["pd"].__setitem__(1, 1.5), r"pd: pd values must lie in \[0, 1\]"),
        (lambda d: d["clutter"].update(rate=-1), r"clutter.rate: Input should be greater than or equal to 0"),
        (lambda d: d.update(version="1.0"), r"version: '1.0' is not a semantic version"),
        (lambda d: d["hotelling"].update(covariance=[[1, 2], [2, 1]]), r"hotelling: covariance is not positive definite"),
        (lambda d: d["detector"]["circle"].update(jump=0), r"detector.circle.jump: Input should be greater than 0"),
    ],
)
def test_bad_profiles_are_rejected_with_the_field_path(tmp_path, edit, match):
    d = make_profile().model_dump(mode="json")
    edit(d)
    f = tmp_path / "bad.yaml"
    f.write_text(yaml.safe_dump(d))
    with pytest.raises(DataError, match="bad.yaml: " + match):
        load_profile_file(f)


def test_other_schema_versions_are_refused_by_name(tmp_path):
    d = make_profile().model_dump(mode="json")
    for v, match in ((4, "schema_version 4 is newer than this detcal reads"), (0, "schema_version 0 is not supported")):
        d["schema_version"] = v
        (tmp_path / "v.yaml").write_text(yaml.safe_dump(d))
        with pytest.raises(DataError, match=match):
            load_profile_file(tmp_path / "v.yaml")


def test_existing_versions_are_never_silently_replaced(tmp_path):
    save_profile(make_profile(), tmp_path)
    assert save_profile(make_profile(), tmp_path)[1] == "unchanged"  # same content: nothing written
    before = (tmp_path / "test-laser@1.0.0.yaml").read_bytes()
    with pytest.raises(UsageError, match="exists with other content; bump the version"):
        save_profile(make_profile(rate=6.0), tmp_path)
    assert (tmp_path / "test-laser@1.0.0.yaml").read_bytes() == before
    assert save_profile(make_profile(rate=6.0), tmp_path, force=True)[1] == "replaced"
    assert save_profile(make_profile("1.1.0", rate=7.0), tmp_path)[1] == "written"


def test_a_rerun_that_rounds_differently_is_the_same_profile_not_a_conflict(tmp_path):
    """A calibration rerun under another numpy or BLAS build rounds its sums differently in the last bits (the
    bundled profile's Hotelling covariance moved by 1-2 units in the last place between numpy builds): that is
    the same content, so saving it again reports the profile unchanged and leaves the file as it was. A number
    changed beyond the tolerance (relative 1e-9), a string or a count is other content, refused as before."""
    from profiles.store import SAME_REL_TOL, same_content

    p = make_profile()
    path, _ = save_profile(p, tmp_path)
    before = path.read_bytes()
    cov = [[np.nextafter(0.2, 1.0), 0.01], [0.01, np.nextafter(0.03, 0.0)]]
    rerun = updated(p, {"hotelling.covariance": cov})
    assert rerun != p and same_content(rerun, p)
    assert save_profile(rerun, tmp_path) == (path, "unchanged") and path.read_bytes() == before
    for other in (
        updated(p, {"clutter.rate": 5.5 * (1 + 10 * SAME_REL_TOL), "clutter.kappa": None}),
        updated(p, {"pd.counts": [10, 20, 30, 41]}),
        updated(p, {"hotelling.names": ["log_radius", "convexity"]}),
    ):
        assert not same_content(other, p)
        with pytest.raises(UsageError, match="exists with other content"):
            save_profile(other, tmp_path)
    assert path.read_bytes() == before


def test_registry_resolves_newest_and_exact_versions(tmp_path, monkeypatch):
    monkeypatch.setenv("DETCAL_PROFILES", str(tmp_path))
    for v, r in (("1.0.0", 1.0), ("1.10.0", 2.0), ("1.9.3", 3.0)):
        save_profile(make_profile(v, rate=r), tmp_path)
    assert resolve("test-laser").version == "1.10.0"  # semantic, not lexical, order
    assert resolve("test-laser@1.9.3").clutter.rate == 3.0
    assert {e.version for e in registry() if e.name == "test-laser"} == {"1.0.0", "1.10.0", "1.9.3"}
    with pytest.raises(UsageError, match="no profile 'test-laser@2.0.0'; known: .*test-laser@1.0.0"):
        resolve("test-laser@2.0.0")
    assert resolve(str(tmp_path / "test-laser@1.0.0.yaml")).clutter.rate == 1.0
    # the file a reference names, by name or by path: what --force must not replace while it is an input
    assert profile_path("test-laser") == tmp_path / "test-laser@1.10.0.yaml"
    assert profile_path("test-laser@1.0.0") == profile_path(str(tmp_path / "test-laser@1.0.0.yaml"))
    from detcal.cli.common import fresh
    from profiles.store import looks_like_profile

    with pytest.raises(UsageError, match="test-laser@1.0.0.yaml: is the input, which --force would delete"):
        fresh(tmp_path / "test-laser@1.0.0.yaml", True, directory=False, owned=looks_like_profile, inputs=[profile_path("test-laser@1.0.0")])


def test_diff_names_changed_fields():
    rows = dict((k, (a, b)) for k, a, b in diff_profiles(make_profile(), make_profile("1.0.1", rate=6.0)))
    assert rows["version"] == ("1.0.0", "1.0.1") and rows["clutter.rate"] == (5.5, 6.0)
    assert len(rows) == 3 and "clutter.kappa" in rows  # kappa follows the rate


def test_killed_writer_leaves_no_partial_profile(tmp_path):
    """SIGKILL the writer in the middle of writing: the old profile stays whole, no new one appears."""
    save_profile(make_profile(), tmp_path)
    before = (tmp_path / "test-laser@1.0.0.yaml").read_bytes()
    script = textwrap.dedent(
        f"""
        import builtins, sys, time
        sys.path.insert(0, {os.getcwd()!r})
        import profiles.store as st
        from tests.profiles.test_store import make_profile
        real_open = builtins.open
        def open_slow(f, mode="r", *a, **k):
            fh = real_open(f, mode, *a, **k)
            if "w" in mode and str(f).endswith(".part"):
                write = fh.write
                def half_then_hang(s):
                    write(s[: len(s) // 2])
                    fh.flush()
                    print("HALF", flush=True)
                    time.sleep(60)
                    return write(s[len(s) // 2 :])
                fh.write = half_then_hang
            return fh
        builtins.open = open_slow
        st.save_profile(make_profile(rate=9.0), {str(tmp_path)!r}, force=True)
        """
    )
    with subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True) as proc:
        assert proc.stdout.readline().strip() == "HALF"  # the writer is mid-file
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    assert (tmp_path / "test-laser@1.0.0.yaml").read_bytes() == before
    assert load_profile_file(tmp_path / "test-laser@1.0.0.yaml").clutter.rate == 5.5
    # the half-written temporary is a dot-file the registry ignores
    leftovers = [p.name for p in tmp_path.iterdir() if p.name != "test-laser@1.0.0.yaml"]
    assert leftovers and all(n.startswith(".") and n.endswith(".part") for n in leftovers)
    with_env = {e.path for e in registry()}
    assert not any(p.name.startswith(".") for p in with_env)


def v2_profile() -> DetectorProfile:
    d = make_profile().model_dump(mode="json")
    d["schema_version"] = 2
    d["detector"] = {"kind": "external", "association_gate": 1.0}
    d["sensor"] = {"kind": "camera", "fov": 1.2, "range_max": 6.0}
    d.pop("hotelling")
    d["pd"] = {
        "covariate": "range_bearing", "edges": [0, 3, 6], "bearing_edges": [-0.6, 0.0, 0.6], "pd": [[0.1, 0.2], [0.3, 0.4]],
        "model": "additive_logit",
        "selection": {"folds": "sensors (2)", "candidates": ["range", "additive_logit"], "loglik": [-0.6, -0.5], "items": 10, "chosen": "additive_logit"},
    }
    d["clutter"] = {
        "rate": 0.5, "volume": 7.2, "count_model": "negative_binomial", "size": 1.5,
        "dispersion_test": {"test": "lr", "statistic": 30.0, "dof": 1, "p_value": 1e-8},
        "density": {"range_edges": [0, 6], "bearing_edges": [-0.6, 0.6], "density": [[1 / 7.2]], "smoothing": 0.0},
    }
    return DetectorProfile.model_validate(d)


def test_schema_1_profiles_keep_their_bytes_and_load_migrated(tmp_path):
    from profiles.notices import collected

    p = make_profile(schema_version=1)
    text = dump_profile(p)
    assert text.startswith("schema_version: 1\n") and "count_model" not in text and "bearing_edges" not in text
    f = tmp_path / "old.yaml"
    f.write_text(text)
    assert dump_profile(load_profile_file(f, migrate=False)) == text
    with collected() as lines:
        back = load_profile_file(f)
    assert back.schema_version == 3 and back.clutter.count_model == "poisson" and back.pd.model == "binned"
    assert lines == [f"{f}: profile schema 1 migrated to schema 3 on loading (its content unchanged); `detcal profile migrate {f}` writes it as schema 3"]
    d = yaml.safe_load(text)
    d["clutter"]["count_model"] = "negative_binomial"
    d["clutter"]["size"] = 2.0
    f.write_text(yaml.safe_dump(d))
    with pytest.raises(DataError, match="old.yaml: .*clutter.count_model needs schema_version 2"):
        load_profile_file(f)


def test_schema_2_profiles_round_trip(tmp_path):
    p = v2_profile()
    path, _ = save_profile(p, tmp_path)
    back = load_profile_file(path, migrate=False)
    assert back == p and dump_profile(back) == path.read_text()
    assert load_profile_file(path, notify=False) == updated(p, {"schema_version": 3})
    assert back.clutter.count_pmf(np.arange(3)).sum() < 1 and back.clutter.count_variance == pytest.approx(0.5 + 0.25 / 1.5)


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d["clutter"]["density"].update(density=[[1.0]]), r"clutter.density: density integrates to 7.2 over the grid, not 1"),
        (lambda d: d["clutter"].update(size=None), r"clutter: size is given exactly when the count model is negative_binomial"),
        (lambda d: d["pd"].pop("bearing_edges"), r"pd: bearing_edges are given exactly when the covariate is range_bearing"),
        (lambda d: d["pd"]["selection"].update(chosen="grid"), r"pd.selection: chosen 'grid' is not one of the candidates"),
        (lambda d: d["pd"].update(counts=[[1, 2]]), r"pd: counts has shape \(1, 2\) for a 2x2 table"),
    ],
)
def test_bad_schema_2_fields_name_their_path(tmp_path, edit, match):
    d = v2_profile().model_dump(mode="json")
    edit(d)
    f = tmp_path / "bad.yaml"
    f.write_text(yaml.safe_dump(d))
    with pytest.raises(DataError, match="bad.yaml: " + match):
        load_profile_file(f)


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d["pd"].update(model="cells_shrunk"), r"pd: a cells_shrunk table needs its shrinkage"),
        (lambda d: d["pd"].update(shrinkage=5.0), r"pd: shrinkage belongs to cells_shrunk and partial_pooling tables"),
        (lambda d: d["pd"]["selection"].update(loglik=[-0.5]), r"pd.selection: loglik has 1 entries for 2 candidates"),
        (lambda d: d["clutter"].update(space="xy"), r"clutter: a clutter density is over range and bearing"),
        (lambda d: d["detector"].update(kind="circle2d"), r"\(top level\): a range_bearing P_D table is for detection-level sensors"),
        (
            lambda d: d.update(sensors={"names": ["a", "b"], "pairs": [1], "pd_observed": [0.1, 0.2], "pd_predicted": [0.1, 0.2], "frames": [1, 1],
                                        "clutter_rate": [0.1, 0.1], "pd_logit_offset": [0, 0], "pd_logit_sd": 0.0, "pd_between_sd": 0.0, "clutter_between_sd": 0.0}),
            r"sensors: pairs has 1 entries for 2 sensors",
        ),
    ],
)
def test_more_bad_schema_2_fields(tmp_path, edit, match):
    d = v2_profile().model_dump(mode="json")
    edit(d)
    f = tmp_path / "bad.yaml"
    f.write_text(yaml.safe_dump(d))
    with pytest.raises(DataError, match="bad.yaml: " + match):
        load_profile_file(f)


def test_table_lookups_refuse_the_wrong_covariates():
    p = v2_profile()
    with pytest.raises(ValueError, match="a range_bearing table needs range and bearing: use lookup_rb"):
        p.pd.lookup(np.array([1.0]))
    with pytest.raises(ValueError, match="a n_p table cannot be looked up by range and bearing"):
        make_profile().pd.lookup_rb(np.array([1.0]), np.array([0.0]))


def test_recorded_parameters_are_checked_the_same_without_calib(tmp_path):
    """A program that imports only ``profiles`` (a robot running slam_runtime) refuses a misspelt key of the
    recorded calibration parameters as ``detcal profile validate`` does, and never imports calib for it."""
    d = make_profile().model_dump(mode="json")
    d["provenance"]["parameters"] = {"pd": {"min_cont": 3}}  # CalibrateConfig's pd has min_count
    f = tmp_path / "p.yaml"
    f.write_text(yaml.safe_dump(d))
    code = textwrap.dedent(
        f"""
        import sys
        from profiles.errors import DataError
        from profiles.store import load_profile_file
        try:
            load_profile_file({str(f)!r})
        except DataError as exc:
            print(exc)
        print(sorted(m for m in sys.modules if m.split(".")[0] in ("calib", "detcal", "slam_runtime")))
        """
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.splitlines() == [f"{f}: provenance.parameters.pd.min_cont: unknown key", "[]"]


def test_a_profile_recorded_before_a_parameter_was_recorded_still_loads(tmp_path):
    """A profile written by an earlier build of this version, before `landmarks` and `range_sigma_source` were
    recorded, loads with its record as it is (it was refused: `provenance.parameters.landmarks: Field required`);
    a misspelt key is still refused."""
    import yaml

    from profiles.store import BUILTIN

    doc = yaml.safe_load((BUILTIN / "sim-park-laser@1.0.0.yaml").read_text())
    for key in ("landmarks", "range_sigma_source"):
        doc["provenance"]["parameters"].pop(key)
    (tmp_path / "old.yaml").write_text(yaml.safe_dump(doc))
    prof = load_profile_file(tmp_path / "old.yaml")
    assert "landmarks" not in prof.provenance.parameters and prof.sensor.n_beams == 361
    doc["provenance"]["parameters"]["landmark"] = "log"
    (tmp_path / "typo.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(DataError, match=r"typo.yaml: provenance.parameters.landmark: unknown key"):
        load_profile_file(tmp_path / "typo.yaml")
