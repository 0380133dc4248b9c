"""The written profile (schema 3): units on every quantity, fitted figures rounded, one P_D bin per line."""

import difflib
import re
import typing

import numpy as np
import pytest
import yaml
from pydantic import BaseModel

from profiles.errors import DataError
from profiles.profile import DetectorProfile
from profiles.override import updated
from profiles.store import dump_profile, load_profile_file, parse_profile, same_content
from profiles.units import SIGNIFICANT, UNITS, models_of
from tests.profiles.test_store import make_profile, v2_profile


def wilson_profile(detections=(0, 5, 27, 38)) -> DetectorProfile:
    """A profile whose P_D table has every per-bin column (pd, counts, detections, Wilson bounds)."""
    from calib.fits import wilson

    counts = [10, 20, 30, 40]
    lo, hi = wilson(np.asarray(detections), np.asarray(counts))
    return make_profile(
        pd={"edges": [0, 1, 2, 3, 4], "pd": [d / n for d, n in zip(detections, counts, strict=True)], "counts": counts,
            "detections": list(detections), "wilson_low": [float(x) for x in lo], "wilson_high": [float(x) for x in hi]},
    )  # fmt: skip


def _numeric(annotation) -> bool:
    stack = [annotation]
    while stack:
        t = stack.pop()
        if t in (int, float):
            return True
        if not (isinstance(t, type) and issubclass(t, BaseModel)) and t is not dict:
            stack.extend(typing.get_args(t))
    return False


def test_every_numeric_field_of_a_profile_has_a_unit():
    seen = models_of(DetectorProfile)
    missing = [
        f"{m.__name__}.{name}" for m in seen for name, f in m.model_fields.items()
        if _numeric(f.annotation) and f"{m.__name__}.{name}" not in UNITS and name != "schema_version"
    ]  # fmt: skip
    assert len(seen) > 15 and not missing, missing


def test_fitted_figures_are_rounded_and_every_quantity_line_names_its_unit():
    p = wilson_profile()
    text = dump_profile(p)
    doc = yaml.safe_load(text)
    # fitted: six significant digits (1/3 is 0.333333), given: exact (the sensor's beam increment from a log header)
    assert [b["pd"] for b in doc["pd"]["bins"]] == [0.0, 0.25, 0.9, 0.95]
    assert doc["pd"]["bins"][0]["wilson_high"] == float(f"{p.pd.wilson_high[0]:.{SIGNIFICANT}g}") != p.pd.wilson_high[0]
    assert doc["sensor"]["angle_increment"] == 0.008726646259971648 and doc["clutter"]["volume"] == 251.327
    for line in text.split("provenance:")[0].splitlines():
        key, _, value = line.strip().partition(": ")
        if re.fullmatch(r"-?[0-9.e+-]+|\[[-0-9., e+]+\]", value.split("  #")[0]) and key not in ("schema_version", "version"):
            assert "  # " in line, f"no unit: {line}"
    assert "range_max: 80.0  # m" in text and "rate: 5.5  # false alarms / scan" in text and "kappa: 0.0218838  # false alarms / scan / (m rad)" in text


def test_a_change_in_one_bin_is_a_one_line_diff():
    """Two calibrations that differ in one P_D bin (its detections, rate and Wilson bounds) differ in one line."""
    a, b = dump_profile(wilson_profile()), dump_profile(wilson_profile(detections=(0, 5, 26, 38)))
    changed = [d for d in difflib.unified_diff(a.splitlines(), b.splitlines(), lineterm="", n=0) if d[:1] in "+-" and d[:3] not in ("+++", "---")]
    assert len(changed) == 2 and changed[0].startswith("-  - {from: 2.0, to: 3.0, pd: 0.9,") and changed[1].startswith("+  - {from: 2.0, to: 3.0, pd: 0.866667,")
    assert max(len(line) for line in a.splitlines()) > 100  # no wrapping: a long row stays one line


def test_the_written_document_reads_back(tmp_path):
    p = wilson_profile()
    doc = yaml.safe_load(dump_profile(p))
    back = parse_profile(doc, "p.yaml")
    assert back.pd.edges == p.pd.edges and back.pd.counts == p.pd.counts and dump_profile(back) == dump_profile(p)
    # a schema-2 profile read as its schema has it keeps its columns and its bytes; loaded, it is migrated to schema 3
    v2 = v2_profile()
    text = dump_profile(v2)
    assert "bins" not in text and "# " not in text and dump_profile(parse_profile(yaml.safe_load(text), "v2", migrate=False)) == text
    migrated = parse_profile(yaml.safe_load(text), "v2", notify=False)
    assert migrated.schema_version == 3 and same_content(migrated, updated(v2, {"schema_version": 3}))


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda bins: bins[2].update({"from": 2.5}), r"p.yaml: pd.bins.2.from: 2.5 is not the previous bin's end 2.0"),
        (lambda bins: bins[1].update(colour=1), r"p.yaml: pd.bins.1.colour: unknown key"),
        (lambda bins: bins[3].pop("counts"), r"p.yaml: pd.bins.3.counts: missing \(bin 0 gives counts\)"),
        (lambda bins: bins.clear(), r"p.yaml: pd.bins: a list of one or more bins"),
    ],
)
def test_bad_bins_name_the_bin_and_the_key(edit, match):
    doc = yaml.safe_load(dump_profile(wilson_profile()))
    edit(doc["pd"]["bins"])
    with pytest.raises(DataError, match=match):
        parse_profile(doc, "p.yaml")


def test_a_table_given_twice_is_refused():
    doc = yaml.safe_load(dump_profile(wilson_profile()))
    doc["pd"]["pd"] = [0.0, 0.0, 0.0, 0.0]
    with pytest.raises(DataError, match=r"p.yaml: pd.pd: given both as a column and in pd.bins"):
        parse_profile(doc, "p.yaml")


def test_a_schema_2_document_cannot_carry_schema_3_provenance(tmp_path):
    d = v2_profile().model_dump(mode="json")
    d["provenance"]["commit"] = "0" * 40
    (tmp_path / "old.yaml").write_text(yaml.safe_dump(d))
    with pytest.raises(DataError, match=r"old.yaml: \(top level\): provenance.commit needs schema_version 3 \(this document says 2\)"):
        load_profile_file(tmp_path / "old.yaml")
