"""The simulated world: the ground truth a calibration tries to recover, and how it is measured.

Built deterministically from a scenario's seed, so ``spacecal simulate`` and
``spacecal verify`` given the same scenario see the same world. Measurement noise draws
from a separate stream.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from spacecal.core.errors import InvalidInputError, UnreachableError
from spacecal.geometry.fitting import fit_rigid
from spacecal.geometry.transforms import (
    invert_transform,
    make_transform,
    rotvec_to_matrix,
    transform_points_by_stack,
)
from spacecal.models.compliance import JointCompliance
from spacecal.models.kinematics import RobotModel, forward_kinematics
from spacecal.models.marker import MarkerGeometry, ndi_8700339_like
from spacecal.models.robot_errors import REPEATABILITY_TO_AXIS_SD
from spacecal.models.robot_kinds import robot_kind
from spacecal.models.tracker import TrackerModel
from spacecal.planning.needle import plan_needle
from spacecal.planning.visibility import VisibilityModel
from spacecal.sim import tools as sim_tools
from spacecal.sim.scenario import Scenario
from spacecal.sim.tools import POINTER, REFERENCE, PhantomTruth, PlannedPath


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
    tools : dict of str to MarkerGeometry
        The further tools the tracker can follow, by name: ``pointer`` (a hand-held tracked
        pointer) and ``reference`` (a marker rigidly on the needle guide, its own tool
        definition); see :mod:`spacecal.sim.tools`.
    pointer_from_tip_true, pointer_from_tip : numpy.ndarray, shape (4, 4)
        Where the pointer's tip really is, and where its pivot calibration puts it (the truth
        off by :data:`~spacecal.sim.tools.POINTER_TIP_ERROR_MM` RMS): the one a user knows.
    tcp_from_reference : numpy.ndarray, shape (4, 4)
        The guide's reference marker on the TCP (truth), mm.
    reference_from_needle : numpy.ndarray, shape (4, 4)
        The needle in the reference marker's frame as the guide's own definition gives it (its
        tool file), independent of the calibrated marker; the needle is the TCP here.
    tool_noise_rng : numpy.random.Generator
        The further tools' measurement noise, a stream apart from :attr:`noise_rng`.
    pointer_hand_rng : numpy.random.Generator
        Draws how the pointer is held at each touch.
    tracker_from_pointer_held : numpy.ndarray, shape (4, 4), or None
        Where the pointer is held now (truth), None while it is put away.
    pointer_fiducial : str or None
        The fiducial the pointer touches now.
    pointer_sway_mm : float
        The hand's sway while it holds the pointer: the pointer moves (sinusoidally, at
        :data:`POINTER_SWAY_HZ`, this amplitude along the tracker's x) instead of holding still.
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
    tools: dict[str, MarkerGeometry] = field(default_factory=dict)
    pointer_from_tip_true: np.ndarray = field(default_factory=lambda: np.eye(4))
    pointer_from_tip: np.ndarray = field(default_factory=lambda: np.eye(4))
    tcp_from_reference: np.ndarray = field(default_factory=lambda: np.eye(4))
    reference_from_needle: np.ndarray = field(default_factory=lambda: np.eye(4))
    tool_noise_rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))
    pointer_hand_rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))
    tracker_from_pointer_held: np.ndarray | None = None
    pointer_fiducial: str | None = None
    pointer_sway_mm: float = 0.0

    #: The frequency (Hz) of a swaying hand (:attr:`pointer_sway_mm`).
    POINTER_SWAY_HZ = 1.0
    #: Fiducials on the phantom, and needle paths planned in it (the paper's five cases, §5.3;
    #: drawn in order, so the first paths stay those of fewer).
    PHANTOM_FIDUCIALS, PHANTOM_PATHS = 6, 5
    #: The head's semi-axes (mm) and the paths' depths below their entries (mm), as the
    #: phantom experiment's (:mod:`spacecal.experiments.phantom`).
    HEAD_RADII_MM, PATH_DEPTH_MM = (75.0, 90.0, 65.0), (40.0, 70.0)
    #: Least distance (mm) between two fiducials.
    FIDUCIAL_SPACING_MM = 30.0
    #: Draws of a fiducial or a path before the phantom counts as not buildable.
    PHANTOM_ATTEMPTS = 200

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
        dynamics = robot_kind(self.scenario.robot_model).dynamics
        if dynamics is None:
            raise InvalidInputError(
                f"scenario: the {self.scenario.robot_model} has no published link dynamics, so no gravity "
                f"model: set joint_stiffness_nm_per_rad to zeros (a rigid arm)"
            )
        return JointCompliance(
            np.divide(1.0, stiffness, out=np.zeros_like(stiffness), where=stiffness > 0),
            payload_kg=self.scenario.payload_kg,
            dynamics=dynamics,
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

    # -- the phantom and the further tools -----------------------------------------------
    @functools.cached_property
    def phantom(self) -> PhantomTruth:
        """The head phantom in the tracker's view below the site (built on first use, from a
        stream of its own): as the phantom experiment places it, the image axes along the
        base's, fiducials on the upper half of the head that the pointer can touch in view,
        and :data:`PHANTOM_PATHS` needle paths the robot reaches (the controller's model,
        from home) with the marker and the guide's reference in view at the target.

        Raises
        ------
        UnreachableError
            The layout leaves no touchable fiducials or reachable paths.
        """
        rng = np.random.default_rng([self.scenario.seed, sim_tools.PHANTOM_STREAM])
        radii = np.asarray(self.HEAD_RADII_MM)
        home = forward_kinematics(self.nominal_model, self.home_joints_rad)
        head_centre_in_base = self.site_in_base + home[:3, :3] @ np.array([0.0, 0.0, 120.0])
        tracker_from_image = self.tracker_from_base @ make_transform(np.eye(3), head_centre_in_base)
        fiducials: dict[str, np.ndarray] = {}
        for _ in range(self.PHANTOM_ATTEMPTS):
            if len(fiducials) == self.PHANTOM_FIDUCIALS:
                break
            direction = rng.normal(size=3)
            direction[2] = abs(direction[2])  # the upper half (image z is base z: up)
            point = sim_tools.surface_point(radii, direction)
            if any(np.linalg.norm(point - other) < self.FIDUCIAL_SPACING_MM for other in fiducials.values()):
                continue  # spread out, as fiducials are placed for a registration
            try:  # a fiducial the pointer cannot touch in view is not one a user would mark
                sim_tools.pointer_pose_at(
                    point,
                    radii,
                    tracker_from_image,
                    self.pointer_from_tip_true,
                    self.tools[POINTER],
                    self.tracker,
                    np.random.default_rng([self.scenario.seed, sim_tools.PHANTOM_STREAM, len(fiducials)]),
                )
            except UnreachableError:
                continue
            fiducials[f"F-{len(fiducials) + 1}"] = point
        if len(fiducials) < self.PHANTOM_FIDUCIALS:
            raise UnreachableError(
                "the simulated phantom has too few fiducials the pointer can touch in view"
            )
        visibility = VisibilityModel(self.tracker, self.marker, self.tracker_from_base, self.tcp_from_marker)
        reference = self.tools[REFERENCE]
        paths: list[PlannedPath] = []
        for _ in range(self.PHANTOM_ATTEMPTS):
            if len(paths) == self.PHANTOM_PATHS:
                break
            top = rng.normal(size=3)
            top[2] = abs(top[2]) + 1.5  # entries on the upper surface, for a downward needle
            entry = sim_tools.surface_point(radii, top)
            target = entry * (1.0 - rng.uniform(*self.PATH_DEPTH_MM) / np.linalg.norm(entry))
            try:
                plan = plan_needle(
                    entry,
                    target,
                    tracker_from_image,
                    self.tracker_from_base,
                    self.controller_model,
                    self.home_joints_rad,
                    visibility=visibility,
                )
            except UnreachableError:
                continue
            tracker_from_reference = (
                self.tracker_from_base @ plan.base_from_needle_target @ self.tcp_from_reference
            )
            if not self.tracker.visible(
                tracker_from_reference[None], reference.spheres_in_marker, reference.face_normal_in_marker
            )[0]:
                continue
            paths.append(PlannedPath(f"T-{len(paths) + 1}", entry, target))
        if len(paths) < self.PHANTOM_PATHS:
            raise UnreachableError("the simulated phantom has too few needle paths the robot reaches")
        return PhantomTruth(radii, fiducials, tracker_from_image, tuple(paths))

    def place_pointer(self, which: int | str) -> np.ndarray:
        """Hold the pointer with its true tip on fiducial ``which`` (its label, or its number
        from 1), at a random but plausible pose facing the tracker (a fresh draw each time),
        until it is placed again or put away; returns the true ``tracker_from_pointer`` (4, 4).

        Raises
        ------
        InvalidInputError
            No such fiducial.
        """
        phantom = self.phantom
        label, point = phantom.fiducial(which)
        self.tracker_from_pointer_held = sim_tools.pointer_pose_at(
            point,
            phantom.head_radii_mm,
            phantom.tracker_from_image,
            self.pointer_from_tip_true,
            self.tools[POINTER],
            self.tracker,
            self.pointer_hand_rng,
        )
        self.pointer_fiducial = label
        return self.tracker_from_pointer_held

    def put_pointer_away(self) -> None:
        """Put the pointer down out of the tracker's view: it is not seen."""
        self.tracker_from_pointer_held = None
        self.pointer_fiducial = None

    def true_tool_pose(self, name: str, base_from_tcp_true, time_s: float) -> np.ndarray | None:
        """The true ``tracker_from_<name>`` (4, 4) of a further tool at ``time_s`` (s) with the
        TCP really at ``base_from_tcp_true`` (4, 4); None for a pointer put away."""
        self.tool_geometry(name)
        if name == REFERENCE:
            return self.tracker_from_base @ np.asarray(base_from_tcp_true) @ self.tcp_from_reference
        held = self.tracker_from_pointer_held
        if held is None:
            return None
        if self.pointer_sway_mm == 0:
            return held
        sway = self.pointer_sway_mm * np.sin(2 * np.pi * self.POINTER_SWAY_HZ * time_s)
        return make_transform(np.eye(3), [sway, 0.0, 0.0]) @ held

    # -- the tracker -------------------------------------------------------------------
    def measure_spheres(
        self, tracker_from_marker_true, true_spheres=None, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        """Noisy sphere centres (N, K, 3) in the tracker frame for true marker poses (N, 4, 4).

        ``true_spheres`` (K, 3), mm, and ``rng`` measure another tool the same way (default:
        the marker's true spheres and :attr:`noise_rng`): the error field, the bias field and
        the white noise with its depth anisotropy are the tracker's, whatever it looks at."""
        t = np.asarray(tracker_from_marker_true).reshape(-1, 4, 4)
        if true_spheres is None:
            true_spheres = (
                self.marker.spheres_in_marker
                if self.true_spheres_in_marker is None
                else self.true_spheres_in_marker
            )
        rng = self.noise_rng if rng is None else rng
        spheres = transform_points_by_stack(t, true_spheres)
        spheres = spheres + self.error_field(spheres)
        if self.bias_field is not None:
            spheres = spheres + self.bias_field(spheres)
        s = self.scenario
        if s.white_noise_rms_mm > 0:
            lateral_sd = s.white_noise_rms_mm / np.sqrt(2.0 + s.depth_anisotropy**2)
            noise = rng.normal(scale=lateral_sd, size=spheres.shape)
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
        return self.track_geometry(tracker_from_marker_true, earlier_true)

    def track_tool(self, name: str, tracker_from_tool_true, earlier_true=None) -> TrackedFrames:
        """What the tracker reports for true poses (N, 4, 4) of a further tool of the world
        (:attr:`tools`: ``pointer``, ``reference``): the marker's measurement model (error
        field, bias, white noise, outliers, visibility, dropout) on the tool's geometry, with
        noise drawn from :attr:`tool_noise_rng` so that the marker's frames stay as they were.

        Raises
        ------
        InvalidInputError
            The world has no tool of that name.
        """
        tool = self.tool_geometry(name)
        return self.track_geometry(
            tracker_from_tool_true, earlier_true, tool, tool.spheres_in_marker, self.tool_noise_rng
        )

    def tool_geometry(self, name: str) -> MarkerGeometry:
        """The geometry of the world's further tool ``name`` (one line for an unknown one)."""
        if name not in self.tools:
            raise InvalidInputError(
                f"the simulated world has no tool {name!r} (its tools: {', '.join(self.tools) or 'none'})"
            )
        return self.tools[name]

    def track_geometry(
        self,
        tracker_from_marker_true,
        earlier_true=None,
        geometry: MarkerGeometry | None = None,
        true_spheres=None,
        rng: np.random.Generator | None = None,
    ) -> TrackedFrames:
        """:meth:`track_marker` for any tool: ``geometry`` is what the tracker fits (default
        the marker's), ``true_spheres`` (K, 3) where the spheres really are (default the
        marker's), ``rng`` the noise stream (default :attr:`noise_rng`)."""
        marker = self.marker if geometry is None else geometry
        rng = self.noise_rng if rng is None else rng
        truth = np.asarray(tracker_from_marker_true).reshape(-1, 4, 4)
        n = len(truth)
        shown = truth.copy()
        kind = np.full(n, "", dtype=object)
        outliers = np.flatnonzero(rng.random(n) < self.scenario.outlier_fraction)
        kinds = rng.integers(0, 3, len(outliers))
        stale = outliers[kinds == 1]
        history = (
            truth if earlier_true is None else np.concatenate([np.reshape(earlier_true, (-1, 4, 4)), truth])
        )
        lead = len(history) - n
        shown[stale] = history[np.maximum(stale + lead - rng.integers(2, 9, len(stale)), 0)]
        reflections = outliers[kinds == 2]
        offsets = _random_directions(rng, len(reflections)) * rng.uniform(5.0, 30.0, (len(reflections), 1))
        tilts = _random_directions(rng, len(reflections)) * np.radians(
            rng.uniform(1.0, 5.0, (len(reflections), 1))
        )
        shown[reflections] = make_transform(rotvec_to_matrix(tilts), offsets) @ shown[reflections]
        spheres = self.measure_spheres(shown, true_spheres, rng)
        misdetected = outliers[kinds == 0]
        which = rng.integers(0, len(marker.spheres_in_marker), len(misdetected))
        spheres[misdetected, which] += _random_directions(rng, len(misdetected)) * rng.uniform(
            3.0, 10.0, (len(misdetected), 1)
        )
        kind[misdetected], kind[stale], kind[reflections] = "sphere", "stale", "reflection"
        measured, rms = fit_rigid(points_in_source=marker.spheres_in_marker, points_in_target=spheres)
        seen = self.tracker.visible(truth, marker.spheres_in_marker, marker.face_normal_in_marker)
        seen &= rng.random(n) >= self.scenario.dropout_probability
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
        rng.normal(scale=scenario.calibration_residual_length_sd_mm, size=true_model.n_joints),
        rng.normal(scale=scenario.calibration_residual_length_sd_mm, size=true_model.n_joints),
        rng.normal(scale=residual_angle_sd, size=true_model.n_joints),
        rng.normal(scale=residual_angle_sd, size=true_model.n_joints),
    )
    if scenario.controller_kinematics == "nominal":
        return nominal
    return true_model.with_dh_errors(*residual)


def build_world(scenario: Scenario) -> World:
    """Construct the ground truth of a scenario (deterministic in ``scenario.seed``)."""
    truth_rng = np.random.default_rng([scenario.seed, 0])
    noise_rng = np.random.default_rng([scenario.seed, 1])
    flange_from_tcp = make_transform(np.eye(3), scenario.tool_offset_mm)
    nominal = robot_kind(scenario.robot_model).model(flange_from_tcp)
    angle_sd = np.radians(scenario.dh_angle_error_sd_deg)
    joints = nominal.n_joints
    true_model = nominal.with_dh_errors(
        delta_a_mm=truth_rng.normal(scale=scenario.dh_length_error_sd_mm, size=joints),
        delta_d_mm=truth_rng.normal(scale=scenario.dh_length_error_sd_mm, size=joints),
        delta_alpha_rad=truth_rng.normal(scale=angle_sd, size=joints),
        delta_theta_rad=truth_rng.normal(scale=angle_sd, size=joints),
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
    # the further tools, from streams of their own (see spacecal.sim.tools)
    tools_rng = np.random.default_rng([scenario.seed, sim_tools.TOOLS_STREAM])
    pointer_from_tip_true = make_transform(np.eye(3), sim_tools.POINTER_TIP_IN_POINTER)
    pointer_from_tip = make_transform(
        np.eye(3),
        pointer_from_tip_true[:3, 3]
        + tools_rng.normal(scale=sim_tools.POINTER_TIP_ERROR_MM / np.sqrt(3.0), size=3),
    )
    reference_in_base = home[:3, :3] @ np.asarray(sim_tools.REFERENCE_OFFSET_IN_TCP) + site
    base_from_reference = sim_tools.face_towards(
        camera_in_base - reference_in_base, [0.0, 0.0, 1.0], reference_in_base
    )
    tcp_from_reference = invert_transform(home) @ base_from_reference
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
        tools={POINTER: sim_tools.pointer_geometry(), REFERENCE: sim_tools.reference_geometry()},
        pointer_from_tip_true=pointer_from_tip_true,
        pointer_from_tip=pointer_from_tip,
        tcp_from_reference=tcp_from_reference,
        # the guide's definition: exact (the needle is the TCP); the marker is not involved
        reference_from_needle=invert_transform(tcp_from_reference),
        tool_noise_rng=np.random.default_rng([scenario.seed, sim_tools.TOOL_NOISE_STREAM]),
        pointer_hand_rng=np.random.default_rng([scenario.seed, sim_tools.POINTER_HAND_STREAM]),
    )
