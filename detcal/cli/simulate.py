"""``detcal simulate ...``: simulated logs with exported truth."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from detcal.cli.common import fresh, out, summary_table
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
    from detcal.reports.simulation import simulate_to

    check_seed(seed)
    cfg = load_yaml_model(ParkConfig, config)
    fresh(out_dir, force, inputs=[config])
    summary = simulate_to(out_dir, seed, cfg, overwrite=force)
    out.print(summary_table(f"simulated park -> {out_dir}", summary))


@app.command("rfs-sim")
def simulate_rfs_cmd(
    out_dir: Annotated[Path, typer.Option("--out", help="Run folder to create.")],
    seed: SeedOpt = 0,
    steps: Annotated[int | None, typer.Option(help="Time steps of 0.1 s (default: the config's, 1,000).")] = None,
    config: Annotated[Path | None, typer.Option(help="YAML scenario config (unknown keys are refused); defaults otherwise.")] = None,
    force: ForceOpt = False,
) -> None:
    """The C++ RFS-SLAM library's 2D RB-PHD-SLAM scenario: 50 landmarks along a piecewise
    constant-velocity path, range-bearing sensor 0.5-2.5 m, P_D 0.99; writes the log and the
    profile of its true statistics."""
    from calib.config import load_yaml_model
    from calib.sim.rfs import RfsSimConfig
    from detcal.reports.simulation import write_rfs_simulation

    check_seed(seed)
    cfg = load_yaml_model(RfsSimConfig, config, {"steps": steps})  # an error in --steps names it
    fresh(out_dir, force, inputs=[config])
    summary = write_rfs_simulation(cfg, seed, out_dir, overwrite=force)
    out.print(summary_table(f"rfs-sim scenario -> {out_dir}", summary))


@app.command("street")
def simulate_street_cmd(
    out_dir: Annotated[Path, typer.Option("--out", help="Run folder to create.")],
    seed: SeedOpt = 0,
    frames: Annotated[int | None, typer.Option(help="Only the first N lidar frames (default: the whole route, about 340).")] = None,
    config: Annotated[Path | None, typer.Option(help="YAML street config (unknown keys are refused); defaults otherwise.")] = None,
    force: ForceOpt = False,
) -> None:
    """Simulate a 3D street (buildings, walls, boards, poles, cars, trees, bushes) swept by an HDL-64E-like
    lidar on a vehicle on an Extended Constant Turn path; writes the log with plane truth and the world."""
    from calib.config import load_yaml_model
    from calib.sim.street import StreetConfig
    from detcal.reports.simulation import write_street_simulation

    check_seed(seed)
    cfg = load_yaml_model(StreetConfig, config, {"frames": frames})  # an error in --frames names it
    fresh(out_dir, force, inputs=[config])
    summary = write_street_simulation(cfg, seed, out_dir, overwrite=force)
    out.print(summary_table(f"simulated street -> {out_dir}", summary))


@app.command("glmb-paper")
def simulate_glmb_paper_cmd(
    out_dir: Annotated[Path, typer.Option("--out", help="Run folder to create.")],
    seed: SeedOpt = 0,
    clutter: Annotated[float | None, typer.Option(help="False alarms per scan (the paper: 1, 5, 10, 15; default: the config's, 5).")] = None,
    config: Annotated[Path | None, typer.Option(help="YAML scenario config (unknown keys are refused); defaults otherwise.")] = None,
    force: ForceOpt = False,
) -> None:
    """The delta-GLMB-SLAM paper's simulation: 23 landmarks beside a pre-planned loop, v = 1 m/s,
    range-bearing sensor 0-3 m over the full circle, P_D 0.7, noise 0.3 m / 2 deg, Poisson clutter;
    writes the log and the profile of its true statistics."""
    from calib.config import load_yaml_model
    from calib.sim.glmb_paper import GlmbPaperConfig
    from detcal.reports.simulation import write_glmb_paper_simulation

    check_seed(seed)
    cfg = load_yaml_model(GlmbPaperConfig, config, {"clutter": clutter})  # an error in --clutter names it
    fresh(out_dir, force, inputs=[config])
    summary = write_glmb_paper_simulation(cfg, seed, out_dir, overwrite=force)
    out.print(summary_table(f"glmb-paper scenario -> {out_dir}", summary))
