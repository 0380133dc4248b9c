"""Profile parts of the planar 3D path (profile kind ``lidar3d-planes``).

* :class:`PlaneDetectorParams` -- the plane detector's parameters
  (``detectors.plane``), stored in ``detector.plane``;
* :class:`PlaneStats` -- what a plane calibration measured beyond the 1-D P_D
  table: P_D over (expected visible points x incidence angle), the noise of a
  detected plane's normal and offset, which planes count as landmarks, and how
  the runtime's estimate of the visible points relates to the ray-traced count.

The 1-D table ``pd`` of such a profile has the covariate ``points``: the
expected number of lidar returns on the visible part of a plane (the n_p idea
in 3D); its clutter lives in the plane chart (azimuth, elevation, offset) of
the landmark planes.
"""

from __future__ import annotations

import numpy as np
from pydantic import ConfigDict, Field, model_validator

from profiles.schema import Strict


class PlaneDetectorParams(Strict):
    """Parameters of the plane detector (``detectors.plane.detect_planes``).

    Cells are spherical (azimuth x elevation x log-range), so a cell holds about the
    same number of returns near and far; planar cells are merged by region growing,
    then every region is refitted with the MSSE robust estimator.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    cell_azimuth_deg: float = Field(default=1.0, gt=0.0, le=20.0, description="cell width in azimuth [deg]")
    cell_elevation_deg: float = Field(default=1.2, gt=0.0, le=20.0, description="cell height in elevation [deg]")
    cell_range_ratio: float = Field(default=1.25, gt=1.0, le=2.0, description="ratio of a cell's far and near range")
    range_min: float = Field(default=1.0, gt=0.0, description="returns closer than this are ignored [m]")
    min_cell_size: float = Field(default=0.3, gt=0.0, description="cells near the sensor grow (by whole multiples) to at least this width [m]")
    min_cell_points: int = Field(default=6, ge=4, description="fewest returns in a cell for a local plane")
    range_sigma: float = Field(default=0.02, gt=0.0, description="the sensor's range noise [m] (sets the thickness tests)")
    merge_angle_deg: float = Field(default=6.0, gt=0.0, le=45.0, description="largest normal angle between neighbouring cells of one plane")
    merge_offset: float = Field(default=0.10, gt=0.0, description="largest offset between neighbouring cells of one plane [m]")
    grow_steps: int = Field(default=4, ge=0, le=50, description="cells beyond a region's border it may take, step by step ...")
    grow_share: float = Field(default=0.3, gt=0.0, le=1.0, description="... when at least this share of a cell's returns lie on its plane")
    coplanar_angle_deg: float = Field(default=2.0, ge=0.0, le=20.0, description="regions this close in normal ...")
    coplanar_offset: float = Field(default=0.10, ge=0.0, description="... and offset [m] are one plane (0: never merge apart regions)")
    msse_t: float = Field(default=2.5, gt=0.0, description="MSSE threshold in scale units (Bab-Hadiashar & Suter: 2.5)")
    msse_min_fraction: float = Field(default=0.2, gt=0.0, lt=1.0, description="smallest inlier share MSSE starts from")
    refits: int = Field(default=2, ge=1, le=10, description="MSSE / least-squares rounds")
    min_points: int = Field(default=40, ge=4, description="fewest inliers of a reported plane")
    max_sigma: float = Field(default=0.08, gt=0.0, description="largest residual standard deviation of a reported plane [m]")


class PdGrid(Strict):
    """P_D over two covariates: expected visible points (``points_edges``) x incidence angle (``angle_edges_deg``).

    Cell (i, j) covers ``points_edges[i] <= n < points_edges[i+1]`` and
    ``angle_edges_deg[j] <= a < angle_edges_deg[j+1]``; beyond the last edges the
    last cells apply; below the first points edge P_D = 0. ``pd`` is (points bins,
    angle bins); cells with fewer than the fit's minimum count take the 1-D table's
    value for their points bin (said in ``filled``).
    """

    points_edges: list[float] = Field(min_length=2)
    angle_edges_deg: list[float] = Field(min_length=2)
    pd: list[list[float]]
    counts: list[list[int]]
    detections: list[list[int]]
    filled: list[list[bool]]

    @model_validator(mode="after")
    def _shapes(self) -> PdGrid:
        for name in ("points_edges", "angle_edges_deg"):
            if np.any(np.diff(getattr(self, name)) <= 0):
                raise ValueError(f"{name} must increase strictly")
        shape = (len(self.points_edges) - 1, len(self.angle_edges_deg) - 1)
        for name in ("pd", "counts", "detections", "filled"):
            a = getattr(self, name)
            if len(a) != shape[0] or any(len(row) != shape[1] for row in a):
                raise ValueError(f"{name} must be {shape[0]} x {shape[1]}")
        if any(not 0.0 <= p <= 1.0 for row in self.pd for p in row):
            raise ValueError("pd values must lie in [0, 1]")
        return self

    def lookup(self, points: np.ndarray, angle: np.ndarray) -> np.ndarray:
        """P_D for expected visible points and incidence angles [rad] (broadcasting)."""
        pe, ae = np.asarray(self.points_edges), np.radians(np.asarray(self.angle_edges_deg))
        pd = np.asarray(self.pd)
        points = np.asarray(points, dtype=np.float64)
        i = np.clip(np.searchsorted(pe, points, side="right") - 1, 0, pd.shape[0] - 1)
        j = np.clip(np.searchsorted(ae, np.asarray(angle, dtype=np.float64), side="right") - 1, 0, pd.shape[1] - 1)
        return np.where(points < pe[0], 0.0, pd[i, j])


class PlaneNoise(Strict):
    """Spread of true detections' sensor-frame chart (azimuth, elevation, offset) about the truth.

    Robust standard deviations (1.4826 x MAD) and median biases; the filter takes the
    sigmas as the floor of its plane measurement noise.
    """

    azimuth_sigma: float = Field(gt=0.0, description="[rad]")
    elevation_sigma: float = Field(gt=0.0, description="[rad]")
    offset_sigma: float = Field(gt=0.0, description="[m]")
    normal_angle_median: float = Field(ge=0.0, description="median angle between detected and true normals [rad]")
    offset_bias: float = Field(default=0.0, description="[m]")
    samples: int = Field(default=0, ge=0)


class PlaneStats(Strict):
    """The plane-specific part of a ``lidar3d-planes`` profile."""

    pd_grid: PdGrid | None = None
    noise: PlaneNoise | None = None
    max_elevation_deg: float = Field(default=45.0, gt=0.0, le=90.0, description="planes whose normal is within this of horizontal are landmarks")
    min_points: int = Field(default=40, ge=1, description="detections with fewer inliers are not used")
    min_width: float = Field(default=0.0, ge=0.0, description="detections narrower than this (shorter side of the enclosing rectangle) are not used [m]")
    offset_max: float = Field(gt=0.0, description="largest sensor-frame offset of a landmark plane [m] (the clutter space)")
    slab_k_sigma: float = Field(default=3.0, gt=0.0, description="half-width of the runtime's slab of a plane, in noise sigmas")
    slab_ratio: float | None = Field(
        default=None, gt=0.0, description="median of (returns in the slab of a true plane) / (ray-traced expected points) in calibration"
    )
