"""The docs' lists follow the registries and the settings; the settings stay short enough to hold in mind."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from pydantic import BaseModel

from tests.conftest import ROOT
from tests.detcal.cli.test_cli import run


def _registries() -> dict:
    import slam_runtime.config  # noqa: F401  (the settings' registries loaded)
    from calib.io.registry import READERS, WRITERS
    from calib.sim import SIMULATORS
    from detcal.pipelines.calibrate import METHODS
    from detectors.kinds import DETECTORS
    from profiles.schema import PD_COVARIATES
    from slam_runtime.features import FEATURE_MODELS
    from slam_runtime.mapfilter import MAP_FILTERS
    from slam_runtime.vehicle import VEHICLE_MODELS

    return {
        "map filters": MAP_FILTERS, "vehicle models": VEHICLE_MODELS, "feature models": FEATURE_MODELS, "log readers": READERS,
        "log writers": WRITERS, "detectors": DETECTORS, "P_D covariates": PD_COVARIATES, "simulators": SIMULATORS,
        "calibration methods": METHODS,
    }  # fmt: skip


def test_the_extending_page_lists_what_is_registered():
    """docs/extending.md's list of each kind is its registry's names, in order."""
    text = (ROOT / "docs/extending.md").read_text()
    for title, reg in _registries().items():
        m = re.search(rf"^- {re.escape(title)}: (.*)$", text, re.M)
        assert m is not None, title
        assert re.findall(r"`([^`]+)`", m.group(1)) == list(reg.names()), title


def _keys(model: type[BaseModel], prefix: str = ""):
    for name, f in model.model_fields.items():
        ann = f.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            yield from _keys(ann, prefix + name + ".")
        else:
            yield prefix + name, f.description or ""


def test_every_setting_is_documented_in_one_line():
    """Every key of the SLAM settings (every registered filter's too) is in docs/settings.md, and its description is
    one line (at most 120 characters; longer explanations live in the docs)."""
    from slam_runtime.config import SlamConfig
    from slam_runtime.mapfilter import MAP_FILTERS

    text = (ROOT / "docs/settings.md").read_text()
    keys = [k for k in _keys(SlamConfig) if not k[0].startswith("filter")]
    keys += [("filter." + k, d) for cls in MAP_FILTERS.values() for k, d in _keys(cls.Config)]
    for key, description in keys:
        assert f"`{key}`" in text, key
        assert len(description) <= 120 and "\n" not in description, (key, len(description))


def test_slam_run_help_fits_on_a_screen(capsys):
    """What most users change fits on one screen: the help of slam run is at most 40 lines, the reader options named
    on a few of them."""
    code, out, _ = run(capsys, "slam", "run", "--help")
    assert code == 0
    assert len(out.splitlines()) <= 40, len(out.splitlines())
    assert "--set KEY=VALUE" in out and "--truth-topic" in out


# ---------------------------------------------------------------------------- runnable blocks of the README and the docs
#: Shell blocks marked ```bash title="runnable"``` are run by test_runnable_blocks_run, in the order of their page, as
#: one script. Real logs of ../shared/data are replaced by the shipped excerpts of tests/data (the same formats, a
#: few hundred frames), or by what an earlier runnable block of the page wrote (KITTI's frames, whose licence keeps
#: them out of the repository: two simulated street frames in KITTI's layout), so the blocks run on a fresh clone and
#: in CI within a minute or two.
SMALL_INPUTS = {
    "../shared/data/radish/aces.clf.bz2": "tests/data/radish/aces-2500.clf.bz2",
    "../shared/data/victoria_park": "tests/data/victoria_park",
    "../shared/data/utias_mrclam/dataset1": "tests/data/utias_dataset1",
    "../shared/data/kitti_object/velodyne": "runs/street-velodyne",  # docs/how-to/kitti.md writes it first
}
RUNNABLE = re.compile(r'^```bash title="runnable"\n(.*?)^```', re.M | re.S)


def runnable_pages() -> list[str]:
    pages = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").rglob("*.md"))]
    return [p for p in pages if RUNNABLE.search((ROOT / p).read_text())]


def runnable_script(page: str) -> str:
    """The page's runnable blocks as one script, with the small stand-ins for the real logs."""
    script = "\n".join(RUNNABLE.findall((ROOT / page).read_text()))
    for real, small in SMALL_INPUTS.items():
        script = script.replace(real, small)
    return script


def test_the_readme_the_tutorial_and_every_log_format_have_runnable_blocks_and_every_real_log_a_stand_in():
    """The README, the tutorial and the how-to of every log format a reader is registered for run in CI."""
    from calib.io.registry import READERS

    pages = runnable_pages()
    how_to = {"native": "native", "carmen": "carmen", "rosbag": "rosbag", "victoria": "victoria-park", "utias": "utias", "kitti": "kitti", "rfsslam": "rfsslam"}
    assert sorted(how_to) == sorted(READERS.names()), "a log format without its how-to page"
    expected = ["README.md", "docs/tutorial.md", *(f"docs/how-to/{page}.md" for page in how_to.values())]
    assert [p for p in expected if p not in pages] == [], pages
    for page in pages:
        assert "../shared/data" not in runnable_script(page), f"{page}: a runnable block reads a real log without a small stand-in"


@pytest.mark.slow  # each page's commands end to end in a fresh interpreter: calibrations, SLAM runs (tens of CPU seconds)
@pytest.mark.parametrize("page", runnable_pages())
def test_runnable_blocks_run(page, tmp_path):
    """Every runnable block of the page, in order, as one bash script (set -euo pipefail) in a scratch folder that sees
    the repository's files; profiles go to a scratch profile folder. The commands' own checks are the test: any
    non-zero exit fails it, with the output shown."""
    import os
    import subprocess
    import sys

    for name in ("Makefile", "pyproject.toml", "constraints.txt", ".venv", "benchmarks", "tests", "profiles", "docs"):
        if (ROOT / name).exists():
            (tmp_path / name).symlink_to(ROOT / name)
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
           "DETCAL_PROFILES": str(tmp_path / "profiles-user"), "COLUMNS": "120"}  # fmt: skip
    env.pop("DETCAL_SHARED_DATA", None)
    proc = subprocess.run(["bash", "-euo", "pipefail", "-c", runnable_script(page)], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert proc.returncode == 0, f"{page}: exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
