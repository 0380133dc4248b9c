"""The benchmarks' resumable per-run CSV: rows added one by one read back as written, a cut last line left out."""

from __future__ import annotations

import math

import pytest

from benchmarks.common import append_row, read_rows


def test_rows_read_back_as_written(tmp_path):
    p = tmp_path / "runs.csv"
    rows = [
        {"part": "clutter", "filter": "glmb", "world": 2, "clutter": 15.0, "ospa": 1e-05, "sets": ""},
        {"part": "vp", "filter": "rbphd", "world": 0, "clutter": float("nan"), "ospa": 0.25, "sets": "particles=20"},
    ]
    for r in rows:
        append_row(p, r)
    back = read_rows(p)
    assert len(back) == 2 and p.read_text().count("part,") == 1  # one header
    assert back[0] == rows[0] and isinstance(back[0]["world"], int)
    assert math.isnan(back[1]["clutter"]) and back[1]["sets"] == "particles=20"


def test_a_cut_last_line_is_left_out_and_the_next_row_starts_a_line(tmp_path):
    p = tmp_path / "runs.csv"
    append_row(p, {"a": 1, "b": 2.5})
    with p.open("a") as fh:
        fh.write("3,4.")  # a run stopped while writing: no line end
    assert read_rows(p) == [{"a": 1, "b": 2.5}]
    append_row(p, {"a": 5, "b": 6.0})
    assert read_rows(p) == [{"a": 1, "b": 2.5}, {"a": 5, "b": 6.0}]  # the cut line dropped, not completed


def test_another_layout_is_refused(tmp_path):
    p = tmp_path / "runs.csv"
    append_row(p, {"a": 1})
    with pytest.raises(SystemExit, match="not this benchmark's"):
        read_rows(p, ["a", "b"])
    assert read_rows(tmp_path / "absent.csv") == []
