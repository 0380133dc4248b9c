"""The version of detcal and what else identifies the code that made a profile (``provenance``)."""

from __future__ import annotations

import functools
import subprocess
import sys
from importlib import metadata
from pathlib import Path

__version__ = "0.1.0"

#: the packages a profile's numbers depend on (fits, ray tracing, compiled kernels), recorded with their versions
NUMERIC_PACKAGES = ("numpy", "scipy", "pandas", "numba", "opencv-python-headless", "scikit-image", "gtsam")

#: the source tree of the detcal that runs (a git checkout when run from one)
SOURCE_ROOT = Path(__file__).resolve().parent.parent

#: the top-level folders of detcal's source: a change in them makes a checkout "dirty" for the recorded commit
SOURCE_PARTS = ("calib", "detcal", "detectors", "profiles", "slam_runtime", "pyproject.toml")


@functools.cache
def source_commit() -> str | None:
    """The git commit of the detcal source that runs, ``+dirty`` when its source has uncommitted changes;
    None when detcal does not run from a git checkout (an installed wheel) or git is not there."""
    if not (SOURCE_ROOT / ".git").exists():
        return None
    try:
        run = functools.partial(subprocess.run, cwd=SOURCE_ROOT, capture_output=True, text=True, timeout=10, check=True)
        sha = run(["git", "rev-parse", "HEAD"]).stdout.strip()
        changed = run(["git", "status", "--porcelain", "--untracked-files=no", "--", *SOURCE_PARTS]).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return f"{sha}+dirty" if changed else sha


@functools.cache
def package_versions() -> dict[str, str]:
    """Python's and the installed :data:`NUMERIC_PACKAGES`' versions (those not installed are left out)."""
    found = {"python": ".".join(map(str, sys.version_info[:3]))}
    for name in NUMERIC_PACKAGES:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return found


def build_stamp() -> dict:
    """``commit`` and ``packages`` of a new profile's provenance."""
    return {"commit": source_commit(), "packages": package_versions()}
