"""Run ``detcal`` in this process and SIGKILL it at a chosen point (for the crash tests).

    python -m tests.detcal.cli.crash_driver '{"argv": [...], "kill": {"target": "module:attr", "call": 1, "when": "after"}}'

``target`` names a function (``module:name`` or ``module:Class.method``) that is
wrapped so that on its ``call``-th call the process kills itself with SIGKILL
``before`` calling it, ``after`` it returned, or (``half``, for a text writer)
after writing half of its text. ``no_exchange`` makes the atomic writer use its
fallback (move the old folder aside, then the new one in), which has a moment
with no folder in place, so that moment can be tested too.
"""

from __future__ import annotations

import importlib
import json
import os
import signal
import sys


def _kill() -> None:
    sys.stdout.flush()
    sys.stderr.flush()
    os.kill(os.getpid(), signal.SIGKILL)


def arm(target: str, call: int, when: str) -> None:
    module, _, attr = target.partition(":")
    owner = importlib.import_module(module)
    *path, name = attr.split(".")
    for p in path:
        owner = getattr(owner, p)
    original = getattr(owner, name)
    count = {"n": 0}

    def wrapper(*args, **kwargs):
        count["n"] += 1
        hit = count["n"] == call
        if hit and when == "before":
            _kill()
        if hit and when == "half":
            text = args[1]
            original(args[0], text[: len(text) // 2], *args[2:], **kwargs)
            _kill()
        out = original(*args, **kwargs)
        if hit and when == "after":
            _kill()
        return out

    setattr(owner, name, wrapper)


def main() -> int:
    spec = json.loads(sys.argv[1])
    if spec.get("no_exchange"):
        import profiles.atomic

        profiles.atomic._exchange = lambda a, b: False  # noqa: SLF001
    kill = spec.get("kill")
    if kill:
        arm(kill["target"], int(kill.get("call", 1)), kill.get("when", "after"))
    from detcal.cli import main as detcal

    return detcal(spec["argv"])


if __name__ == "__main__":
    sys.exit(main())
