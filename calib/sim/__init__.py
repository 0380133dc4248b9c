"""Simulators whose truth is exported: the park, the street, and the rfs-sim and glmb-paper scenarios.

Every simulator is found through :data:`SIMULATORS` (its name -> a
:class:`Simulator`: its scenario config, the one setting the command line
offers as an option, and ``run(cfg, seed)`` giving the log with its summary and
the files that belong beside it); ``detcal simulate <name>`` is made from the
table. A new simulator is one module with its :class:`Simulator` and one
registration line.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from detectors.sensor_log import SensorLog
from profiles.registry import Registry


@dataclass
class Simulated:
    """One simulator run: the log, its summary, the files beside it ({name: text or bytes}) and the simulator's own
    result (what its overview figure draws)."""

    log: SensorLog
    summary: dict
    files: dict[str, str | bytes] = field(default_factory=dict)
    result: object = None


def with_truth(log: SensorLog, summary: dict, profile) -> Simulated:
    """A scenario's run whose truth is a profile (rfs-sim, glmb-paper): the log, its summary, and profile.yaml, the
    profile of the simulator's true statistics."""
    from profiles.store import dump_profile

    return Simulated(log, summary, {"profile.yaml": dump_profile(profile)}, log)


@dataclass(frozen=True)
class Option:
    """The scenario setting a simulate command offers as an option (``--<name>``): its config field, type and help."""

    name: str
    type: type
    help: str


@dataclass(frozen=True)
class Simulator:
    """A simulator: ``config`` its scenario settings (a pydantic model refusing unknown keys), ``key`` the name of
    the settings in the run folder's config.yaml, ``help`` one line for its command, ``title`` what its run is
    called in the command's summary, ``run(cfg, seed, progress) -> Simulated``, ``option`` a setting with its own
    option."""

    config: type
    key: str
    help: str
    title: str
    run: Callable[..., Simulated]
    option: Option | None = None


#: The simulators by name, as ``detcal simulate`` offers them.
SIMULATORS: Registry[Simulator] = Registry(
    "simulator", builtins=("calib.sim.park", "calib.sim.rfs", "calib.sim.street", "calib.sim.glmb_paper")
)
