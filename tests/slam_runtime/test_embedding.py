"""slam_runtime is what a robot embeds: on its own it pulls in no pandas, matplotlib, Dask or calib."""

from __future__ import annotations

import subprocess
import sys
import textwrap

from tests.conftest import ROOT


def test_slam_runtime_alone_imports_no_application_packages():
    """Every module of slam_runtime imported in a fresh interpreter, the registries read (every filter, vehicle model
    and feature model and the settings built from them), a bundled profile loaded: none of the packages a robot
    does not embed may be in sys.modules. (matplotlib and pandas were imported by the run folders and sweeps that
    lived here, calib by the provenance check of profiles: each made this list non-empty.)"""
    code = textwrap.dedent(
        """
        import importlib, pkgutil, sys
        import slam_runtime
        for m in pkgutil.walk_packages(slam_runtime.__path__, "slam_runtime."):
            importlib.import_module(m.name)
        from profiles.store import resolve
        from slam_runtime.config import SlamConfig
        from slam_runtime.features import FEATURE_MODELS
        from slam_runtime.mapfilter import MAP_FILTERS
        from slam_runtime.vehicle import VEHICLE_MODELS
        from detectors.kinds import DETECTORS
        resolve("sim-park-laser@1.0.0")
        SlamConfig.model_validate({"filter": {"kind": MAP_FILTERS.names()[-1]}})
        assert MAP_FILTERS.names() and VEHICLE_MODELS.names() and FEATURE_MODELS.names() and DETECTORS.names()
        banned = ("pandas", "matplotlib", "dask", "distributed", "calib", "detcal")
        print(sorted(m for m in sys.modules if m.split(".")[0] in banned))
        """
    )
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "[]"
