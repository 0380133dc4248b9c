"""A new kind is a module and a registration line: a toy map filter, log reader and detector, defined here and
registered from this module, run through the detcal command line with no library file edited."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import pytest
import yaml
from pydantic import BaseModel, ConfigDict, Field

from calib.io.registry import READERS, LogReader
from calib.sim.rfs import RfsSimConfig, simulate_rfs, truth_profile
from detectors.kinds import DETECTORS, Detector, Measurements, register
from profiles.override import updated
from profiles.profile import DETECTOR_KINDS, DetectorKind
from profiles.store import dump_profile
from slam_runtime.mapfilter import MAP_FILTERS, MapFilter
from tests.detcal.cli.test_cli import run


# ---------------------------------------------------------------------------- a toy log reader: a scenario file
def read_toy(path, options):
    """A ``.toy`` file names an rfs-sim scenario by its seed and steps; the log is that simulation."""
    spec = yaml.safe_load(path.read_text())
    return simulate_rfs(RfsSimConfig(steps=spec["steps"]), spec["seed"])


# ---------------------------------------------------------------------------- a toy detector: the log's near detections
class NearDetections(Detector):
    """Keeps the log's detections nearer than 2 m (a ranger that sees less far than the simulated sensor)."""

    stream = "detections"
    needs = "takes the log's detections"

    def source(self, log, profile, detection, options):
        d = log.detections
        z = np.column_stack([d.range, d.bearing])
        return lambda frame: Measurements(z[frame.rows][z[frame.rows, 0] < 2.0])


# ---------------------------------------------------------------------------- a toy map filter: nearest-neighbour means
class NearestConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    kind: Literal["nearest"] = "nearest"
    # (not "gate": a setting of that name carries over from the filter --filter replaces, and means a squared
    # Mahalanobis distance there)
    radius: float = Field(default=0.1, gt=0.0, description="[m] a measurement within this of a feature updates it")


@dataclass
class NearestMaps:
    xy: np.ndarray  # (P, K, 2) running means
    n: np.ndarray  # (P, K) measurements averaged (0: an empty slot)

    def take(self, idx):
        return NearestMaps(self.xy[idx], self.n[idx])


class Nearest(MapFilter):
    """Each measurement, placed in the world from its particle's pose, updates the running mean of the nearest feature
    within ``radius`` or starts a new one; every particle's measurements at once (the loop is over one frame's
    measurements, each of which may start a feature the next one must see)."""

    name = "nearest"
    Config = NearestConfig

    def __init__(self, feature, detection, cfg) -> None:
        super().__init__(feature, detection)
        self.cfg = cfg
        self.r = feature.r

    def empty(self, n):
        return NearestMaps(np.zeros((n, 0, 2)), np.zeros((n, 0)))

    def update(self, maps, poses, meas):
        xy, cnt = maps.xy, maps.n
        p = xy.shape[0]
        world, _ = self.feature.inverse(poses[:, None, :], np.asarray(meas.z)[None, :, :])  # (P, M, 2)
        for m in range(world.shape[1]):
            w = world[:, m]
            d = np.where(cnt > 0, np.hypot(*(xy - w[:, None, :]).transpose(2, 0, 1)), np.inf)
            j = np.argmin(d, axis=1) if d.shape[1] else np.zeros(p, np.int64)
            hit = d[np.arange(p), j] < self.cfg.radius if d.shape[1] else np.zeros(p, bool)
            xy = np.concatenate([xy, np.zeros((p, 1, 2))], axis=1)
            cnt = np.concatenate([cnt, np.zeros((p, 1))], axis=1)
            slot = np.where(hit, j, xy.shape[1] - 1)
            rows = np.arange(p)
            cnt[rows, slot] += 1
            xy[rows, slot] += (w - xy[rows, slot]) / cnt[rows, slot][:, None]
        return NearestMaps(xy, cnt), np.zeros(p)

    def estimate(self, maps, i):
        keep = maps.n[i] >= 2  # seen at least twice: not a lone false alarm
        return maps.xy[i][keep], np.ones(int(keep.sum()))

    def size(self, maps):
        return (maps.n > 0).sum(axis=1).astype(float)


@pytest.fixture
def toys():
    """The three kinds registered as a plug-in module would register them, and taken out again after the test."""
    MAP_FILTERS.add("nearest", Nearest)
    READERS.add("toy", LogReader(lambda p: p.suffix == ".toy", read_toy))
    register("near-ranger", NearDetections(), DetectorKind(label="ranges"))
    yield
    MAP_FILTERS.remove("nearest")
    READERS.remove("toy")
    DETECTORS.remove("near-ranger")
    DETECTOR_KINDS.remove("near-ranger")


def test_a_toy_filter_reader_and_detector_run_through_the_command_line(tmp_path, capsys, toys):
    """slam run on a .toy log (the toy reader) with a profile of the toy detector and --filter nearest, mapping only
    (the true poses): the map is the true landmarks the ranger saw. Truth: the seeded simulator's landmarks; each
    mapped feature is the mean of at least two detections of 0.022 m range noise (var_range 5e-4), so within 0.1 m of
    its landmark (over 4 sigma of one detection); of 50 landmarks a few stay unseen (nearer than the sensor's 0.5 m
    or farther than 2 m from the whole path), 35 at least are mapped."""
    (tmp_path / "run.toy").write_text("seed: 3\nsteps: 300\n")
    prof = truth_profile(RfsSimConfig(steps=300))
    prof = updated(prof, {"name": "near-ranger", "detector.kind": "near-ranger"})
    (tmp_path / "p.yaml").write_text(dump_profile(prof))
    code, out, err = run(
        capsys, "slam", "run", str(tmp_path / "run.toy"), "--profile", str(tmp_path / "p.yaml"), "--filter", "nearest",
        "--poses", "ground_truth", "--particles", "2", "--out", str(tmp_path / "o"),
    )  # fmt: skip
    assert code == 0, err
    assert "nearest (nearest), 2 particles" in out  # the derived settings it printed name the toy filter
    truth = simulate_rfs(RfsSimConfig(steps=300), 3).landmarks.xy
    mapped = np.loadtxt(tmp_path / "o/map.csv", delimiter=",", skiprows=1, ndmin=2)[:, :2]
    err_m = np.min(np.hypot(*(mapped[:, None, :] - truth[None, :, :]).transpose(2, 0, 1)), axis=1)
    assert mapped.shape[0] >= 35 and err_m.max() < 0.1, (mapped.shape, err_m.max())
    settings = yaml.safe_load((tmp_path / "o/config.yaml").read_text())["settings"]
    assert settings["filter"] == {"kind": "nearest", "radius": 0.1}
