"""paired.csv of a sweep: settings that differ in one label, compared run by run on the same log and seed."""

import numpy as np
import pytest

from detcal.reports.sweep import paired


def _rows():
    """2 logs x 3 seeds x filters (glmb, lmb) x P_D modes (profile, constant); map OSPA made so that glmb is
    lower than lmb by 0.01 + 0.002 * seed, and the calibrated P_D lower than the constant by 0.03 on log a, by 0.01
    on log b; a log's own offset (its data) is the same for every setting."""
    rows = []
    for log, off in (("a", 0.5), ("b", 0.1)):
        for f in ("glmb", "lmb"):
            for m in ("profile", "constant"):
                for s in range(3):
                    ospa = off + (0.0 if f == "lmb" else -(0.01 + 0.002 * s)) + (0.0 if m == "constant" else (-0.03 if log == "a" else -0.01))
                    rows.append({"log": log, "profile": "p@1", "filter": f, "pd_mode": m, "particles": 10, "seed": s, "map_ospa": ospa, "map_features": 9.0})
    return rows


def test_paired_differences_of_each_label_that_varies():
    out = paired(_rows())
    # two labels vary: filter (one comparison per P_D mode) and pd_mode (one per filter); two metrics each
    assert {(r["varies"], r["a"], r["b"]) for r in out} == {("filter", "glmb", "lmb"), ("pd_mode", "profile", "constant")}
    assert len(out) == 8
    f = [r for r in out if r["varies"] == "filter" and r["metric"] == "map_ospa"]
    assert [r["pd_mode"] for r in f] == ["profile", "constant"] and all(r["particles"] == 10 and r["profile"] == "p@1" for r in f)
    d = -(0.01 + 0.002 * np.array([0, 1, 2, 0, 1, 2]))  # the six (log, seed) pairs
    for r in f:
        assert r["pairs"] == 6 and r["a_lower"] == 6
        assert r["mean_difference"] == pytest.approx(d.mean(), abs=1e-12)
        assert r["standard_error"] == pytest.approx(d.std(ddof=1) / np.sqrt(6), abs=1e-12)
    p = [r for r in out if r["varies"] == "pd_mode" and r["metric"] == "map_ospa"]
    assert [r["filter"] for r in p] == ["glmb", "lmb"]
    for r in p:  # the logs' offsets (0.5 against 0.1) cancel within a pair: only the calibration's effect is left
        assert r["mean_difference"] == pytest.approx(-0.02, abs=1e-12) and r["a_lower"] == 6
        assert r["standard_error"] == pytest.approx(np.std([-0.03] * 3 + [-0.01] * 3, ddof=1) / np.sqrt(6), abs=1e-12)
    same = [r for r in out if r["metric"] == "map_features"]
    assert all(r["mean_difference"] == 0.0 and r["standard_error"] == 0.0 and r["a_lower"] == 0 for r in same)


def test_only_runs_with_a_partner_are_paired_and_missing_values_are_left_out():
    rows = _rows()
    rows = [r for r in rows if not (r["filter"] == "lmb" and r["seed"] == 2)]  # glmb's seed-2 runs lose their partner
    rows[0]["map_ospa"] = float("nan")  # log a, glmb, profile, seed 0
    rows[1]["map_ospa"] = None  # log a, glmb, profile, seed 1: a metric the run does not have
    out = [r for r in paired(rows) if r["varies"] == "filter" and r["metric"] == "map_ospa"]
    assert [(r["pd_mode"], r["pairs"]) for r in out] == [("profile", 2), ("constant", 4)]


def test_no_pairs_when_nothing_varies():
    rows = [r for r in _rows() if r["filter"] == "glmb" and r["pd_mode"] == "profile"]
    assert paired(rows) == []
    assert paired([]) == []


def test_two_logs_of_one_name_are_both_paired():
    """Logs are labelled by name: two logs that share one give runs with the same labels, each paired in turn."""
    rows = _rows()
    for r in rows:
        r["log"] = "same"
    out = [r for r in paired(rows) if r["varies"] == "pd_mode" and r["metric"] == "map_ospa"]
    assert [r["pairs"] for r in out] == [6, 6]
    assert out[0]["mean_difference"] == pytest.approx(-0.02, abs=1e-12)


def test_the_varied_settings_are_ranked_by_the_runs_log_evidence():
    """by_evidence: per setting, the variant of the largest mean log evidence and its lead over the next, paired by
    log and seed (the logs' own evidence, which differs by thousands of nats, cancels within a pair)."""
    from detcal.reports.sweep import by_evidence

    rows = []
    for log, off in (("a", 5000.0), ("b", 100.0)):
        for f in ("glmb", "lmb"):
            for v, gain in (("filter.survival=1", 0.0), ("filter.survival=0.99", 30.0), ("filter.survival=0.95", 10.0)):
                for s in range(3):
                    ev = off + gain + (s if f == "glmb" else -s) * (2.0 if v.endswith("0.99") else 1.0)
                    rows.append({"log": log, "profile": "p@1", "filter": f, "pd_mode": "profile", "particles": 10, "variant": v, "seed": s, "log_evidence": ev})
    # a run whose evidence is not finite is left out, wherever it stands
    out = by_evidence([{**rows[3], "variant": "filter.survival=0.5", "log_evidence": float("nan")}, *rows])
    assert [(g["filter"], g["best"], g["next"]) for g in out] == [("glmb", "filter.survival=0.99", "filter.survival=0.95")] * 1 + [
        ("lmb", "filter.survival=0.99", "filter.survival=0.95")
    ]
    glmb, lmb = out
    assert glmb["pairs"] == 6 and glmb["lead_higher"] == 6
    assert glmb["lead"] == pytest.approx(20.0 + np.mean([0, 1, 2]), abs=1e-9)  # (30 + 2s) - (10 + s) over s = 0, 1, 2
    assert glmb["lead_se"] == pytest.approx(np.std([0, 1, 2, 0, 1, 2], ddof=1) / np.sqrt(6), abs=1e-9)
    assert lmb["lead"] == pytest.approx(20.0 - 1.0, abs=1e-9) and lmb["lead_higher"] == 6
    assert glmb["best_mean"] == pytest.approx(2550.0 + 30.0 + 2.0 * 1.0, abs=1e-9)
    # a setting of one variant has no next; runs without the evidence are left out
    one = [r for r in rows if r["variant"] == "filter.survival=1"] + [{**rows[0], "filter": "rbphd", "log_evidence": None}]
    assert [(g["best"], g["next"]) for g in by_evidence(one)] == [("filter.survival=1", None)] * 2
