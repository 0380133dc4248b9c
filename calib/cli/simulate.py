"""``detcal simulate ...``: simulated logs with exported truth."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from calib.cli.common import fresh, out, summary_table
from profiles.errors import UsageError

app = typer.Typer(help="Simulate sensor logs with exported truth.", no_args_is_help=True, rich_markup_mode=None)

SeedOpt = Annotated[int, typer.Option(help="Random seed; same seed and config, same bytes.")]
ForceOpt = Annotated[bool, typer.Option(help="Replace the run folder if it exists.")]


def check_seed(seed: int) -> None:
    if seed < 0:
        raise UsageError(f"--seed: expected a non-negative integer, got {seed}")


@app.command("park")
def simulate_park_cmd(
    out_dir: Annotated[Path, typer.Option("--out", help="Run folder to create.")],
    seed: SeedOpt = 0,
    config: Annotated[Path | None, typer.Option(help="YAML park config (unknown keys are refused); defaults otherwise.")] = None,
    force: ForceOpt = False,
) -> None:
    """Simulate a 2D park (trees, bushes, walls, posts, dust) seen by a laser on a moving vehicle."""
    from calib.config import load_yaml_model
    from calib.sim.park import ParkConfig
    from calib.sim.run import simulate_to

    check_seed(seed)
    cfg = load_yaml_model(ParkConfig, config)
    fresh(out_dir, force)
    summary = simulate_to(out_dir, seed, cfg, overwrite=force)
    out.print(summary_table(f"simulated park -> {out_dir}", summary))
