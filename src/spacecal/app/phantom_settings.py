"""The settings of ``spacecal phantom`` (:class:`PhantomCommandSettings`): the paper's phantom
needle biopsy (§5.3) in simulation, or on the (simulated) devices, and the one-line refusals of
devices it cannot run on."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from spacecal.app.devices import SIMULATED
from spacecal.core.errors import InvalidInputError
from spacecal.core.strict_numbers import integer
from spacecal.experiments.phantom import PhantomSettings
from spacecal.sim.scenario import DEFAULT_SCENARIO
from spacecal.sim.world import World

#: The most cases the simulated phantom has planned paths for (the paper's five).
MAX_CASES_ON_DEVICES = World.PHANTOM_PATHS


@dataclass(frozen=True)
class PhantomCommandSettings:
    """``spacecal phantom``: the paper's phantom needle biopsy (§5.3): in simulation, or with
    ``robot`` and ``tracker`` on the (simulated) devices through ``acquire``, ``calibrate``,
    ``touch`` and ``guide`` (:mod:`spacecal.app.phantom_devices`).

    Attributes
    ----------
    scenario : str
        Preset name or scenario JSON file (on the devices: of the acquisition; a given
        calibration brings its own).
    method : str
        Calibration method.
    cases : int
        Needle paths (the paper: five; on the devices at most the simulated phantom's five).
    output, figure : str or None
        Results JSON and figure (paper Fig. 9) to write.
    robot, tracker : str or None
        ``sim``: run on the simulated devices (both, or neither); other devices are refused.
    calibration : str or None
        On the devices: a calibration to use instead of acquiring and calibrating.
    work_dir : str or None
        On the devices: the folder each step writes its files to (default ``OUTPUT_STEM.work``
        beside ``output``, else a new temporary folder, kept and named in the output).
    force : bool
    """

    scenario: str = DEFAULT_SCENARIO
    method: str = "paper"
    cases: int = PhantomSettings.cases
    output: str | None = None
    figure: str | None = None
    robot: str | None = None
    tracker: str | None = None
    calibration: str | None = None
    work_dir: str | None = None
    force: bool = False

    #: The command line's flag and argparse options of each field (``--force`` is shared).
    FLAGS: ClassVar[dict[str, tuple[str, dict[str, Any]]]] = {
        "scenario": ("--scenario", dict(help=f"scenario JSON file or preset (default {DEFAULT_SCENARIO})")),
        "method": ("--method", dict(help="calibration method")),
        "cases": ("--cases", dict(type=integer, help="needle paths (the paper: 5)")),
        "output": ("-o --output", dict(help="results JSON to write")),
        "figure": ("--figure", dict(help="PNG of the error curves (paper Fig. 9)")),
        "robot": ("--robot", dict(help="sim: on the simulated robot (with --tracker sim)")),
        "tracker": ("--tracker", dict(help="sim: through acquire, calibrate, touch and guide")),
        "calibration": ("--calibration", dict(help="on the devices: this calibration, not a new one")),
        "work_dir": ("--work-dir", dict(help="on the devices: folder of each step's files")),
    }

    def __post_init__(self) -> None:
        if not (isinstance(self.cases, int) and 1 <= self.cases <= 100):
            raise InvalidInputError(f"--cases must be 1..100, got {self.cases}")
        check_devices(self)


def check_devices(settings: PhantomCommandSettings) -> None:
    """Refuse, in one line, devices the phantom experiment cannot run on."""
    robot, tracker = settings.robot, settings.tracker
    if robot is None and tracker is None:
        for name, value in (("--calibration", settings.calibration), ("--work-dir", settings.work_dir)):
            if value is not None:
                raise InvalidInputError(f"{name} is for the phantom on the devices (--robot and --tracker)")
        return
    if robot is None or tracker is None:
        raise InvalidInputError(
            "the phantom on the devices needs both --robot and --tracker (or neither: the "
            "simulation without devices)"
        )
    if robot != SIMULATED or tracker != SIMULATED:
        raise InvalidInputError(
            "spacecal phantom runs on the simulated devices only (--robot sim --tracker sim): on real "
            "devices the second CT is a real scan of the phantom, which spacecal cannot take; run "
            "acquire, calibrate, touch and guide there yourself (docs/phantom.md)"
        )
    if not 1 <= settings.cases <= MAX_CASES_ON_DEVICES:
        raise InvalidInputError(
            f"--cases must be 1..{MAX_CASES_ON_DEVICES} on the devices (the simulated phantom's planned "
            f"paths), got {settings.cases}"
        )


__all__ = ["MAX_CASES_ON_DEVICES", "PhantomCommandSettings", "check_devices"]
