"""The station's "verify on the robot" step: the paper's verification experiment (§5.2) on the
calibration's devices, through :func:`spacecal.app.verification.verify_on_devices`.

A dry run first (the motion gate's summary, nothing moves), then a confirmation bound to that
dry run and to the calibration file's sha256, then the motion in its own process. What the page
shows at the end is read back from the verification JSON the run wrote, whose name carries the
calibration's digest, so the numbers shown are the file's and the file is of that calibration.
"""

from __future__ import annotations

import hashlib
import secrets
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from spacecal import app
from spacecal.app.verification import MAX_POSES, VerifySettings, verify_on_devices
from spacecal.core.errors import InvalidInputError
from spacecal.io.results_json import read_json_object
from spacecal.records import VerificationResult

#: The paper's verification (§5.2): position error min and mean, mm; posture error min and
#: mean, degrees (Table/Fig. 7: min 0.87 mm, mean under 1.05 mm; min 0.83 deg, mean about 1.1).
PAPER_POSITION_MM = "min 0.87, mean < 1.05"
PAPER_POSTURE_DEG = "min 0.83, mean about 1.1"
#: Needle poses a verification at the station reaches unless the operator asks for others
#: (the paper's 15).
DEFAULT_POSES = 15
#: Hex digits of the calibration's sha256 in the verification's file names.
DIGEST_IN_NAME = 12


def file_sha256(path: Path) -> str | None:
    """The file's sha256 (hex), None when it is not there."""
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


def poses_from_form(text: str) -> int:
    """The number of needle poses from the form (empty: :data:`DEFAULT_POSES`).

    Raises
    ------
    InvalidInputError
        Not a whole number in 1..MAX_POSES.
    """
    if not text:
        return DEFAULT_POSES
    if not text.isdigit() or not 1 <= int(text) <= MAX_POSES:
        raise InvalidInputError(f"the needle poses must be a whole number 1..{MAX_POSES}, not {text[:20]!r}")
    return int(text)


@dataclass(frozen=True)
class Verified:
    """A verification that ran to its end, as its JSON file says.

    Attributes
    ----------
    calibration_name, calibration_sha256 : str
        The calibration file verified and its sha256 when the motion was confirmed (and still
        when it ended).
    result : VerificationResult
        Read back from ``json_name``.
    json_name, figure_name : str
        The verification JSON and its Fig. 7 PNG in the calibration's folder.
    """

    calibration_name: str
    calibration_sha256: str
    result: VerificationResult
    json_name: str
    figure_name: str

    @property
    def statistics(self) -> dict[str, dict[str, float]]:
        return self.result.statistics()

    @property
    def rows(self) -> list[tuple[int, float, float]]:
        """Per pose: its number (1-based), position error, mm, and posture error, degrees."""
        return [
            (k + 1, float(p), float(a))
            for k, (p, a) in enumerate(zip(self.result.position_error_mm, self.result.posture_error_deg))
        ]


@dataclass
class VerifyStep:
    """The verification step of one calibration at the station.

    Attributes
    ----------
    calibration_path : Path
        The calibration it verifies.
    poses : int
        Needle poses of the last dry run.
    dry_run_lines : list of str
        The dry run's gate summary and plan.
    basis : str or None
        What a confirmation confirms: the dry run that passed and the calibration's sha256.
    done : Verified or None
        The last verification that ran to its end.
    """

    calibration_path: Path
    poses: int = DEFAULT_POSES
    dry_run_lines: list[str] = field(default_factory=list)
    basis: str | None = None
    moves: int = 0
    done: Verified | None = None

    def calibration_sha256(self) -> str | None:
        return file_sha256(self.calibration_path)

    def file_names(self, sha256: str) -> tuple[str, str]:
        """The verification JSON and figure of the calibration whose sha256 is ``sha256``."""
        stem = f"verification-{sha256[:DIGEST_IN_NAME]}"
        return f"{stem}.json", f"{stem}.png"

    def settings(
        self, devices: app.DeviceSettings, dry_run: bool, simulated_speed: float | None
    ) -> VerifySettings:
        """The verification's settings; its motion was confirmed on the station's page."""
        sha = self.calibration_sha256() or "none"
        json_name, figure_name = self.file_names(sha)
        folder = self.calibration_path.parent
        return VerifySettings(
            str(self.calibration_path),
            devices=devices,
            points=self.poses,
            dry_run=dry_run,
            confirm_robot_motion=not dry_run,
            simulated_speed=None if dry_run else simulated_speed,
            output=None if dry_run else str(folder / json_name),
            figure=None if dry_run else str(folder / figure_name),
            force=True,
        )

    def dry_run(self, devices: app.DeviceSettings, poses: int) -> None:
        """Plan the needle poses from where the robot stands and pass them through the motion
        gate; nothing moves. An earlier dry run's confirmation is worthless from here on."""
        self.basis, self.dry_run_lines, self.poses = None, [], poses
        before = self.calibration_sha256()
        if before is None:
            raise InvalidInputError("calibrate first: there is no calibration file to verify")
        out = verify_on_devices(self.settings(devices, dry_run=True, simulated_speed=None))
        gate = out.record.gate
        self.moves = gate.moves
        self.dry_run_lines = [gate.summary(), *gate.lines(), *out.notes, *out.lines]
        if gate.passed and self.calibration_sha256() == before:
            self.basis = f"verify-dry-run {secrets.token_hex(8)} poses {poses} calibration {before}"

    def motion_basis(self) -> str | None:
        """The dry run that passed, while the calibration file is still the one it planned for."""
        if self.basis is None or not self.basis.endswith(f"calibration {self.calibration_sha256()}"):
            return None
        return self.basis

    def words(self) -> str:
        sha = self.calibration_sha256() or ""
        return (
            f"the verification of {self.calibration_path.name} (sha256 {sha[:DIGEST_IN_NAME]}...): "
            f"{self.poses} needle poses around where the needle stands, each reached from home and "
            "held while the tracker measures it"
        )

    def finished(self, confirmed_sha256: str) -> Verified:
        """Read the verification the run wrote back from its file and keep it as done.

        Raises
        ------
        InvalidInputError
            The calibration file changed while the verification ran: the files are not of it.
        """
        now = self.calibration_sha256()
        if now != confirmed_sha256:
            raise InvalidInputError(
                f"{self.calibration_path.name} changed while it was verified: the verification's "
                "files are of the calibration confirmed, not of the one now on disk"
            )
        json_name, figure_name = self.file_names(confirmed_sha256)
        folder = self.calibration_path.parent
        data = read_json_object(folder / json_name, "verification")
        result = VerificationResult.from_dict(data, what=json_name)
        self.done = Verified(self.calibration_path.name, confirmed_sha256, result, json_name, figure_name)
        return self.done


def verification_line(output: Any) -> str:
    """How a verification that ran to its end ended (``output``: its
    :class:`~spacecal.app.verification.RobotVerifyOutput`), for its run's page."""
    result = output.result
    if result is None:
        return "nothing was run"
    s = result.statistics()
    pos, ang = s["position_mm"], s["posture_deg"]
    return (
        f"verified at {len(result.position_error_mm)} needle poses: position error min / mean / max "
        f"{pos['min']:.3f} / {pos['mean']:.3f} / {pos['max']:.3f} mm, posture error "
        f"{ang['min']:.3f} / {ang['mean']:.3f} / {ang['max']:.3f} deg"
    )
