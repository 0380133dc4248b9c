"""Trajectories in the field's formats, and their scores against benchmark relations.

- TUM (Sturm et al., "A benchmark for the evaluation of RGB-D SLAM systems",
  IROS 2012): one line per pose, ``timestamp tx ty tz qx qy qz qw``, seconds
  and metres; a planar pose (x, y, theta) is z = 0 and the quaternion of a
  rotation by theta about z. ``evo_ape tum``, ``evo_rpe tum`` read it.
- KITTI (Geiger et al., CVPR 2012): one line per pose, the first three rows of
  the 4x4 pose matrix, row-major, no time; for planar poses the rotation is
  about z. ``evo_ape kitti`` reads it; it pairs poses by line, so it applies
  only against a reference with one pose per scan.
- Relations (Kümmerle et al., "On measuring the accuracy of SLAM algorithms",
  Autonomous Robots 2009): the error of each relative pose against a
  reference relation, translation [m] and rotation [deg]: mean +- standard
  deviation and maximum of the absolute errors, and of the squared ones
  (eq. 1 of that paper sums them).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.icp import relation_errors


def _stamp_text(stamps_ns: np.ndarray) -> list[str]:
    """Seconds with nine decimals, exact from integer nanoseconds."""
    s = np.asarray(stamps_ns, dtype=np.int64)
    sec, ns = np.divmod(s, 1_000_000_000)
    return [f"{a}.{b:09d}" for a, b in zip(sec.tolist(), ns.tolist(), strict=True)]


def tum_text(stamps_ns: np.ndarray, poses: np.ndarray) -> str:
    """TUM trajectory text of planar poses (S, 3) at integer-nanosecond stamps (S,)."""
    half = poses[:, 2] / 2.0
    rows = np.column_stack([poses[:, 0], poses[:, 1], np.zeros(len(poses)), np.zeros(len(poses)), np.zeros(len(poses)), np.sin(half), np.cos(half)])
    body = ["{} {:.9g} {:.9g} {:.9g} {:.9g} {:.9g} {:.9g} {:.9g}".format(t, *r) for t, r in zip(_stamp_text(stamps_ns), rows.tolist(), strict=True)]
    return "\n".join(["# timestamp tx ty tz qx qy qz qw", *body]) + "\n"


def kitti_text(poses: np.ndarray) -> str:
    """KITTI trajectory text of planar poses (S, 3): 3x4 pose matrices, row-major, one line each."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    z, o = np.zeros(len(poses)), np.ones(len(poses))
    rows = np.column_stack([c, -s, z, poses[:, 0], s, c, z, poses[:, 1], z, z, o, z])
    return "".join(" ".join(f"{v:.9g}" for v in r) + "\n" for r in rows.tolist())


def read_tum(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(stamps [s] (S,), planar poses (S, 3)) of a TUM file (the yaw of its quaternions)."""
    t = np.loadtxt(path, comments="#", ndmin=2)
    qx, qy, qz, qw = t[:, 4], t[:, 5], t[:, 6], t[:, 7]
    yaw = np.arctan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy**2 + qz**2))
    return t[:, 0], np.column_stack([t[:, 1], t[:, 2], yaw])


def relation_scores(stamps_ns: np.ndarray, poses: np.ndarray, relations: np.ndarray) -> dict:
    """Kümmerle et al. (2009) scores of poses (S, 3) at scan stamps against relations (R, 5) (t1, t2, x, y, yaw).

    Keys: relations (matched), trans_mean_m, trans_std_m, trans_max_m, trans_sq_mean_m2, trans_sq_std_m2, and the same
    for rotation in degrees (rot_*_deg, rot_sq_*_deg2).
    """
    et, er = relation_errors(stamps_ns, poses, relations)
    er = np.degrees(er)
    return {
        "relations": int(et.size),
        "trans_mean_m": float(et.mean()),
        "trans_std_m": float(et.std()),
        "trans_max_m": float(et.max()),
        "trans_sq_mean_m2": float((et**2).mean()),
        "trans_sq_std_m2": float((et**2).std()),
        "rot_mean_deg": float(er.mean()),
        "rot_std_deg": float(er.std()),
        "rot_max_deg": float(er.max()),
        "rot_sq_mean_deg2": float((er**2).mean()),
        "rot_sq_std_deg2": float((er**2).std()),
    }
