"""The runtime detection model a filter calls: P_D, clutter intensity and descriptor likelihoods.

Built from the parts of a detector profile (``profiles.schema``); a filter
passes arrays and gets arrays back. It is the only place that knows n_p, the
P_D tables, the buffer bands and the clutter:

* :meth:`DetectionModel.pd_points` -- P_D and buffer-zone flags of the point
  features of many particles' maps at once, (P, J): through n_p ray-traced
  against the current scan for a laser profile (eqs. 4.1, 6.1, 6.2), through the
  predicted measurement for a detection-level profile (:meth:`pd_at`), or a
  constant inside the field of view (for comparison);
* :meth:`DetectionModel.pd_at` -- P_D of a feature predicted at range-bearing z
  (sensor frame) for detection-level profiles: a range table or a range x
  bearing grid, 0 outside the field of view;
* :meth:`DetectionModel.pd_landmarks` -- P_D of L landmarks from one sensor pose
  given the current scan, with the buffer-zone flag of sec. 6.1 (for eq. 3.21);
* :meth:`DetectionModel.clutter_intensity` -- kappa(z): lambda / |FoV| inside
  the field of view (sec. 4.2), or lambda x the profile's clutter density over
  (range, bearing) when it has one; 0 outside;
* :meth:`DetectionModel.g_true` / :meth:`DetectionModel.g_false` -- the
  descriptor likelihoods of eq. 5.6 for the amplitude-feature update (eq. 2.26).

Buffer zone (eq. 3.21, sec. 6.1): a feature whose P_D is uncertain may not lose
weight when it is not detected. At the edges of the field of view and of the
range limits, whether the sensor reports a feature depends on the sensor's own
noise, so the band there is ``buffer_sigmas`` standard deviations of the
measurement noise (the profile's measured noise, else the sensor's range
sigma) combined with the feature's own spread; a well-mapped feature still
has a band as wide as the sensor's noise. For n_p profiles the thesis's rules
apply (samples across the line of sight, 0 < P_D < 0.5).
"""

from __future__ import annotations

from dataclasses import dataclass
from math import gamma as gamma_fn
from math import pi

import numpy as np
from scipy.special import chdtr  # chi-square CDF; scipy.stats (slow to import) is not needed here

from detectors.circle import hotelling_maha2
from detectors.sensor_log import SensorModel
from detectors.raytrace import buffer_zone, count_unoccluded, expected_pd, expected_unoccluded
from profiles.errors import DataError
from profiles.schema import PD_COVARIATES, ClutterParams, HotellingParams, MeasurementNoise, PdTable


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angles (any difference of two wrapped angles) wrapped to (-pi, pi]."""
    a = np.where(a > np.pi, a - 2 * np.pi, a)
    return np.where(a <= -np.pi, a + 2 * np.pi, a)


@dataclass(frozen=True, eq=False)
class DetectionModel:
    """P_D table + clutter + optional Hotelling model of one detector on one sensor.

    ``k_sigma`` is the occlusion tolerance of the ray tracer (in sigma_r);
    ``buffer_samples`` the number of lateral positions of the buffer-zone rule.

    Filter options (``slam_runtime.config.DetectionOptions``): ``constant_pd``
    replaces the profile's P_D by a constant inside the field of view (for
    comparison); ``buffer`` turns the buffer zone on; ``buffer_sigmas`` is its
    half-width in standard deviations; ``landmark_radius`` the radius the ray
    tracer gives map features (default: the typical true radius);
    ``phase_average`` takes n_p averaged over where the beams fall
    (:func:`detectors.raytrace.expected_unoccluded`) instead of the integer count.
    """

    pd_table: PdTable
    clutter: ClutterParams
    sensor: SensorModel
    hotelling: HotellingParams | None = None
    noise: MeasurementNoise | None = None
    k_sigma: float = 3.0
    buffer_samples: int = 5
    constant_pd: float | None = None
    buffer: bool = True
    buffer_sigmas: float = 2.0
    landmark_radius: float | None = None
    phase_average: bool = True
    frame_clutter: bool = False
    clutter_memory: float = 0.0
    occluder_radius: float | None = None
    occluder_weight: float = 0.5

    def __post_init__(self) -> None:
        c = self.pd_table.covariate
        if self.ray_traced and self.sensor.n_beams is None:
            raise DataError(f"an {c} P_D table needs a sensor model with a beam geometry")
        if self.ray_traced and self.sensor.range_sigma is None:
            raise DataError(f"an {c} P_D table needs the sensor's range_sigma (for the occlusion test)")

    @property
    def ray_traced(self) -> bool:
        """The P_D table's covariate is ray-traced against the current scan (n_p), not a function of the measurement."""
        return PD_COVARIATES.get(self.pd_table.covariate).ray_traced

    @classmethod
    def from_profile(cls, profile, sensor: SensorModel | None = None, **options) -> DetectionModel:
        """The runtime model of a :class:`profiles.profile.DetectorProfile`.

        sensor: the log's sensor model when it differs from the profile's in what
        the profile does not fix (e.g. a detection-level log's mount); ``options``
        are the filter options of the class docstring.
        """
        return cls(
            pd_table=profile.pd,
            clutter=profile.clutter,
            sensor=sensor if sensor is not None else profile.sensor,
            hotelling=profile.hotelling,
            noise=profile.noise,
            buffer_samples=profile.detector.buffer_samples,
            **{"occluder_radius": profile.detector.occluder_radius, "k_sigma": profile.detector.k_sigma, **options},
        )

    @classmethod
    def from_options(cls, profile, sensor, options, k_sigma: float | None = None) -> DetectionModel:
        """The runtime model with a filter's detection options (``slam_runtime.config.DetectionOptions``: P_D mode,
        buffer zone, landmark radius, phase averaging, occlusion) and occlusion tolerance ``k_sigma`` (None: the
        profile's)."""
        o = options
        return cls.from_profile(
            profile,
            sensor,
            constant_pd=o.constant_pd if o.pd_mode == "constant" else None,
            buffer=o.buffer_zone,
            buffer_sigmas=o.buffer_sigmas,
            landmark_radius=o.landmark_radius,
            phase_average=o.phase_average,
            frame_clutter=o.frame_clutter,
            clutter_memory=o.clutter_memory,
            **({} if o.occlusion else {"occluder_radius": None}),
            **({} if k_sigma is None else {"k_sigma": k_sigma}),
        )

    @property
    def noise_sigmas(self) -> tuple[float, float]:
        """(range [m], bearing [rad]) standard deviations of a detection: the profile's measured
        noise, else the sensor's range sigma (and no bearing term)."""
        if self.noise is not None:
            return float(self.noise.range_sigma), float(self.noise.bearing_sigma)
        return float(self.sensor.range_sigma or 0.0), 0.0

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

    def pd_landmarks(
        self,
        sensor_pose: np.ndarray,
        ranges: np.ndarray,
        centres: np.ndarray,
        radii: np.ndarray,
        lateral: np.ndarray | None = None,
        angles: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """P_D (L,) and buffer-zone flags (L,) of landmarks seen from one sensor pose.

        sensor_pose (3,) world; ranges (B,) the current scan; centres (L, 2) world;
        radii (L,) or scalar; lateral (L,) spread [m] for the buffer rule (e.g. 2
        standard deviations of the position across the line of sight); without it
        only the 0 < P_D < 0.5 rule applies. angles (B,): the scan's beam angles,
        needed for a laser of several beam layouts (``SensorLog.scan_angles(i)``);
        default the sensor's one layout.
        """
        s = self.sensor
        angles = s.angles() if angles is None else np.asarray(angles, dtype=np.float64)
        if lateral is None:
            n_p, _ = count_unoccluded(
                np.asarray(sensor_pose)[None], angles, np.asarray(ranges)[None], centres, radii,
                range_sigma=float(s.range_sigma), k_sigma=self.k_sigma, range_max=s.range_max,
            )
            pd = self.pd_of_np(n_p[0])
            return pd, (pd > 0) & (pd < 0.5)
        return buffer_zone(
            sensor_pose, angles, ranges, centres, radii, lateral, self.pd_of_np,
            samples=self.buffer_samples, range_sigma=float(s.range_sigma), k_sigma=self.k_sigma, range_max=s.range_max,
        )

    def pd_at(self, z: np.ndarray) -> np.ndarray:
        """P_D (...) of features predicted at range-bearing z (..., 2) (sensor frame): the profile's
        range table or range x bearing grid inside the field of view, 0 outside; a constant in
        constant mode. An n_p table needs the scan (:meth:`pd_points`)."""
        z = np.asarray(z, dtype=np.float64)
        if z.shape[-1:] != (2,):
            raise DataError(f"pd_at: z must have shape (..., 2) = (range, bearing), got {z.shape}")
        inside = self.in_fov(z)
        if self.constant_pd is not None:
            return np.where(inside, self.constant_pd, 0.0)
        return np.where(inside, self._table_at(z), 0.0)

    def _table_at(self, z: np.ndarray) -> np.ndarray:
        """The table's P_D at z (..., 2) as if inside the field of view: a grid's bearing is held to its
        edges, so a feature in the buffer band beyond an edge gets the edge cell's value."""
        t = self.pd_table
        of_z = PD_COVARIATES.get(t.covariate).from_measurement
        if of_z is None:
            raise DataError(f"P_D of a {t.covariate} table needs the scan (pd_points), not a predicted measurement")
        v = of_z(z)
        if t.two_d:
            return t.lookup_rb(v[..., 0], np.clip(v[..., 1], t.bearing_edges[0], t.bearing_edges[-1]))
        return t.lookup(v)

    def _edge_band(self, z: np.ndarray, s_rad: np.ndarray, s_lat: np.ndarray, pd_in: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """P_D and buffer flags at the edges of the field of view and the range limits.

        A feature within ``buffer_sigmas`` standard deviations (sensor noise and its own
        spread combined) of an edge is in the buffer zone; it is given the P_D it would
        have inside (pd_in), so a detection can still update it, and the filter keeps
        its weight when it is missed (eq. 3.21).
        """
        inside = self.in_fov(z)
        if not self.buffer:
            return np.where(inside, pd_in, 0.0), np.zeros(inside.shape, dtype=bool)
        sr, sb = self.noise_sigmas
        k = self.buffer_sigmas
        r = np.maximum(z[..., 0], 1e-9)
        band_r = k * np.sqrt(sr * sr + s_rad * s_rad)
        band_b = k * np.sqrt(sb * sb + (s_lat / r) ** 2)
        # the four shifted points (range out, in; bearing left, right) tested in one call: (4, ...) stacked
        zero = np.zeros_like(band_r)
        zb = np.zeros(band_b.shape)
        q = np.stack(
            [z[..., 0] + np.stack([band_r, -band_r, zero, zero]), _wrap(z[..., 1] + np.stack([zb, zb, band_b, -band_b]))], axis=-1
        )
        near = (self.in_fov(q) != inside).any(axis=0)
        pd = np.where(inside | near, pd_in, 0.0)
        return pd, near

    def pd_features(
        self, sensor_poses: np.ndarray, mu: np.ndarray, cov: np.ndarray, meas, weights: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """What a map filter calls: P_D (P, J) and buffer flags (P, J) of the map features mu (P, J, dx)
        with covariances cov (P, J, dx, dx) seen from sensor poses (P, 3), given the frame's measurements
        ``meas`` (:class:`slam_runtime.mapfilter.Measurements`: its scan and beam angles for n_p profiles)
        and the features' weights or existence probabilities (P, J) (who can occlude whom). Detection
        models of other feature kinds (planes) offer the same method."""
        pd, buf = self.pd_points(sensor_poses, mu, cov, getattr(meas, "scan", None), getattr(meas, "angles", None))
        if self.occluder_radius is not None and weights is not None and not self.ray_traced and mu.shape[1]:
            pd, buf = self._occlude(np.asarray(sensor_poses, dtype=np.float64), mu, cov, np.asarray(weights), pd, buf)
        return pd, buf

    def _occlude(self, sp, mu, cov, w, pd, buf) -> tuple[np.ndarray, np.ndarray]:
        """The n_p idea on a detection-level map: a feature whose centre lies behind a nearer confirmed
        feature (weight >= occluder_weight), within that trunk's angular half-width, has P_D 0; one within
        the half-width widened by buffer_sigmas of its own lateral spread is in the buffer zone."""
        p, j = pd.shape
        view = pd > 0
        jv = int(view.sum(axis=1).max())
        if jv < 2:
            return pd, buf
        sel = np.argsort(~view, axis=1, kind="stable")[:, :jv]
        rows = np.arange(p)[:, None]
        m, c, in_v = mu[rows, sel], cov[rows, sel], view[rows, sel]
        occluder = in_v & (w[rows, sel] >= self.occluder_weight)
        los = m - sp[:, None, :2]
        r = np.maximum(np.hypot(los[..., 0], los[..., 1]), 1e-9)
        b = np.arctan2(los[..., 1], los[..., 0])
        u = los / r[..., None]
        s_lat = np.sqrt(np.maximum(u[..., 1] ** 2 * c[..., 0, 0] - 2 * u[..., 0] * u[..., 1] * c[..., 0, 1] + u[..., 0] ** 2 * c[..., 1, 1], 0.0))
        rad = self.occluder_radius
        half = np.arcsin(np.clip(rad / r, 0.0, 1.0))  # (P, Jv) each occluder's angular half-width
        margin = self.buffer_sigmas * s_lat / r
        from detectors.occlusion import occlusion_flags  # numba: imported by the filters that need it only

        hidden, near = occlusion_flags(r, b, occluder, in_v, half, margin, float(rad))
        pd_v, buf_v = pd[rows, sel], buf[rows, sel]
        pd = pd.copy()
        buf = buf.copy()
        pd[rows, sel] = np.where(hidden, 0.0, pd_v)
        buf[rows, sel] = buf_v | (near & self.buffer)
        return pd, buf

    def pd_points(
        self,
        sensor_poses: np.ndarray,
        mu: np.ndarray,
        cov: np.ndarray,
        scan: np.ndarray | None = None,
        angles: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """P_D (P, J) and buffer-zone flags (P, J) of point features of P maps.

        sensor_poses (P, 3) world; mu (P, J, 2) world positions; cov (P, J, 2, 2) their
        covariances; scan (B,) the current scan's ranges and angles (B,) its beam angles
        (sensor frame; default: the sensor model's), needed by n_p profiles.
        """
        p, j = mu.shape[:2]
        sp = np.asarray(sensor_poses, dtype=np.float64)
        if j == 0:
            return np.zeros((p, 0)), np.zeros((p, 0), dtype=bool)
        from detectors.occlusion import line_of_sight  # numba: imported by the filters that need it only

        # range and bearing, and the position std along and across the line of sight
        z, s_rad, s_lat = line_of_sight(
            np.ascontiguousarray(sp), np.ascontiguousarray(mu, dtype=np.float64), np.ascontiguousarray(cov, dtype=np.float64)
        )
        if self.constant_pd is not None or not self.ray_traced:
            full = np.full((p, j), self.constant_pd) if self.constant_pd is not None else self._table_at(z)
            return self._edge_band(z, s_rad, s_lat, full)
        return self._pd_np(sp, mu, z, s_lat, scan, angles)

    def _pd_np(self, sp, mu, z, s_lat, scan, angles) -> tuple[np.ndarray, np.ndarray]:
        """n_p profiles: ray-trace only what can be seen (each particle's in-view features)."""
        if scan is None:
            raise DataError("an n_p profile needs the current scan to compute P_D")
        p, j = mu.shape[:2]
        inside = self.in_fov(z)
        pd_full = np.zeros((p, j))
        buf_full = np.zeros((p, j), dtype=bool)
        jf = int(inside.sum(axis=1).max())
        if jf == 0:
            return pd_full, buf_full
        sel = np.argsort(~inside, axis=1, kind="stable")[:, :jf]
        rows = np.arange(p)[:, None]
        mu_v, in_v = mu[rows, sel], inside[rows, sel]
        s = self.sensor
        ang = s.angles() if angles is None else np.asarray(angles, dtype=np.float64)
        radius = self.landmark_radius if self.landmark_radius is not None else self.typical_radius()
        occ = max(radius, self.large_radius()) if self.phase_average else None
        common = {"range_sigma": float(s.range_sigma), "k_sigma": self.k_sigma, "range_max": s.range_max}
        if self.buffer:
            # sec. 6.1: samples across the line of sight, spread by the position std
            lat = self.buffer_sigmas * s_lat[rows, sel]
            pd_v, buf_v = buffer_zone(
                sp, ang, scan, mu_v, radius, lat, self.pd_table.lookup, samples=self.buffer_samples,
                phase_average=self.phase_average, occlusion_radius=occ, **common,
            )
        elif self.phase_average:
            n_bar = expected_unoccluded(sp, ang, scan, mu_v, radius, occlusion_radius=occ, **common)
            pd_v, buf_v = expected_pd(n_bar, self.pd_table.lookup), np.zeros((p, jf), dtype=bool)
        else:
            n_p, _ = count_unoccluded(sp, ang, scan, mu_v, radius, **common)
            pd_v, buf_v = self.pd_table.lookup(n_p), np.zeros((p, jf), dtype=bool)
        pd_full[rows, sel] = np.where(in_v, pd_v, 0.0)
        buf_full[rows, sel] = buf_v & in_v
        return pd_full, buf_full

    # ------------------------------------------------------------------ clutter
    def in_fov(self, z: np.ndarray) -> np.ndarray:
        """(...) whether range-bearing points z (..., 2) lie in the field of view."""
        z = np.asarray(z)
        s = self.sensor
        ok = z[..., 0] >= s.range_min
        if s.range_max is not None:
            ok &= z[..., 0] <= s.range_max
        span = s.angle_span()  # over every beam layout of the laser
        if span is not None:
            ok &= (z[..., 1] >= span[0]) & (z[..., 1] <= span[1])
        elif s.fov is not None:
            ok &= np.abs(z[..., 1]) <= s.fov / 2
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
        mass = chdtr(d, h.gamma)  # the Gaussian's mass inside the ellipsoid
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
