"""`detcal slam run --filter lmb|glmb` and `detcal slam sweep --filter ...`: run folders with the label history,
reproducible bytes, the sweep's filter dimension."""

import csv

import pytest
import yaml

from calib.sim.glmb_paper import GlmbPaperConfig
from detcal.reports.simulation import write_simulation_run
from tests.detcal.cli.test_cli import assert_one_line_error, run


@pytest.fixture(scope="module")
def paper(tmp_path_factory):
    folder = tmp_path_factory.mktemp("paper") / "c5"
    write_simulation_run("glmb-paper", GlmbPaperConfig(clutter=5.0), 1, folder)
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
        "trajectory.csv", "trajectory_map.png", "warnings.yaml",
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
    # the plan keeps the settings' own particle count (each run holds its --particles): sweeps made before --particles
    # met the islands check resume
    assert yaml.safe_load((out / "config.yaml").read_text())["settings"]["particles"] == 20
    code, _, err = run(capsys, "slam", "sweep", str(paper / "log.dlog"), "--profile", str(paper / "profile.yaml"), "--filter", "ekf", "--out", str(tmp_path / "x"))
    assert code == 2
    assert_one_line_error(err, "--filter: expected one of rbphd, lmb, glmb, mhfastslam, got 'ekf'")
    assert not (tmp_path / "x").exists()


def test_varies_returns_every_combination_with_its_label():
    from detcal.pipelines.sweep import variants

    assert variants(None) == [(None, {})]
    got = variants(["filter.survival=1, 0.99,1.0", "island_match=null,0.5"])  # (1 and 1.0 are one value)
    assert got == [
        ("filter.survival=1, island_match=null", {"filter.survival": 1, "island_match": None}),
        ("filter.survival=1, island_match=0.5", {"filter.survival": 1, "island_match": 0.5}),
        ("filter.survival=0.99, island_match=null", {"filter.survival": 0.99, "island_match": None}),
        ("filter.survival=0.99, island_match=0.5", {"filter.survival": 0.99, "island_match": 0.5}),
    ]
    # 1e-3 is the number YAML 1.1 reads as text; true is not 1
    assert variants(["filter.prune=0.001,1e-3", "map_refine=1,true"]) == [
        ("filter.prune=0.001, map_refine=1", {"filter.prune": 0.001, "map_refine": 1}),
        ("filter.prune=0.001, map_refine=true", {"filter.prune": 0.001, "map_refine": True}),
    ]


def test_sweep_varies_a_setting_and_the_log_evidence_finds_the_simulators_noise(tmp_path, capsys, paper):
    """``--vary measurement.sigma_range=0.1,0.3,0.9``: one run per value (the label ``variant``, its own run folder,
    its settings in config.yaml), compared run by run in paired.csv, and ranked by the runs' log evidence. The
    simulator's range noise is 0.3 m; with the poses given (80 frames, one particle) the evidence of the true value
    leads both others by tens of nats (measured: 147.6 against 89.5 at 0.1 m and 84.5 at 0.9 m), and the map is no
    worse with it. ``--write-config`` writes the settings of the likeliest value (the true one), and ``slam run`` with
    that file repeats its run to the last digit."""
    from detcal.reports.sweep import by_evidence

    out, chosen = tmp_path / "sw", tmp_path / "chosen.yaml"
    code, text, err = run(
        capsys, "slam", "sweep", str(paper / "log.dlog"), "--profile", str(paper / "profile.yaml"), "--filter", "glmb",
        "--pd-mode", "profile", "--particles", "1", "--frames", "80", "--poses", "ground_truth", "--workers", "0",
        "--vary", "measurement.sigma_range=0.1,0.3,0.9", "--out", str(out), "--write-config", str(chosen),
    )  # fmt: skip
    assert code == 0, err
    written = yaml.safe_load(chosen.read_text())
    assert written["measurement"]["sigma_range"] == 0.3
    assert (written["particles"], written["detection"]["pd_mode"], written["poses"], written["filter"]["kind"]) == (1, "profile", "ground_truth", "glmb")
    assert "likeliest by the mean log evidence" in chosen.read_text() and "measurement.sigma_range=0.3" in chosen.read_text()
    code, _, err = run(
        capsys, "slam", "run", str(paper / "log.dlog"), "--profile", str(paper / "profile.yaml"), "--config", str(chosen),
        "--frames", "80", "--seed", "0", "--out", str(tmp_path / "again"),
    )  # fmt: skip
    assert code == 0, err
    again = yaml.safe_load((tmp_path / "again" / "metrics.yaml").read_text())["log_evidence"]
    (v1,) = [p for p in out.iterdir() if p.name.endswith("_v1_s0")]
    assert again == yaml.safe_load((v1 / "metrics.yaml").read_text())["log_evidence"]
    rows = list(csv.DictReader((out / "runs.csv").read_text().splitlines()))
    labels = [f"measurement.sigma_range={v}" for v in ("0.1", "0.3", "0.9")]
    assert [r["variant"] for r in rows] == labels
    folders = sorted(p.name for p in out.iterdir() if p.is_dir())
    assert [f[-6:] for f in folders] == ["_v0_s0", "_v1_s0", "_v2_s0"]
    sigma = [yaml.safe_load((out / f / "config.yaml").read_text())["settings"]["measurement"]["sigma_range"] for f in folders]
    assert sigma == [0.1, 0.3, 0.9]
    ev = {r["variant"]: float(r["log_evidence"]) for r in rows}
    assert ev[labels[1]] > max(ev[labels[0]], ev[labels[2]]) + 20.0, ev
    ospa = {r["variant"]: float(r["map_ospa"]) for r in rows}
    assert ospa[labels[1]] <= min(ospa.values()) + 1e-9, ospa
    best = by_evidence([{**r, "log_evidence": float(r["log_evidence"])} for r in rows])
    assert [(g["best"], g["pairs"], g["lead_higher"]) for g in best] == [(labels[1], 1, 1)]
    pairs = {(r["a"], r["b"]) for r in csv.DictReader((out / "paired.csv").read_text().splitlines()) if r["varies"] == "variant"}
    assert pairs == {(labels[0], labels[1]), (labels[0], labels[2]), (labels[1], labels[2])}
    assert "likeliest" in text and "evidence" in text


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        ([], "--write-config: nothing to choose; give --vary"),
        (["--vary", "filter.gate=9,16"], "P_D modes profile, constant: sweep one at a time; give one --pd-mode"),
        (["--vary", "filter.gate=9,16", "--pd-mode", "profile", "--particles", "1", "--particles", "2"], "particle counts 1, 2: sweep one at a time"),
        (["--vary", "filter.gate=9,16", "--pd-mode", "profile", "--write-config", "TAKEN"], "TAKEN exists; remove it or name another file"),
        (["--vary", "filter.gate=9,16", "--pd-mode", "profile", "--write-config", "nofolder/c.yaml"], "--write-config: no folder"),
    ],
)
def test_write_config_is_refused_before_any_run(tmp_path, capsys, paper, extra, needle):
    """--write-config needs variants to choose among, one of everything else, and a free file name: refused with one
    message before any run, the sweep folder not made and an existing file untouched."""
    taken = tmp_path / "taken.yaml"
    taken.write_text("particles: 3\n")
    extra = [str(taken) if e == "TAKEN" else str(tmp_path / e) if e.startswith("nofolder") else e for e in extra]
    if "--write-config" not in extra:
        extra += ["--write-config", str(tmp_path / "c.yaml")]
    code, _, err = run(
        capsys, "slam", "sweep", str(paper / "log.dlog"), "--profile", str(paper / "profile.yaml"), "--frames", "3", "--workers", "0",
        "--out", str(tmp_path / "x"), *extra,
    )  # fmt: skip
    assert code == 2, err
    assert_one_line_error(err, needle.replace("TAKEN", str(taken)))
    assert not (tmp_path / "x").exists() and not (tmp_path / "c.yaml").exists()
    assert taken.read_text() == "particles: 3\n"


@pytest.mark.parametrize("bad", [float("nan"), float("-inf")])
def test_write_config_refuses_a_ranking_with_a_run_of_no_finite_evidence(tmp_path, paper, bad):
    """A run whose log evidence is not finite (NaN: not computed; -inf: a measurement the model cannot explain) would
    rank the variants on different runs: nothing is written, and the message names the run."""
    from calib.io.registry import ReadOptions, read_log
    from detcal.pipelines.slam_run import SettingsRequest
    from detcal.pipelines.sweep import SweepRequest
    from profiles.errors import DataError

    target, base = tmp_path / "c.yaml", tmp_path / "base.yaml"
    base.write_text("detection: &e {}\nmetric: *e\n")  # one YAML mapping under two groups
    sw = SweepRequest(
        [paper / "log.dlog"], read_log, None, ReadOptions(), [str(paper / "profile.yaml")], SettingsRequest(base), [0, 1], tmp_path / "x",
        pd_modes=["profile"], vary=["filter.gate=9,16"], frames=3, write_config=target,
    )  # fmt: skip
    sw.prepare()
    rows = [{**j.labels, "log_evidence": 10.0 + i} for i, j in enumerate(sw.jobs)]
    rows[1]["log_evidence"] = bad
    with pytest.raises(DataError, match=r"1 of 4 runs recorded no finite log evidence \(the first: filter.gate=9, log .*, seed 1\)"):
        sw.write_likeliest(rows)
    assert not target.exists()
    rows[1]["log_evidence"] = 11.0
    assert sw.write_likeliest(rows)["best"] == "filter.gate=16"
    written = yaml.safe_load(target.read_text())
    assert written["filter"]["gate"] == 16 and written["detection"] == {"pd_mode": "profile"} and written["metric"] == {}
    assert "base.yaml, --pd-mode profile; profile " in target.read_text() and "give --frames 3 too" in target.read_text()


@pytest.mark.parametrize(
    ("vary", "needle"),
    [
        (["filter.survival=1,0.99", "--filter", "rbphd"], "--vary filter.survival=1, for filter rbphd: filter.rbphd.survival: unknown key"),
        (["filter.survival=0.5,2", "--filter", "glmb"], "--vary filter.survival=2, for filter glmb: filter.glmb.survival: Input should be less than or equal to 1"),
        (["nosuch.key=1"], "nosuch.key: unknown key (nosuch is not a group of settings)"),
        (["particles=5,10"], "--vary particles: use --particles (repeat it)"),
        (["filter.survival"], "--vary: expected KEY=V1,V2,..."),
        (["filter.survival=1,"], "--vary: expected KEY=V1,V2,..."),
        (["filter.gate=9", "--vary", "filter.gate=4"], "--vary filter.gate: given twice"),
        (["filter={kind: lmb}"], "--vary filter: use --filter (repeat it) to vary filter.kind"),
        (["filter.survival=0.5", "--vary", "filter=x"], "--vary filter: use --filter"),
        (["motion=1,2"], "--vary motion: a group of settings; vary the single settings in it (e.g. motion.model)"),
        (["motion.ackermann.sigma_speed=1", "--vary", "motion.ackermann=2"], "--vary motion.ackermann: overlaps --vary motion.ackermann.sigma_speed"),
        (["filter.gate=[1,2]"], "--vary filter.gate: cannot read the value '[1'"),
    ],
)
def test_a_bad_vary_is_refused_before_anything_is_written(tmp_path, capsys, paper, vary, needle):
    code, _, err = run(
        capsys, "slam", "sweep", str(paper / "log.dlog"), "--profile", str(paper / "profile.yaml"), "--frames", "3", "--workers", "0",
        "--out", str(tmp_path / "x"), "--vary", *vary,
    )  # fmt: skip
    assert code == 2
    assert_one_line_error(err, needle)
    assert not (tmp_path / "x").exists()


def test_particles_given_on_the_command_line_meet_the_files_islands(tmp_path, capsys, paper):
    """--particles replaces the file's count before the islands are checked against it: 3 islands of 1 is a valid run
    although the file's default 20 particles would not split into 3; 4 particles are refused, naming both."""
    cfg = tmp_path / "islands.yaml"
    cfg.write_text("islands: 3\nfilter: {kind: lmb}\n")
    base = ["slam", "run", str(paper / "log.dlog"), "--profile", str(paper / "profile.yaml"), "--frames", "5", "--config", str(cfg)]
    code, _, err = run(capsys, *base, "--particles", "3", "--out", str(tmp_path / "ok"))
    assert code == 0, err
    settings = yaml.safe_load((tmp_path / "ok/config.yaml").read_text())["settings"]
    assert (settings["particles"], settings["islands"]) == (3, 3)
    code, _, err = run(capsys, *base, "--particles", "4", "--out", str(tmp_path / "bad"))
    assert code == 2
    assert_one_line_error(err, "islands: 3 islands cannot share 4 particles equally")
    assert not (tmp_path / "bad").exists()
