"""The run folder of ``detcal selfcal``: every iteration's profile, the iterations' table and figure, the last SLAM run."""

from __future__ import annotations

import numpy as np
import pandas as pd

from calib.config import dump_yaml
from detectors.sensor_log import SensorLog
from profiles.store import dump_profile


def fill_selfcal_run(log: SensorLog, history: list, tmp, *, last_run=None) -> list[str]:
    """Fill the (new, empty) run folder ``tmp`` of ``detcal selfcal``.

    profile.yaml (the profile measured last), slam.yaml (the settings of the last run with the
    measured odometry biases, for ``detcal slam run --config``), iterations.csv (one row per SLAM
    run: what it used, what it scored against the log's reference, what was measured),
    profiles/iteration_K.yaml (every measured profile), pairs.csv.gz (the last measurement's
    frame x feature pairs), pd_iterations.png; ``last_run(folder)`` may write the last SLAM run
    into ``last_run/`` (the CLI passes the SLAM run-folder writer).
    """

    rows = []
    for it in history:
        m, s = it.result.metrics, it.summary
        row = {"iteration": it.index, "profile_used": it.profile.ref, "change": it.change}
        row.update({k: v for k, v in m.items() if isinstance(v, int | float) and not isinstance(v, bool)})
        row.update({f"measured_{k}": v for k, v in s.items() if isinstance(v, int | float) and not isinstance(v, bool)})
        row.update({f"bias_{k}": v for k, v in it.bias.items()})
        rows.append(row)
    last = history[-1]
    (tmp / "profile.yaml").write_text(dump_profile(last.measured))
    cfg = last.next_config if last.next_config is not None else last.config
    (tmp / "slam.yaml").write_text(dump_yaml(cfg.model_dump(mode="json")))
    pd.DataFrame(rows).to_csv(tmp / "iterations.csv", index=False, float_format="%.6g")
    (tmp / "profiles").mkdir()
    for it in history:
        (tmp / "profiles" / f"iteration_{it.index}.yaml").write_text(dump_profile(it.measured))
    (tmp / "summary.yaml").write_text(dump_yaml({"log": log.name, "iterations": len(history), "last": rows[-1]}))
    _plot_iterations(history, tmp / "pd_iterations.png")
    if last_run is not None:
        last_run(tmp / "last_run")
    return ["pd_iterations.png"]


def _plot_iterations(history: list, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    for it in history:
        e = np.asarray(it.measured.pd.edges)
        a.step(e[:-1], it.measured.pd.pd, where="post", label=f"iteration {it.index}")
    e = np.asarray(history[0].profile.pd.edges)
    a.step(e[:-1], history[0].profile.pd.pd, where="post", color="k", ls="--", label="starting profile")
    a.set_xlabel("range [m]")
    a.set_ylabel("P_D (unoccluded map features)")
    a.legend(fontsize=7)
    a.grid(alpha=0.3)
    keys = [k for k in history[0].result.metrics if k.startswith("trajectory_rmse_vs_")]
    for k in keys:
        b.plot([it.index for it in history], [it.result.metrics[k] for it in history], "o-", label=k.replace("_", " "))
    b.set_xlabel("iteration")
    b.set_ylabel("trajectory RMSE [m]")
    b.legend(fontsize=7)
    b.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
