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


def truth_provenance(cfg, command: str):
    """The provenance of a scenario's truth profile: the scenario's settings, recorded by ``command``; its date is a
    statement of the settings, not of a time (same config, same bytes)."""
    from calib import __version__
    from profiles.profile import Provenance

    return Provenance(detcal_version=__version__, command=command, parameters=cfg.model_dump(mode="json"), created="1970-01-01T00:00:00Z")


@dataclass(frozen=True)
class Option:
    """The scenario setting a simulate command offers as an option (``--<name>``): its config field, type and help;
    ``flag`` the option's own declaration where ``--<name>`` is not it (a switch: ``"--moving/--static"``)."""

    name: str
    type: type
    help: str
    flag: str | None = None


@dataclass(frozen=True)
class Simulator:
    """A simulator: ``config`` its scenario settings (a pydantic model refusing unknown keys), ``key`` the name of
    the settings in the run folder's config.yaml, ``help`` one line for its command, ``title`` what its run is
    called in the command's summary, ``run(cfg, seed, progress) -> Simulated``, ``option`` a setting with its own
    option, or a tuple of them."""

    config: type
    key: str
    help: str
    title: str
    run: Callable[..., Simulated]
    option: Option | tuple[Option, ...] | None = None

    @property
    def options(self) -> tuple[Option, ...]:
        """The settings with an option of their own, in the command's order."""
        return () if self.option is None else (self.option,) if isinstance(self.option, Option) else tuple(self.option)


#: The simulators by name, as ``detcal simulate`` offers them.
SIMULATORS: Registry[Simulator] = Registry(
    "simulator", builtins=("calib.sim.park", "calib.sim.rfs", "calib.sim.street", "calib.sim.glmb_paper", "calib.sim.two_stage")
)
