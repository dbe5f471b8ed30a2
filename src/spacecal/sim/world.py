"""The simulated world: the ground truth a calibration tries to recover, and how it is measured.

Built deterministically from a scenario's seed, so ``spacecal simulate`` and
``spacecal verify`` given the same scenario see the same world. Measurement noise draws
from a separate stream.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spacecal.geometry.fitting import fit_rigid
from spacecal.geometry.transforms import (
    invert_transform,
    make_transform,
    rotvec_to_matrix,
    transform_points_by_stack,
)
from spacecal.models.compliance import JointCompliance
from spacecal.models.kinematics import RobotModel, forward_kinematics, ur_model
from spacecal.models.marker import MarkerGeometry, ndi_8700339_like
from spacecal.models.robot_errors import REPEATABILITY_TO_AXIS_SD
from spacecal.models.tracker import TrackerModel
from spacecal.sim.scenario import Scenario


def look_at_tracker_from_base(camera_in_base, target_in_base) -> np.ndarray:
    """``tracker_from_base`` for a tracker at ``camera_in_base`` whose -z axis points at the target.

    The tracker's x axis is kept horizontal (perpendicular to base z).
    """
    z_axis = np.asarray(camera_in_base, float) - np.asarray(target_in_base, float)
    z_axis /= np.linalg.norm(z_axis)
    x_axis = np.cross([0.0, 0.0, 1.0], z_axis)
    if np.linalg.norm(x_axis) < 1e-9:
        x_axis = np.array([1.0, 0.0, 0.0])
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(z_axis, x_axis)
    base_from_tracker = make_transform(np.column_stack([x_axis, y_axis, z_axis]), camera_in_base)
    return invert_transform(base_from_tracker)


@dataclass(frozen=True)
class VolumetricErrorField:
    """A smooth, spatially correlated position error field in the tracker frame.

    A sum of random plane-wave modes ``a_k sin(w_k . p + phi_k)`` with wavelengths around
    the correlation length, rescaled to the requested 3-D RMS over the measurement volume.
    It models the part of a tracker's error that is fixed in space and does not average
    away with more samples.
    """

    amplitudes_mm: np.ndarray  # (K, 3)
    wave_vectors_per_mm: np.ndarray  # (K, 3)
    phases_rad: np.ndarray  # (K,)

    def __call__(self, points_in_tracker) -> np.ndarray:
        """Error vectors (…, 3), mm, at points (…, 3)."""
        phase = np.asarray(points_in_tracker) @ self.wave_vectors_per_mm.T + self.phases_rad
        return np.sin(phase) @ self.amplitudes_mm

    @classmethod
    def random(
        cls,
        rng: np.random.Generator,
        rms_mm: float,
        length_scale_mm: float,
        tracker: TrackerModel,
        modes: int = 12,
    ) -> VolumetricErrorField:
        directions = rng.normal(size=(modes, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        wavelengths = length_scale_mm * rng.uniform(1.0, 3.0, size=modes)
        field = cls(
            rng.normal(size=(modes, 3)),
            directions * (2 * np.pi / wavelengths)[:, None],
            rng.uniform(0, 2 * np.pi, size=modes),
        )
        if rms_mm == 0:
            return cls(np.zeros((modes, 3)), field.wave_vectors_per_mm, field.phases_rad)
        probe = _points_in_volume(rng, tracker, 4000)
        measured_rms = np.sqrt(np.mean(np.sum(field(probe) ** 2, axis=1)))
        return cls(field.amplitudes_mm * rms_mm / measured_rms, field.wave_vectors_per_mm, field.phases_rad)


def _random_directions(rng, count: int) -> np.ndarray:
    directions = rng.normal(size=(count, 3))
    return directions / np.linalg.norm(directions, axis=1, keepdims=True)


@dataclass
class TrackedFrames:
    """What the simulated tracker reports, plus the truth about which frames are outliers.

    Attributes
    ----------
    tracker_from_marker : numpy.ndarray, shape (N, 4, 4)
        NaN where not tracked.
    rms_mm : numpy.ndarray, shape (N,)
    spheres_in_tracker : numpy.ndarray, shape (N, K, 3)
        The measured sphere centres.
    outlier_kind : numpy.ndarray of str, shape (N,)
        ``""`` for a good frame, else ``sphere``, ``stale`` or ``reflection``.
    """

    tracker_from_marker: np.ndarray
    rms_mm: np.ndarray
    spheres_in_tracker: np.ndarray
    outlier_kind: np.ndarray


def _points_in_volume(rng, tracker: TrackerModel, count: int) -> np.ndarray:
    volume = tracker.volume
    depth = rng.uniform(volume.near_mm, volume.far_mm, count)
    scale = depth / volume.far_mm
    x = rng.uniform(-0.5, 0.5, count) * volume.far_width_mm * scale
    y = rng.uniform(-0.5, 0.5, count) * volume.far_height_mm * scale
    return np.column_stack([x, y, -depth])


@dataclass(frozen=True)
class TrackerBiasField:
    """Smooth tracker bias beyond :class:`VolumetricErrorField`: a depth-dependent scale and a
    low-order polynomial field over the measurement volume, in the tracker frame.

    The error at a point ``p`` (tracker frame, mm; depth ``z = -p_z``) is

    ``depth_scale_per_100mm * (z - reference_depth_mm) / 100 * p + sum_k c_k m_k(u)``

    where ``u`` are the point's coordinates normalised to the volume (x and y by the half
    width and height at the far face, depth by half the depth range about the reference) and
    ``m_k`` the monomials of degree 1 and 2 in ``u`` (9 of them). The first term is a scale
    error that grows with depth, as a stereo tracker's vergence error gives (its relative depth
    error grows linearly with depth); the second is a smooth, low-order distortion of the
    volume (coefficients ``c_k``, mm, shape (9, 3)).
    """

    depth_scale_per_100mm: float
    reference_depth_mm: float
    half_extent_mm: np.ndarray  # (3,): x, y at the far face; half the depth range
    coefficients_mm: np.ndarray  # (9, 3)

    @staticmethod
    def monomials(u) -> np.ndarray:
        """The 9 monomials of degree 1 and 2 (…, 9) of normalised coordinates ``u`` (…, 3)."""
        u = np.asarray(u, float)
        x, y, z = u[..., 0], u[..., 1], u[..., 2]
        return np.stack([x, y, z, x * x, y * y, z * z, x * y, x * z, y * z], axis=-1)

    def normalised(self, points_in_tracker) -> np.ndarray:
        """Coordinates (…, 3) of points (…, 3), mm, normalised to the volume (about -1..1)."""
        p = np.asarray(points_in_tracker, float)
        centred = np.stack([p[..., 0], p[..., 1], -p[..., 2] - self.reference_depth_mm], axis=-1)
        return centred / self.half_extent_mm

    def __call__(self, points_in_tracker) -> np.ndarray:
        """Error vectors (…, 3), mm, at points (…, 3), mm, in the tracker frame."""
        p = np.asarray(points_in_tracker, float)
        depth = -p[..., 2:3]
        error = self.depth_scale_per_100mm * (depth - self.reference_depth_mm) / 100.0 * p
        return error + self.monomials(self.normalised(p)) @ self.coefficients_mm

    @classmethod
    def random(
        cls,
        rng: np.random.Generator,
        depth_scale_per_100mm: float,
        polynomial_rms_mm: float,
        tracker: TrackerModel,
    ) -> TrackerBiasField:
        """A field with the given depth scale and a random polynomial part of the given 3-D RMS
        over the volume (uniform in the volume's pyramid); ``rng`` draws the coefficients and
        the probe points."""
        volume = tracker.volume
        reference = 0.5 * (volume.near_mm + volume.far_mm)
        half = np.array(
            [0.5 * volume.far_width_mm, 0.5 * volume.far_height_mm, 0.5 * (volume.far_mm - volume.near_mm)]
        )
        coefficients = rng.normal(size=(9, 3))
        field = cls(0.0, reference, half, coefficients)
        probe = _points_in_volume(rng, tracker, 4000)
        measured_rms = np.sqrt(np.mean(np.sum(field(probe) ** 2, axis=1)))
        scale = polynomial_rms_mm / measured_rms if polynomial_rms_mm > 0 else 0.0
        return cls(depth_scale_per_100mm, reference, half, coefficients * scale)


@dataclass
class World:
    """Ground truth and measurement models of one simulated set-up.

    Attributes
    ----------
    scenario : Scenario
    nominal_model : RobotModel
        The robot's catalogue model (nominal DH table, the scenario's tool): what the layout
        (site, verification targets) is defined with.
    true_model : RobotModel
        How the arm really moves (nominal plus DH length, twist and joint-offset errors).
    controller_model : RobotModel
        The controller's own kinematic model: what the robot reports its TCP pose through and
        solves its moves with (:func:`controller_model_of`): the nominal model, or its factory
        calibration (the true arm within a small residual).
    tracker_from_base, tcp_from_marker : numpy.ndarray, shape (4, 4)
        The two unknowns of the calibration, mm.
    tracker : TrackerModel
    marker : MarkerGeometry
    error_field : VolumetricErrorField
    home_joints_rad : numpy.ndarray, shape (6,)
    site_in_base : numpy.ndarray, shape (3,)
        The surgical site (TCP position at home), mm.
    noise_rng : numpy.random.Generator
        Stream for measurement noise, separate from the one that built the truth.
    bias_field : TrackerBiasField or None
        The depth-dependent scale and polynomial tracker bias; None when the scenario has
        neither (``depth_scale_per_100mm``, ``polynomial_error_rms_mm``).
    true_spheres_in_marker : numpy.ndarray, shape (K, 3), or None
        Where the marker's spheres really are in its frame, mm, when they differ from the
        definition the tracker fits (``marker_geometry_error_sd_mm``); None when they do not.
    """

    scenario: Scenario
    nominal_model: RobotModel
    true_model: RobotModel
    controller_model: RobotModel
    tracker_from_base: np.ndarray
    tcp_from_marker: np.ndarray
    tracker: TrackerModel
    marker: MarkerGeometry
    error_field: VolumetricErrorField
    home_joints_rad: np.ndarray
    site_in_base: np.ndarray
    noise_rng: np.random.Generator
    bias_field: TrackerBiasField | None = None
    true_spheres_in_marker: np.ndarray | None = None

    # -- the robot ---------------------------------------------------------------------
    def repeatability_offsets(self, count: int) -> np.ndarray:
        """Position scatter (count, 3), mm, of where the arm really comes to rest.

        The one repeatability model of the simulator: isotropic Gaussian with the per-axis
        s.d. that gives the scenario's ISO 9283 RP. The simulated robot draws one offset per
        stop (and one per state while moving); draws from ``noise_rng``.
        """
        sd = self.scenario.repeatability_mm * REPEATABILITY_TO_AXIS_SD
        if sd <= 0:
            return np.zeros((count, 3))
        return self.noise_rng.normal(scale=sd, size=(count, 3))

    def true_compliance(self) -> JointCompliance | None:
        """The shoulder's and elbow's true compliance under gravity: the inverse of the
        scenario's ``joint_stiffness_nm_per_rad`` (a stiffness of 0 standing for a rigid joint)
        with its ``payload_kg``; None on a rigid arm."""
        stiffness = np.asarray(self.scenario.joint_stiffness_nm_per_rad, float)
        if not np.any(stiffness > 0):
            return None
        return JointCompliance(
            np.divide(1.0, stiffness, out=np.zeros_like(stiffness), where=stiffness > 0),
            payload_kg=self.scenario.payload_kg,
        )

    def joint_deflections_rad(self, joints_rad) -> np.ndarray:
        """How far (N, 6), rad, the joints really are from the encoder angles (N, 6) under
        gravity: ``torque / stiffness`` on the shoulder and elbow (joints 2 and 3), the
        package's one deflection rule with :meth:`true_compliance` (zero on a rigid arm).
        The encoders sit on the motor side of the transmission, so the controller neither
        reports nor corrects it."""
        q = np.atleast_2d(np.asarray(joints_rad, float))
        compliance = self.true_compliance()
        if compliance is None:
            return np.zeros_like(q)
        return compliance.deflections_rad(self.true_model, q)

    def true_base_from_tcp(self, joints_rad, jitter: bool = True) -> np.ndarray:
        """Where the TCP really is (N, 4, 4) for joint angles (N, 6), with repeatability scatter
        (one :meth:`repeatability_offsets` draw per pose) unless ``jitter`` is False, and the
        joints' deflection under gravity (:meth:`joint_deflections_rad`) on a compliant arm."""
        joints = np.atleast_2d(joints_rad)
        if any(k > 0 for k in self.scenario.joint_stiffness_nm_per_rad):
            joints = joints + self.joint_deflections_rad(joints)
        poses = forward_kinematics(self.true_model, joints)
        if jitter and self.scenario.repeatability_mm > 0:
            poses = poses.copy()
            poses[:, :3, 3] += self.repeatability_offsets(len(poses))
        return poses

    # -- the tracker -------------------------------------------------------------------
    def measure_spheres(self, tracker_from_marker_true) -> np.ndarray:
        """Noisy sphere centres (N, K, 3) in the tracker frame for true marker poses (N, 4, 4)."""
        t = np.asarray(tracker_from_marker_true).reshape(-1, 4, 4)
        true_spheres = (
            self.marker.spheres_in_marker
            if self.true_spheres_in_marker is None
            else self.true_spheres_in_marker
        )
        spheres = transform_points_by_stack(t, true_spheres)
        spheres = spheres + self.error_field(spheres)
        if self.bias_field is not None:
            spheres = spheres + self.bias_field(spheres)
        s = self.scenario
        if s.white_noise_rms_mm > 0:
            lateral_sd = s.white_noise_rms_mm / np.sqrt(2.0 + s.depth_anisotropy**2)
            noise = self.noise_rng.normal(scale=lateral_sd, size=spheres.shape)
            if s.depth_anisotropy != 1.0:
                sight = spheres / np.linalg.norm(spheres, axis=-1, keepdims=True)
                along = np.sum(noise * sight, axis=-1, keepdims=True)
                noise = noise + (s.depth_anisotropy - 1.0) * along * sight
            spheres = spheres + noise
        return spheres

    def track_marker(self, tracker_from_marker_true, earlier_true=None) -> TrackedFrames:
        """What the tracker reports for true marker poses (N, 4, 4), in time order.

        ``earlier_true`` (M, 4, 4), the true poses of the frames just before these (oldest
        first), lets a streaming tracker report a stale frame from before the batch.

        The marker pose is a rigid fit of the marker geometry to the noisy spheres, as the
        tracker computes it. A share ``outlier_fraction`` of frames are gross errors (see
        :class:`~spacecal.sim.scenario.Scenario`); frames where the marker is not visible,
        or that drop out, are NaN.
        """
        truth = np.asarray(tracker_from_marker_true).reshape(-1, 4, 4)
        n = len(truth)
        shown = truth.copy()
        kind = np.full(n, "", dtype=object)
        outliers = np.flatnonzero(self.noise_rng.random(n) < self.scenario.outlier_fraction)
        kinds = self.noise_rng.integers(0, 3, len(outliers))
        stale = outliers[kinds == 1]
        history = (
            truth if earlier_true is None else np.concatenate([np.reshape(earlier_true, (-1, 4, 4)), truth])
        )
        lead = len(history) - n
        shown[stale] = history[np.maximum(stale + lead - self.noise_rng.integers(2, 9, len(stale)), 0)]
        reflections = outliers[kinds == 2]
        offsets = _random_directions(self.noise_rng, len(reflections)) * self.noise_rng.uniform(
            5.0, 30.0, (len(reflections), 1)
        )
        tilts = _random_directions(self.noise_rng, len(reflections)) * np.radians(
            self.noise_rng.uniform(1.0, 5.0, (len(reflections), 1))
        )
        shown[reflections] = make_transform(rotvec_to_matrix(tilts), offsets) @ shown[reflections]
        spheres = self.measure_spheres(shown)
        misdetected = outliers[kinds == 0]
        which = self.noise_rng.integers(0, len(self.marker.spheres_in_marker), len(misdetected))
        spheres[misdetected, which] += _random_directions(
            self.noise_rng, len(misdetected)
        ) * self.noise_rng.uniform(3.0, 10.0, (len(misdetected), 1))
        kind[misdetected], kind[stale], kind[reflections] = "sphere", "stale", "reflection"
        measured, rms = fit_rigid(points_in_source=self.marker.spheres_in_marker, points_in_target=spheres)
        seen = self.tracker.visible(truth, self.marker.spheres_in_marker, self.marker.face_normal_in_marker)
        seen &= self.noise_rng.random(n) >= self.scenario.dropout_probability
        measured[~seen] = np.nan
        rms = np.where(seen & self.scenario.tracker_reports_rms, rms, np.nan)
        kind[~seen] = ""
        return TrackedFrames(measured, rms, spheres, kind.astype(str))


def controller_model_of(
    scenario: Scenario, nominal: RobotModel, true_model: RobotModel, rng: np.random.Generator
) -> RobotModel:
    """The kinematic model the simulated controller reports and moves with.

    ``controller_kinematics == "nominal"``: the catalogue model. ``"calibrated"``: a factory
    calibration, the true arm plus a zero-mean Gaussian residual on each of the 24 DH
    parameters (s.d. ``calibration_residual_length_sd_mm`` on a and d,
    ``calibration_residual_angle_sd_deg`` on alpha and the joint offsets), as a real UR
    controller holds it and reports ``actual_TCP_pose`` through it.

    Universal Robots does not publish the absolute accuracy its factory calibration leaves.
    The residual assumed by paper-realistic (0.05 mm, 0.005 deg) puts the flange about
    0.2 mm RMS from the true arm over the workspace (0.4 mm at most), about a sixth of the
    nominal model's 1.3 mm: the accuracy published kinematic calibrations of collaborative
    arms reach (about 0.2 mm mean, e.g. Franzese et al., "MUKCa", arXiv:2503.12584, 2025),
    well above the arm's 0.1 mm repeatability. It is an assumption, to be replaced by a
    measured figure when one is at hand.

    Parameters
    ----------
    scenario : Scenario
    nominal, true_model : RobotModel
        The catalogue model and the true arm (same tool).
    rng : numpy.random.Generator
        Draws the residual (24 normals, a then d then alpha then theta offsets), whatever the
        mode, so that the rest of the world does not depend on it.

    Returns
    -------
    RobotModel
        Same name, tool, limits and rate as ``nominal``.
    """
    residual_angle_sd = np.radians(scenario.calibration_residual_angle_sd_deg)
    residual = (
        rng.normal(scale=scenario.calibration_residual_length_sd_mm, size=6),
        rng.normal(scale=scenario.calibration_residual_length_sd_mm, size=6),
        rng.normal(scale=residual_angle_sd, size=6),
        rng.normal(scale=residual_angle_sd, size=6),
    )
    if scenario.controller_kinematics == "nominal":
        return nominal
    return true_model.with_dh_errors(*residual)


def build_world(scenario: Scenario) -> World:
    """Construct the ground truth of a scenario (deterministic in ``scenario.seed``)."""
    truth_rng = np.random.default_rng([scenario.seed, 0])
    noise_rng = np.random.default_rng([scenario.seed, 1])
    flange_from_tcp = make_transform(np.eye(3), scenario.tool_offset_mm)
    nominal = ur_model(scenario.robot_model, flange_from_tcp)
    angle_sd = np.radians(scenario.dh_angle_error_sd_deg)
    true_model = nominal.with_dh_errors(
        delta_a_mm=truth_rng.normal(scale=scenario.dh_length_error_sd_mm, size=6),
        delta_d_mm=truth_rng.normal(scale=scenario.dh_length_error_sd_mm, size=6),
        delta_alpha_rad=truth_rng.normal(scale=angle_sd, size=6),
        delta_theta_rad=truth_rng.normal(scale=angle_sd, size=6),
    )
    home_joints = np.radians(np.asarray(scenario.home_joints_deg, float))
    home = forward_kinematics(nominal, home_joints)
    site = home[:3, 3].copy()
    azimuth = np.radians(scenario.tracker_azimuth_deg)
    elevation = np.radians(scenario.tracker_elevation_deg)
    direction = np.array(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)]
    )
    tracker_from_base = look_at_tracker_from_base(site + scenario.tracker_distance_mm * direction, site)

    # The marker sits at a fixed offset from the TCP with its face towards the tracker at home.
    marker_in_base = home[:3, :3] @ np.asarray(scenario.marker_offset_mm, float) + site
    camera_in_base = invert_transform(tracker_from_base)[:3, 3]
    normal = camera_in_base - marker_in_base
    normal /= np.linalg.norm(normal)
    up = np.cross(normal, np.cross([0.0, 0.0, 1.0], normal))
    up /= np.linalg.norm(up)
    marker = ndi_8700339_like()
    # marker x = face normal, marker z = the long axis of the sphere pattern, pointing up.
    base_from_marker = make_transform(np.column_stack([normal, np.cross(up, normal), up]), marker_in_base)
    tcp_from_marker = invert_transform(home) @ base_from_marker

    tracker = TrackerModel(rate_hz=scenario.tracker_rate_hz, max_view_angle_deg=scenario.max_view_angle_deg)
    field = VolumetricErrorField.random(
        truth_rng, scenario.volumetric_error_rms_mm, scenario.volumetric_length_scale_mm, tracker
    )
    # drawn after everything else, from its own stream, so that a scenario's arm, layout and
    # tracker error do not depend on the controller's model
    controller = controller_model_of(scenario, nominal, true_model, np.random.default_rng([scenario.seed, 4]))
    # the families added later each draw from a stream of their own, and only when switched
    # on, so that every other scenario's world is unchanged
    bias = None
    if scenario.depth_scale_per_100mm != 0 or scenario.polynomial_error_rms_mm > 0:
        bias = TrackerBiasField.random(
            np.random.default_rng([scenario.seed, 5]),
            scenario.depth_scale_per_100mm,
            scenario.polynomial_error_rms_mm,
            tracker,
        )
    true_spheres = None
    if scenario.marker_geometry_error_sd_mm > 0:
        true_spheres = marker.spheres_in_marker + np.random.default_rng([scenario.seed, 6]).normal(
            scale=scenario.marker_geometry_error_sd_mm, size=marker.spheres_in_marker.shape
        )
    return World(
        scenario,
        nominal,
        true_model,
        controller,
        tracker_from_base,
        tcp_from_marker,
        tracker,
        marker,
        field,
        home_joints,
        site,
        noise_rng,
        bias,
        true_spheres,
    )
