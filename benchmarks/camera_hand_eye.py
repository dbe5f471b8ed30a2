"""Hand-eye calibration from rendered ChArUco images through the ``camera://`` tracker: spacecal's
methods against OpenCV's ``calibrateHandEye`` (every method) and ``calibrateRobotWorldHandEye``
(both), on the same detected poses; prints a table per mount (eye-in-hand, eye-to-hand).

A simulated UR10 (nominal kinematics) moves through views of a 7 x 5 ChArUco board (30 mm
squares) 0.5-0.75 m from a 960 x 720 camera of 900 px focal length; the images are rendered
with pixel noise and blur (:mod:`spacecal.testing.charuco_render`), read back through
``camera://FOLDER?board=...&intrinsics=...&mount=...``, written as a recording and calibrated
with ``spacecal calibrate``'s app function (:mod:`spacecal.testing.camera_hand_eye`).

Columns: the error of the hand-eye transform (``flange_from_board`` eye-to-hand,
``flange_from_camera`` eye-in-hand) and of the fixed frame (``camera_from_base``,
``board_from_base``), rotation deg and translation mm, against the scene's truth. For a
calibrateHandEye method the transform it does not give is the mean over the views of what its
answer and each view make of it.

    python benchmarks/camera_hand_eye.py [--views 25] [--noise 4] [--blur 0.7] [--seeds 3]
        [--calibrate-intrinsics]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from spacecal.adapters.camera import MOUNT_FIXED, MOUNT_FLANGE
from spacecal.testing.camera_hand_eye import observe, opencv_rows, spacecal_rows
from spacecal.testing.charuco_render import simulate_scene

TITLES = {
    MOUNT_FLANGE: "eye-in-hand (camera on the flange, board fixed)",
    MOUNT_FIXED: "eye-to-hand (camera fixed, board on the flange)",
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=25)
    parser.add_argument("--noise", type=float, default=4.0, help="pixel noise, grey levels (1 sd)")
    parser.add_argument("--blur", type=float, default=0.7, help="Gaussian blur, px (1 sd)")
    parser.add_argument("--seeds", type=int, default=3, help="scenes per mount; the table shows medians")
    parser.add_argument("--calibrate-intrinsics", action="store_true", help="intrinsics from the same images")
    args = parser.parse_args()
    for mount in (MOUNT_FLANGE, MOUNT_FIXED):
        table: dict[tuple[str, str], list[tuple[float, float, float, float]]] = {}
        rms = []
        for seed in range(args.seeds):
            scene = simulate_scene(mount, args.views, seed=seed)
            with tempfile.TemporaryDirectory() as folder:
                observed = observe(
                    scene,
                    Path(folder) / "views",
                    args.noise,
                    args.blur,
                    not args.calibrate_intrinsics,
                    seed + 100,
                )
                if observed.intrinsics.rms_px is not None:
                    rms.append(observed.intrinsics.rms_px)
                rows = spacecal_rows(scene, observed, folder) + opencv_rows(scene, observed)
            for row in rows:
                table.setdefault((row.library, row.method), []).append(
                    (
                        row.hand_eye_deg,
                        row.hand_eye_mm,
                        row.fixed_deg,
                        row.fixed_mm,
                        row.predicted_hand_eye_mm,
                    )
                )
        print(
            f"\n{TITLES[mount]}: {args.views} views, noise {args.noise:g} grey, blur {args.blur:g} px, "
            f"median of {args.seeds} scene(s)"
            + (
                f"; intrinsics calibrated from the images, RMS {np.median(rms):.3f} px"
                if rms
                else "; intrinsics given"
            )
        )
        print(
            f"{'library':<34} {'method':<11} {'hand-eye deg':>12} {'hand-eye mm':>11} "
            f"{'fixed deg':>9} {'fixed mm':>8} {'predicted hand-eye mm (1 sd)':>28}"
        )
        for (library, method), values in table.items():
            med = np.median(np.array(values), axis=0)
            print(
                f"{library:<34} {method:<11} {med[0]:>12.4f} {med[1]:>11.3f} {med[2]:>9.4f} {med[3]:>8.3f}"
                + ("" if np.isnan(med[4]) else f" {med[4]:>28.3f}")
            )


if __name__ == "__main__":
    main()
