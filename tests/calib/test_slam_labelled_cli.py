"""`detcal slam run --filter lmb|glmb` and `detcal slam sweep --filter ...`: run folders with the label history,
reproducible bytes, the sweep's filter dimension."""

import csv

import pytest
import yaml

from calib.sim.glmb_paper import GlmbPaperConfig
from calib.sim.run import write_glmb_paper_simulation
from tests.calib.test_cli import assert_one_line_error, run


@pytest.fixture(scope="module")
def paper(tmp_path_factory):
    folder = tmp_path_factory.mktemp("paper") / "c5"
    write_glmb_paper_simulation(GlmbPaperConfig(clutter=5.0), 1, folder)
    return folder


def _args(paper, *extra):
    return ["slam", "run", str(paper / "log.dlog"), "--profile", str(paper / "profile.yaml"), "--particles", "5", "--frames", "80", *extra]


def test_labelled_run_folder_is_reproducible(tmp_path, capsys, paper):
    kind = "glmb"
    code, _, err = run(capsys, *_args(paper, "--filter", kind, "--seed", "4", "--out", str(tmp_path / "a")))
    assert code == 0, err
    names = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert names == [
        ".detcal-output", "config.yaml", "hypotheses.png", "labels.csv", "map.csv", "metrics.yaml", "ospa.png", "steps.csv", "timing.png",
        "trajectory.csv", "trajectory_map.png",
    ]  # fmt: skip
    cfg = yaml.safe_load((tmp_path / "a/config.yaml").read_text())
    assert cfg["settings"]["filter"]["kind"] == kind
    m = yaml.safe_load((tmp_path / "a/metrics.yaml").read_text())
    assert m["filter"] == "delta-GLMB"
    axes = {"rmse_x_vs_ground_truth_m", "rmse_y_vs_ground_truth_m", "rmse_heading_vs_ground_truth_deg"}
    assert axes | {"mean_" + k for k in axes} <= set(m)
    steps = list(csv.DictReader((tmp_path / "a/steps.csv").read_text().splitlines()))
    assert len(steps) == 80 and all(float(r["hypotheses"]) >= 1 for r in steps)
    spans = list(csv.DictReader((tmp_path / "a/labels.csv").read_text().splitlines()))
    # 16 s along the first side: the landmarks of the first metres enter the map, each under its own label
    assert spans and all(int(r["first_step"]) > int(r["birth_step"]) for r in spans)
    open_labels = [r["label"] for r in spans if r["ended"] == "0"]
    assert len(open_labels) == len(set(open_labels)) == int(float(steps[-1]["map_labels"]))
    code, _, err = run(capsys, *_args(paper, "--filter", kind, "--seed", "4", "--out", str(tmp_path / "b")))
    assert code == 0, err
    for f in ("trajectory.csv", "map.csv", "labels.csv"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes()


def test_sweep_over_filters(tmp_path, capsys, paper):
    out = tmp_path / "sw"
    code, text, err = run(
        capsys, "slam", "sweep", str(paper / "log.dlog"), "--profile", str(paper / "profile.yaml"), "--filter", "lmb", "--filter", "glmb",
        "--pd-mode", "profile", "--particles", "3", "--seeds", "1", "--frames", "30", "--workers", "0", "--out", str(out),
    )  # fmt: skip
    assert code == 0, err
    rows = list(csv.DictReader((out / "runs.csv").read_text().splitlines()))
    assert sorted((r["filter"], r["seed"]) for r in rows) == [("glmb", "0"), ("lmb", "0")]
    summary = list(csv.DictReader((out / "summary.csv").read_text().splitlines()))
    assert sorted(r["filter"] for r in summary) == ["glmb", "lmb"]
    pairs = list(csv.DictReader((out / "paired.csv").read_text().splitlines()))
    assert pairs and all((r["varies"], r["a"], r["b"], r["pairs"]) == ("filter", "lmb", "glmb", "1") for r in pairs)
    # the timing row has a cell per filter (it was one, for both, under the first)
    ms = next(line for line in text.splitlines() if "ms per step" in line)
    assert len([c for c in ms.split("│") if c.strip()]) == 3
    assert sum(1 for p in out.iterdir() if p.is_dir() and (p / "labels.csv").exists()) == 2
    code, _, err = run(capsys, "slam", "sweep", str(paper / "log.dlog"), "--profile", str(paper / "profile.yaml"), "--filter", "ekf", "--out", str(tmp_path / "x"))
    assert code == 2
    assert_one_line_error(err, "--filter: expected one of rbphd, lmb, glmb, got 'ekf'")
    assert not (tmp_path / "x").exists()
