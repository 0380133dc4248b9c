"""The environment variables and folders detcal relies on, checked before a command runs.

* ``SOURCE_DATE_EPOCH`` (reproducible builds): the time written into a
  profile's provenance, as whole seconds since 1970. Anything else is a usage
  error naming the variable, not a ``ValueError`` deep in a calibration.
* numba's cache of compiled kernels: numba writes it beside the modules, else
  under the user's cache folder (``$XDG_CACHE_HOME`` or ``~/.cache``); with
  neither writable (an installed detcal under a read-only HOME) it fails at
  import with "no locator available". detcal then points numba at a folder of
  its own under the temporary folder and says so once.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from profiles.errors import UsageError

#: Latest SOURCE_DATE_EPOCH a datetime can hold (9999-12-31T23:59:59Z).
MAX_EPOCH = 253_402_300_799


def check_source_date_epoch() -> None:
    """Refuse a ``SOURCE_DATE_EPOCH`` that is not whole seconds since 1970 (an empty value means unset)."""
    value = os.environ.get("SOURCE_DATE_EPOCH")
    if not value:
        return
    if not (value.isascii() and value.isdigit()) or int(value) > MAX_EPOCH:
        raise UsageError(
            f"SOURCE_DATE_EPOCH: expected whole seconds since 1970-01-01 UTC (0..{MAX_EPOCH}, e.g. 1700000000), got {value!r}"
        )


def _probe_function():  # a stand-in with the file name of one of our numba modules (see numba_cache)
    return None


def numba_cache() -> str | None:
    """Make sure numba finds a writable cache folder for detcal's kernels; the fallback folder when one was needed.

    Asks numba's own cache machinery whether it finds a place for a function of
    ``slam_runtime/kernels.py`` (a kernel declared with ``cache=True``): where
    it finds none, ``NUMBA_CACHE_DIR`` is set to ``<tmp>/detcal-numba-<uid>``
    and numba's configuration reloaded. Call before any module with
    ``numba.njit(cache=True)`` is imported (the decorators ask at import).
    """
    from importlib.util import find_spec

    from numba.core import caching, config

    source = Path(find_spec("slam_runtime.kernels").origin)  # found, not imported
    probe = _probe_function
    probe.__code__ = probe.__code__.replace(co_filename=str(source))
    try:
        caching.CompileResultCacheImpl(probe)  # numba's locator search, as its njit(cache=True) decorators run it
        return None
    except (RuntimeError, OSError):
        pass
    uid = os.getuid() if hasattr(os, "getuid") else "user"
    fallback = Path(tempfile.gettempdir()) / f"detcal-numba-{uid}"
    fallback.mkdir(mode=0o700, exist_ok=True)
    os.environ["NUMBA_CACHE_DIR"] = str(fallback)
    classes = os.environ.get("NUMBA_CACHE_LOCATOR_CLASSES")
    if classes and "UserProvidedCacheLocator" not in classes:  # a locator list of the user's own: the fallback first
        os.environ["NUMBA_CACHE_LOCATOR_CLASSES"] = f"UserProvidedCacheLocator,{classes}"
    config.reload_config()
    return str(fallback)
