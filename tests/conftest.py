"""Shared fixtures: the real-data folder (tests skip when it is absent) and small seeded simulations."""

from __future__ import annotations

from pathlib import Path

import pytest

from calib.sim.park import ParkConfig, simulate_park

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"
VENDORED = Path(__file__).resolve().parent / "data"


def shared(rel: str) -> Path:
    """A path inside ../shared/data, skipping the test when it is not there."""
    p = SHARED_DATA / rel
    if not p.exists():
        pytest.skip(f"real data {rel} not available (expected beside the repository in ../shared/data)")
    return p


def small_park_config(**path) -> ParkConfig:
    """A small park that simulates in well under a second."""
    return ParkConfig.model_validate(
        {
            "width": 60.0,
            "height": 45.0,
            "trees": {"count": 40},
            "bushes": {"count": 6},
            "walls": {"count": 3, "min_length": 3.0, "max_length": 8.0},
            "posts": {"count": 6},
            "path": {"margin": 8.0, "speed": 2.0, **path},
        }
    )


@pytest.fixture(scope="session")
def small_sim():
    return simulate_park(small_park_config(), seed=11)


@pytest.fixture(autouse=True, scope="session")
def _private_folders(tmp_path_factory):
    """Tests never touch the user's profile folder or cache; creation times are fixed."""
    import os

    saved = {k: os.environ.get(k) for k in ("DETCAL_PROFILES", "DETCAL_CACHE", "SOURCE_DATE_EPOCH")}
    os.environ["DETCAL_PROFILES"] = str(tmp_path_factory.mktemp("profiles"))
    os.environ["DETCAL_CACHE"] = str(tmp_path_factory.mktemp("cache"))
    os.environ["SOURCE_DATE_EPOCH"] = "1700000000"
    yield
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
