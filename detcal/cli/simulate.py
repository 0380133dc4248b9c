"""``detcal simulate ...``: simulated logs with exported truth, one command per simulator of :data:`calib.sim.SIMULATORS`."""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Annotated

import typer

from calib.sim import SIMULATORS, Simulator
from detcal.cli.common import fresh, out, summary_table
from profiles.errors import UsageError

app = typer.Typer(help="Simulate sensor logs with exported truth.", no_args_is_help=True, rich_markup_mode=None)


def check_seed(seed: int) -> None:
    if seed < 0:
        raise UsageError(f"--seed: expected a non-negative integer, got {seed}")


def simulate_command(name: str, sim: Simulator):
    """The command of simulator ``name``: --out, --seed, its own option, --config, --force; writes the run folder
    (:func:`detcal.reports.simulation.write_simulation_run`) and prints its summary."""

    def command(out_dir: Path, seed: int, config: Path | None, force: bool, **option) -> None:
        from calib.config import load_yaml_model
        from detcal.reports.simulation import write_simulation_run

        check_seed(seed)
        cfg = load_yaml_model(sim.config, config, option)  # an error in the option names it
        fresh(out_dir, force, inputs=[config])
        summary = write_simulation_run(name, cfg, seed, out_dir, overwrite=force)
        out.print(summary_table(f"{sim.title} -> {out_dir}", summary))

    params = [
        inspect.Parameter("out_dir", inspect.Parameter.KEYWORD_ONLY, annotation=Annotated[Path, typer.Option("--out", help="Run folder to create.")]),
        inspect.Parameter("seed", inspect.Parameter.KEYWORD_ONLY, default=0, annotation=Annotated[int, typer.Option(help="Random seed; same seed and config, same bytes.")]),
    ]
    if sim.option is not None:
        o = sim.option
        params.append(inspect.Parameter(o.name, inspect.Parameter.KEYWORD_ONLY, default=None, annotation=Annotated[o.type | None, typer.Option(help=o.help)]))
    params += [
        inspect.Parameter(
            "config", inspect.Parameter.KEYWORD_ONLY, default=None,
            annotation=Annotated[Path | None, typer.Option(help="YAML scenario config (unknown keys are refused); defaults otherwise.")],
        ),
        inspect.Parameter("force", inspect.Parameter.KEYWORD_ONLY, default=False, annotation=Annotated[bool, typer.Option(help="Replace the run folder if it exists.")]),
    ]  # fmt: skip

    def wrapper(**kwargs) -> None:
        command(kwargs.pop("out_dir"), kwargs.pop("seed"), kwargs.pop("config"), kwargs.pop("force"), **kwargs)

    wrapper.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    wrapper.__doc__ = sim.help
    return wrapper


for _name, _sim in SIMULATORS.items():
    app.command(_name)(simulate_command(_name, _sim))
