"""The docs' lists follow the registries and the settings; the settings stay short enough to hold in mind."""

from __future__ import annotations

import re

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
