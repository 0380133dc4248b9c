"""The C++ RFS-SLAM simulator's export folder (``rbphdslam2dSim``: ``gtPose.dat``, ``odometry.dat``,
``measurement.dat``, ``gtLandmark.dat``, ``simSettings.xml``) written from a seeded detcal rfs-sim run, in the
simulator's own layout ('%f' columns, as it prints them).

Run as a script it writes the small export shipped in ``tests/data/rfsslam-sim`` (200 steps, 50 landmarks, seed 0),
which the log-format how-to reads: ``python -m tests.data.rfsslam_export``. Same seed, same bytes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.sim.rfs import simulate_rfs
from detectors.sensor_log import SensorLog
from profiles.parameters import RfsSimConfig

XML = """<config>
  <logging><logResultsToFile>1</logResultsToFile><logTimingToFile>0</logTimingToFile><logDirPrefix>x/</logDirPrefix></logging>
  <timesteps>{steps}</timesteps><sec_per_timestep>0.1</sec_per_timestep>
  <trajectory><vardx>0.002</vardx><vardy>0.002</vardy><vardz>0.002</vardz></trajectory>
  <landmarks><nLandmarks>{landmarks}</nLandmarks></landmarks>
  <measurements><rangeLimitMax>2.5</rangeLimitMax><rangeLimitMin>0.5</rangeLimitMin><probDetection>0.99</probDetection>
    <clutterIntensity>0.0001</clutterIntensity><varzr>0.0005</varzr><varzb>0.00005</varzb></measurements>
</config>"""

SHIPPED = Path(__file__).parent / "rfsslam-sim"


def write_export(d: Path, log: SensorLog, steps: int, landmarks: int) -> Path:
    """The simulator's five files for ``log`` in folder ``d`` (created)."""
    d.mkdir(parents=True, exist_ok=True)
    t = log.odometry.stamp / 1e9
    poses = log.reference["ground_truth"].poses
    np.savetxt(d / "gtPose.dat", np.column_stack([t, poses]), fmt="%f")
    np.savetxt(d / "odometry.dat", np.column_stack([t, log.odometry.values]), fmt="%f")
    det = log.detections
    np.savetxt(d / "measurement.dat", np.column_stack([det.frame_stamp[det.frame] / 1e9, det.range, det.bearing]), fmt="%f")
    np.savetxt(d / "gtLandmark.dat", np.column_stack([log.landmarks.xy, np.zeros(landmarks)]), fmt="%f")
    (d / "simSettings.xml").write_text(XML.format(steps=steps, landmarks=landmarks))
    return d


def shipped_export(d: Path) -> Path:
    """The shipped example: rfs-sim's scenario, 200 steps, 50 landmarks, seed 0."""
    cfg = RfsSimConfig(steps=200, landmarks=50)
    return write_export(d, simulate_rfs(cfg, 0), cfg.steps, cfg.landmarks)


if __name__ == "__main__":
    shipped_export(SHIPPED)
