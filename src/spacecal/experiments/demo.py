"""``spacecal demo``: the whole chain on the default simulated system, with a summary table."""

from __future__ import annotations

import time
from dataclasses import dataclass

from spacecal.estimators import calibrate
from spacecal.experiments.simulation import Simulation, simulate
from spacecal.experiments.truth import calibration_error
from spacecal.experiments.verification import verify_in_simulation
from spacecal.records import CalibrationResult, VerificationResult
from spacecal.records.paper_reference import PAPER_VERIFICATION
from spacecal.sim.scenario import Scenario


@dataclass
class DemoResult:
    """Everything the demo produced."""

    simulation: Simulation
    calibration: CalibrationResult
    calibration_error: dict
    verification: VerificationResult
    compute_time_s: float
    ml_calibration: CalibrationResult
    ml_calibration_error: dict

    def table(self) -> str:
        """The summary table printed by ``spacecal demo``."""
        plan = self.simulation.plan
        rec = self.simulation.recording
        err = self.calibration_error
        stats = self.verification.statistics()
        pos, ang = stats["position_mm"], stats["posture_deg"]
        p = PAPER_VERIFICATION
        rows = [
            ("scenario", self.simulation.world.scenario.name, ""),
            ("planned motion time", f"{plan.motion_time_s:.1f} s", "about 1 min"),
            ("samples (visible / total)", f"{int(rec.visible.sum())} / {len(rec)}", ""),
            ("samples used by the estimator", f"{self.calibration.sample_counts['used']}", ""),
            (
                "paper estimator: TRE, 200 mm cube (RMS / max)",
                f"{err['tre_rms_mm']:.3f} / {err['tre_max_mm']:.3f} mm",
                "",
            ),
            ("paper estimator: rotation error", f"{err['rotation_error_deg']:.4f} deg", ""),
            (
                "ML estimator, same data: TRE (RMS / max)",
                f"{self.ml_calibration_error['tre_rms_mm']:.3f} / "
                f"{self.ml_calibration_error['tre_max_mm']:.3f} mm",
                "",
            ),
            (
                "ML estimator: predicted TRE (noise only)",
                f"{(self.ml_calibration.predicted_tre_mm or {}).get('cube_rms', float('nan')):.3f} mm",
                "",
            ),
            (
                "ML estimator: expected error at a target, verdict",
                f"{_expected_mm(self.ml_calibration):.2f} mm, "
                f"{self.ml_calibration.verdict.grade if self.ml_calibration.verdict else 'none'}",
                "",
            ),
            (
                f"verification position error, {len(self.verification.position_error_mm)} points "
                "(min / mean / max)",
                f"{pos['min']:.2f} / {pos['mean']:.2f} / {pos['max']:.2f} mm",
                f"{p['position_min_mm']} / <{p['position_mean_bound_mm']} / - mm",
            ),
            (
                "verification posture error (min / mean / max)",
                f"{ang['min']:.2f} / {ang['mean']:.2f} / {ang['max']:.2f} deg",
                f"{p['posture_min_deg']} / ~{p['posture_mean_deg']} / - deg",
            ),
            ("paper estimator compute time", f"{self.compute_time_s * 1000:.0f} ms", ""),
        ]
        width = [max(len(r[i]) for r in rows + [("quantity", "spacecal", "paper")]) for i in range(3)]
        lines = [
            f"{'quantity':<{width[0]}}  {'spacecal':<{width[1]}}  paper",
            f"{'-' * width[0]}  {'-' * width[1]}  {'-' * width[2]}",
        ]
        lines += [f"{a:<{width[0]}}  {b:<{width[1]}}  {c}" for a, b, c in rows]
        if plan.messages:
            lines.append("")
            lines += [f"note: {m}" for m in plan.messages]
        return "\n".join(lines)


def run_demo(scenario: Scenario | None = None) -> DemoResult:
    """Simulate, calibrate with the paper's method, and verify, on one scenario; also
    calibrate the same recording by maximum likelihood for comparison.

    Parameters
    ----------
    scenario : Scenario, optional
        The default is the paper's system with realistic errors.
    """
    from spacecal.sim.scenario import PRESETS

    scenario = scenario or PRESETS["paper-realistic"]
    simulation = simulate(scenario)
    start = time.perf_counter()
    calibration = calibrate(simulation.recording, "paper", uncertainty=False)
    compute_time = time.perf_counter() - start
    verification = verify_in_simulation(calibration, scenario)
    ml = calibrate(simulation.recording, "ml")
    return DemoResult(
        simulation,
        calibration,
        calibration_error(calibration, simulation.world),
        verification,
        compute_time,
        ml,
        calibration_error(ml, simulation.world),
    )


def _expected_mm(calibration: CalibrationResult) -> float:
    """The expected position error at a target a result states (NaN when it has none), mm."""
    expected = calibration.expected_error
    return float("nan") if expected is None or expected.position_mm is None else expected.position_mm
