"""The runtime detection model a filter calls: P_D, clutter intensity and descriptor likelihoods.

Built from the parts of a detector profile (``profiles.schema``); a filter
passes arrays and gets arrays back:

* :meth:`DetectionModel.pd_landmarks` -- P_D of L landmarks from one sensor pose
  given the current scan, through n_p (eqs. 4.1, 6.1) and the P_D table, with
  the buffer-zone flag of sec. 6.1 (for eq. 3.21);
* :meth:`DetectionModel.pd_at` -- P_D at predicted measurements z = (range,
  bearing) in the sensor frame, for detection-level profiles (a range table or a
  range x bearing grid), 0 outside the field of view;
* :meth:`DetectionModel.pd_covariate` -- P_D from the covariate directly (e.g.
  range, for detectors without scans);
* :meth:`DetectionModel.clutter_intensity` -- kappa(z): lambda / |FoV| inside
  the field of view (sec. 4.2), or lambda x the profile's clutter density over
  (range, bearing) when it has one; 0 outside;
* :meth:`DetectionModel.g_true` / :meth:`DetectionModel.g_false` -- the
  descriptor likelihoods of eq. 5.6 for the amplitude-feature update (eq. 2.26).
"""

from __future__ import annotations

from dataclasses import dataclass
from math import gamma as gamma_fn
from math import pi

import numpy as np
from scipy.stats import chi2

from detectors.circle import hotelling_maha2
from detectors.logs import SensorModel
from detectors.raytrace import buffer_zone, count_unoccluded
from profiles.errors import DataError, UsageError
from profiles.schema import ClutterParams, HotellingParams, MeasurementNoise, PdTable


@dataclass(frozen=True, eq=False)
class DetectionModel:
    """P_D table + clutter + optional Hotelling model of one detector on one sensor.

    ``k_sigma`` is the occlusion tolerance of the ray tracer (in sigma_r);
    ``buffer_samples`` the number of lateral positions of the buffer-zone rule.
    """

    pd_table: PdTable
    clutter: ClutterParams
    sensor: SensorModel
    hotelling: HotellingParams | None = None
    noise: MeasurementNoise | None = None
    k_sigma: float = 3.0
    buffer_samples: int = 5

    def __post_init__(self) -> None:
        if self.pd_table.covariate == "n_p" and self.sensor.n_beams is None:
            raise DataError("an n_p P_D table needs a sensor model with a beam geometry")
        if self.pd_table.covariate == "n_p" and self.sensor.range_sigma is None:
            raise DataError("an n_p P_D table needs the sensor's range_sigma (for the occlusion test)")

    @classmethod
    def from_profile(cls, profile) -> DetectionModel:
        """The runtime model of a :class:`profiles.profile.DetectorProfile`."""
        return cls(
            pd_table=profile.pd,
            clutter=profile.clutter,
            sensor=profile.sensor,
            hotelling=profile.hotelling,
            noise=profile.noise,
            k_sigma=profile.detector.k_sigma,
            buffer_samples=profile.detector.buffer_samples,
        )

    # ------------------------------------------------------------------ P_D
    def radius_quantile(self, z: float, default: float) -> float:
        """Radius of true detections ``z`` standard deviations above the Hotelling mean (log-normal
        when the model has ``log_radius``), or ``default`` without a radius in the model."""
        h = self.hotelling
        for name, log in (("log_radius", True), ("radius", False)):
            if h is not None and name in h.names:
                i = h.names.index(name)
                v = h.mean[i] + z * np.sqrt(h.covariance[i][i])
                return float(np.exp(v) if log else v)
        return default

    def typical_radius(self, default: float = 0.2) -> float:
        """The radius of a typical true detection (the Hotelling mean), for ray tracing map features."""
        return self.radius_quantile(0.0, default)

    def large_radius(self, default: float = 0.5) -> float:
        """A generous radius: the Hotelling model's 99th percentile of true radii (occlusion tests)."""
        return self.radius_quantile(2.326, max(default, self.typical_radius()))

    def pd_of_np(self, n_p: np.ndarray) -> np.ndarray:
        return self.pd_table.lookup(n_p)

    def pd_covariate(self, v: np.ndarray) -> np.ndarray:
        """P_D for covariate values (any shape): n_p counts or ranges, as a one-covariate table says."""
        return self.pd_table.lookup(v)

    def pd_at(self, z: np.ndarray) -> np.ndarray:
        """P_D (...) at predicted measurements z (..., 2) = (range [m], bearing [rad]) in the sensor frame.

        For detection-level profiles: a range table (thesis eq. 6.2 with range as
        the covariate) or a range x bearing grid; 0 outside the field of view
        (range_min..range_max, the angular span). An n_p profile needs the current
        scan and raises :class:`UsageError` (use :meth:`pd_landmarks`).

        >>> # m = DetectionModel.from_profile(profile); m.pd_at(np.array([[2.0, 0.1], [9.0, 0.0]]))
        """
        t = self.pd_table
        if t.covariate == "n_p":
            raise UsageError("an n_p P_D table needs the current scan to ray-trace: use pd_landmarks, not pd_at")
        z = np.asarray(z, dtype=np.float64)
        if z.shape[-1:] != (2,):
            raise UsageError(f"pd_at: z must have shape (..., 2) = (range, bearing), got {z.shape}")
        return np.where(self.in_fov(z), t.lookup_rb(z[..., 0], z[..., 1]), 0.0)

    def pd_landmarks(
        self,
        sensor_pose: np.ndarray,
        ranges: np.ndarray,
        centres: np.ndarray,
        radii: np.ndarray,
        lateral: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """P_D (L,) and buffer-zone flags (L,) of landmarks seen from one sensor pose.

        sensor_pose (3,) world; ranges (B,) the current scan; centres (L, 2) world;
        radii (L,) or scalar; lateral (L,) spread [m] for the buffer rule (e.g. 2
        standard deviations of the position across the line of sight); without it
        only the 0 < P_D < 0.5 rule applies.
        """
        s = self.sensor
        if lateral is None:
            n_p, _ = count_unoccluded(
                np.asarray(sensor_pose)[None], s.angles(), np.asarray(ranges)[None], centres, radii,
                range_sigma=float(s.range_sigma), k_sigma=self.k_sigma, range_max=s.range_max,
            )
            pd = self.pd_of_np(n_p[0])
            return pd, (pd > 0) & (pd < 0.5)
        return buffer_zone(
            sensor_pose, s.angles(), ranges, centres, radii, lateral, self.pd_of_np,
            samples=self.buffer_samples, range_sigma=float(s.range_sigma), k_sigma=self.k_sigma, range_max=s.range_max,
        )

    # ------------------------------------------------------------------ clutter
    def in_fov(self, z: np.ndarray) -> np.ndarray:
        """(...) whether range-bearing points z (..., 2) lie in the field of view."""
        z = np.asarray(z)
        s = self.sensor
        ok = z[..., 0] >= s.range_min
        if s.range_max is not None:
            ok &= z[..., 0] <= s.range_max
        fov = s.field_of_view
        if fov is not None:
            if s.angle_min is not None and s.angle_increment is not None and s.n_beams is not None:
                lo = min(s.angle_min, s.angle_min + s.angle_increment * (s.n_beams - 1))
                ok &= (z[..., 1] >= lo) & (z[..., 1] <= lo + fov)
            else:
                ok &= np.abs(z[..., 1]) <= fov / 2
        return ok

    def clutter_intensity(self, z: np.ndarray) -> np.ndarray:
        """kappa(z) (M,) for range-bearing measurements z (M, 2) in the sensor frame.

        Per unit of range x bearing [1 / (m rad)]: lambda x density(z) when the
        profile has a clutter density (it integrates to lambda over the field of
        view), else the uniform lambda / |FoV| of the thesis (sec. 4.2); 0 outside
        the field of view. For an ``xy`` profile the uniform density per m^2 times
        the Jacobian r.
        """
        z = np.atleast_2d(np.asarray(z, dtype=np.float64))
        k = self.clutter.kappa
        if self.clutter.density is not None:
            return np.where(self.in_fov(z), self.clutter.rate * self.clutter.density.at(z[:, 0], z[:, 1]), 0.0)
        if self.clutter.space == "xy":
            # a uniform density in x-y is r times a density in (r, bearing)
            return np.where(self.in_fov(z), k * z[:, 0], 0.0)
        return np.where(self.in_fov(z), k, 0.0)

    # ------------------------------------------------------------------ descriptors (eq. 5.6)
    def _need_hotelling(self) -> HotellingParams:
        if self.hotelling is None:
            raise DataError("this profile has no Hotelling model: descriptor likelihoods are unavailable")
        return self.hotelling

    def g_true(self, desc: np.ndarray) -> np.ndarray:
        """g_x (eq. 5.6): the Gaussian of true detections truncated to the ellipsoid, renormalised."""
        h = self._need_hotelling()
        desc = np.atleast_2d(desc)
        d = len(h.names)
        m2 = hotelling_maha2(desc, h)
        cov = np.asarray(h.covariance)
        norm = np.sqrt((2 * pi) ** d * np.linalg.det(cov))
        mass = chi2.cdf(h.gamma, d)  # the Gaussian's mass inside the ellipsoid
        return np.where(m2 <= h.gamma, np.exp(-0.5 * m2) / norm / mass, 0.0)

    def g_false(self, desc: np.ndarray) -> np.ndarray:
        """g_FA (eq. 5.6): uniform over the ellipsoid, 1 / its volume inside and 0 outside."""
        h = self._need_hotelling()
        desc = np.atleast_2d(desc)
        d = len(h.names)
        m2 = hotelling_maha2(desc, h)
        unit_ball = pi ** (d / 2) / gamma_fn(d / 2 + 1)
        vol = unit_ball * h.gamma ** (d / 2) * np.sqrt(np.linalg.det(np.asarray(h.covariance)))
        return np.where(m2 <= h.gamma, 1.0 / vol, 0.0)


def fov_volume(sensor: SensorModel, space: str = "range_bearing") -> float:
    """Size of the field of view: range span x angular span [m rad], or its area [m^2]."""
    if sensor.range_max is None or sensor.field_of_view is None:
        raise DataError("the sensor model needs range_max and a field of view to spread clutter over")
    span = sensor.field_of_view
    if space == "xy":
        return 0.5 * span * (sensor.range_max**2 - sensor.range_min**2)
    return span * (sensor.range_max - sensor.range_min)
