"""The embedded default log: a simulated park (fixed seed, default config), made once and cached.

Cache folder: ``$DETCAL_CACHE`` or ``$XDG_CACHE_HOME/detcal`` (``~/.cache/detcal``).
The file name carries a hash of the simulator config, so a changed default is
simulated anew rather than read stale.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from calib.io.native import read_native, write_native
from calib.sim.park import ParkConfig, simulate_park
from detectors.sensor_log import SensorLog

DEFAULT_SEED = 1
DEFAULT_PROFILE_NAME = "sim-park-laser"


def cache_dir() -> Path:
    env = os.environ.get("DETCAL_CACHE")
    if env:
        return Path(env).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "detcal"


def default_log_path(seed: int = DEFAULT_SEED) -> Path:
    digest = hashlib.sha256(json.dumps(ParkConfig().model_dump(mode="json"), sort_keys=True).encode()).hexdigest()[:12]
    return cache_dir() / f"park_seed{seed}_{digest}.dlog"


def default_log(seed: int = DEFAULT_SEED) -> tuple[SensorLog, Path]:
    """The default park log, simulating and caching it on first use."""
    path = default_log_path(seed)
    if not path.is_file():
        from calib.progress import progress

        sim = simulate_park(ParkConfig(), seed, progress=progress)
        write_native(sim.log, path, overwrite=True)
    return read_native(path), path
