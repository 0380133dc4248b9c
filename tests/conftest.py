"""Shared fixtures: the real-data folder (tests skip when it is absent) and small seeded simulations."""

from __future__ import annotations

import os
import resource
from pathlib import Path

import pytest

from calib.sim.park import ParkConfig, simulate_park

ROOT = Path(__file__).resolve().parents[1]
#: the real logs: beside the repository, or where $DETCAL_SHARED_DATA says (a checkout elsewhere)
SHARED_DATA = Path(os.environ.get("DETCAL_SHARED_DATA") or ROOT.parent / "shared" / "data")
VENDORED = Path(__file__).resolve().parent / "data"


def _cpu_seconds() -> float:
    """User + system CPU of this process (all its threads) and of its children already waited for."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def pytest_addoption(parser):
    parser.addoption(
        "--cpu-durations",
        type=int,
        default=None,
        metavar="N",
        help="list the N tests that used the most CPU (setup + call + teardown, subprocesses included; "
        "unlike --durations, independent of how busy the machine is); 0 lists all",
    )


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    item.stash[_CPU_START] = _cpu_seconds()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    if call.when == "teardown" and _CPU_START in item.stash:
        # user_properties travel from an xdist worker to the controller with the report
        outcome.get_result().user_properties.append(("cpu_s", _cpu_seconds() - item.stash[_CPU_START]))


def pytest_runtest_logreport(report):
    if report.when == "teardown":
        cpu = dict(report.user_properties).get("cpu_s")
        if cpu is not None:
            _CPU_BY_TEST[report.nodeid] = cpu


def pytest_terminal_summary(terminalreporter, config):
    n = config.getoption("--cpu-durations")
    if n is None or not _CPU_BY_TEST:
        return
    rows = sorted(_CPU_BY_TEST.items(), key=lambda kv: -kv[1])
    tr = terminalreporter
    tr.write_sep("=", f"CPU per test, most first (total {sum(_CPU_BY_TEST.values()):.1f} s in {len(rows)} tests, process start-up not included)")
    for nodeid, cpu in rows if n == 0 else rows[:n]:
        tr.write_line(f"{cpu:8.2f} s  {nodeid}")


_CPU_START = pytest.StashKey[float]()
_CPU_BY_TEST: dict[str, float] = {}


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


def small_street_config(frames: int = 20, **over):
    """A short street with the 64 rings at 0.35 deg azimuth steps (about 65k returns a frame): seconds, not minutes."""
    from calib.sim.street import StreetConfig

    data = {
        "route": [{"kind": "straight", "length": 50.0}, {"kind": "turn", "angle_deg": 90.0, "radius": 15.0}, {"kind": "straight", "length": 30.0}],
        "extend": 25.0,
        "lidar": {"azimuth_increment_deg": 0.35},
        "frames": frames,
    }
    for k, v in over.items():
        data[k] = {**data.get(k, {}), **v} if isinstance(v, dict) else v
    return StreetConfig.model_validate(data)


@pytest.fixture(scope="session")
def small_street():
    """40 frames of a small street (seed 21): truth for the plane detector and SLAM tests."""
    from calib.sim.street import simulate_street

    return simulate_street(small_street_config(40), seed=21)


@pytest.fixture(scope="session")
def street_profile(small_street):
    """A lidar3d-planes profile calibrated on a second small street (seed 22)."""
    from calib.planes import PlaneCalibConfig, calibrate_planes
    from calib.sim.street import simulate_street

    sim = simulate_street(small_street_config(16), seed=22)
    cfg = PlaneCalibConfig.model_validate({"pd": {"min_count": 20}, "every": 1})
    return calibrate_planes([sim.log], cfg, name="small-street", version="1.0.0").profile
