"""The environment a command starts in: variables detcal (and numpy) read at import, cache folders it cannot write.

These run ``python -m detcal`` in a fresh process: the checks happen as the
command line is imported, before any test process could have imported it.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from tests.detcal.cli.test_bad_inputs import small_log


def test_a_read_only_install_under_an_unwritable_home_falls_back_and_a_bad_epoch_is_one_line(tmp_path):
    """numba finds no cache folder (none beside the modules, as in a read-only install, and HOME under a plain file,
    which no user can write): the command warns once and uses a folder under TMPDIR instead of failing at import.
    A SOURCE_DATE_EPOCH that is not an integer (numpy reads it as it imports f2py) is refused in one line, exit 2."""
    blocker = tmp_path / "plain"
    blocker.write_text("a file, so nothing can be created under it")
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("XDG_CACHE_HOME", "NUMBA_CACHE_DIR")}
    # numba's locators without the one beside the modules: what an install in a read-only site-packages leaves
    env.update(HOME=str(blocker / "home"), NUMBA_CACHE_LOCATOR_CLASSES="UserWideCacheLocator", TMPDIR=str(tmp))
    log = small_log(tmp_path)
    ok = subprocess.run([sys.executable, "-m", "detcal", "log", "info", log], env=env, capture_output=True, text=True, check=False)
    assert ok.returncode == 0, ok.stderr
    warning = f"detcal: warning: numba cannot write its cache of compiled kernels beside detcal nor under the user's cache folder; using {tmp}"
    assert ok.stderr.splitlines() == [f"{warning}/detcal-numba-{os.getuid()}"]
    env["SOURCE_DATE_EPOCH"] = "yesterday"
    bad = subprocess.run([sys.executable, "-m", "detcal", "log", "info", log], env=env, capture_output=True, text=True, check=False)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert bad.stderr.splitlines()[-1] == (
        "detcal: error: SOURCE_DATE_EPOCH: expected whole seconds since 1970-01-01 UTC (0..253402300799, e.g. 1700000000), got 'yesterday'"
    )
    assert bad.stdout == "" and sorted(p.name for p in tmp_path.iterdir()) == sorted(["plain", "tmp", Path(log).name])


def test_out_of_memory_is_named_not_a_traceback(tmp_path, capsys, monkeypatch):
    """A reader that runs out of memory (a valid log too large for this machine): one line that says so, exit 1."""
    import calib.io.registry as registry
    from detcal.cli import main

    def exhausted(path):
        raise MemoryError

    monkeypatch.setattr(registry, "read_native", exhausted)
    code = main(["log", "info", small_log(tmp_path)])
    err = capsys.readouterr().err
    assert code == 1 and err == "detcal: error: out of memory: the input is too large for this machine's memory (it is not necessarily damaged)\n"
