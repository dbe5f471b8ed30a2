"""The closed forms (tsai, park, daniilidis, li) against OpenCV's same-named methods; prints a table.

Datasets:

* Storz: UCL's laparoscope hand-eye set, 10 real views (../shared/realdata/handeye_storz_sksurgery),
  scored by the distance of the hand-eye H from the authors' SmartLiver result. Two ways in:
  "board": X = the board's pattern -> marker, as spacecal's registry maps the set, H averaged
  from X over the views (both libraries alike); "camera": X = H^-1 directly, as OpenCV's
  calibrateHandEye is usually fed (gripper2base = inv(T_obj) T_dev, target2cam = E).
* KinHEC (``pip install kinhec``): the smoke tier's noise track (16 sequences: ur5e and panda,
  eye-in-hand and eye-to-hand, joint sweeps and look-at stations; camera noise c1 = 0.03 deg,
  0.3/0.3/1 mm, or c4 = 0.57 deg, 6/6/20 mm) and outliers track (4 sequences of 20 stations:
  Gaussian or Student-t noise, 0 or 20 % planar-flip outliers), generated in memory, keyframed
  as KinHEC's benchmark does, in mm. Scored by the error of X against KinHEC's ground truth:
  median over the sequences (and the worst).

Both libraries get the same absolute poses; OpenCV forms every pair itself, spacecal takes
``motion_pairs`` (every pair up to 60 poses). Times are the median of 5 calls, one solve.

    python benchmarks/closed_forms.py [--realdata ../shared/realdata]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from spacecal.estimators.methods.hand_eye import motion_pairs, relative_motions
from spacecal.estimators.registry import ESTIMATORS, Family, estimators_of
from spacecal.geometry.rotations import mean_rotation, rotation_angle
from spacecal.geometry.transforms import invert_transform, make_transform

ROBOT_WORLD_SOLVERS = {name: spec.closed_form for name, spec in estimators_of(Family.ROBOT_WORLD).items()}
HAND_EYE_SOLVERS = {name: spec.closed_form for name, spec in estimators_of(Family.HAND_EYE).items()}

SOLVERS = ("tsai", "park", "daniilidis", "li")
HAND_EYE_FLAGS = {
    "tsai": cv2.CALIB_HAND_EYE_TSAI,
    "park": cv2.CALIB_HAND_EYE_PARK,
    "daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS,
}


def spacecal_solve(name: str, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """X (and Y for li) for A_i X = Y B_i, A_i = base_from_tcp, B_i = tracker_from_marker (mm)."""
    if ESTIMATORS[name].family is Family.ROBOT_WORLD:
        x, y = ROBOT_WORLD_SOLVERS[name](a, b)
        return x, y
    return HAND_EYE_SOLVERS[name](*relative_motions(a, b, motion_pairs(a))), None


def opencv_solve(name: str, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """OpenCV's X (and Y for LI) for the same A_i, B_i."""
    if name in HAND_EYE_FLAGS:
        b_inv = invert_transform(b)
        rotation, translation = cv2.calibrateHandEye(
            list(a[:, :3, :3]),
            list(a[:, :3, 3]),
            list(b_inv[:, :3, :3]),
            list(b_inv[:, :3, 3]),
            method=HAND_EYE_FLAGS[name],
        )
        return make_transform(rotation, translation.ravel()), None
    b_inv, a_inv = invert_transform(b), invert_transform(a)
    r_base2world, t_base2world, r_gripper2cam, t_gripper2cam = cv2.calibrateRobotWorldHandEye(
        list(b_inv[:, :3, :3]),
        list(b_inv[:, :3, 3]),
        list(a_inv[:, :3, :3]),
        list(a_inv[:, :3, 3]),
        method=cv2.CALIB_ROBOT_WORLD_HAND_EYE_LI,
    )
    x = invert_transform(make_transform(r_gripper2cam, t_gripper2cam.ravel()))
    y = invert_transform(make_transform(r_base2world, t_base2world.ravel()))
    return x, y


def timed(solve: Callable, *args) -> tuple[tuple[np.ndarray, np.ndarray | None] | None, float]:
    """The solver's answer (None if it raised or is not finite) and its median time (ms)."""
    times, result = [], None
    for _ in range(5):
        start = time.perf_counter()
        try:
            result = solve(*args)
        except Exception:  # a failure is a result here
            result = None
        times.append(time.perf_counter() - start)
    if result is not None and not all(np.all(np.isfinite(m)) for m in result if m is not None):
        result = None
    return result, 1000.0 * float(np.median(times))


def distance(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Rotation (deg) and translation (mm) distance."""
    try:
        angle = float(np.degrees(rotation_angle(estimate[:3, :3] @ truth[:3, :3].T)))
    except (ValueError, np.linalg.LinAlgError):
        return np.nan, np.nan
    return angle, float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3]))


# ---------------------------------------------------------------- Storz


def storz_cases(folder: Path) -> list[tuple[str, Callable, list[tuple[np.ndarray, np.ndarray]]]]:
    def load(name: str) -> np.ndarray:
        return np.loadtxt(folder / name).reshape(4, 4)

    views = range(10)
    device = np.array([load(f"tracking/calib.device_tracking.{i}.txt") for i in views])
    board = np.array([load(f"tracking/calib.calib_obj_tracking.{i}.txt") for i in views])
    camera = np.array(
        [load(f"derived_sksurgerycalibration_1.2.6/camera/calib.extrinsics.{i}.txt") for i in views]
    )
    smartliver = load("authors_reference/calib.left.handeye.txt")
    a, b = invert_transform(device) @ board, camera  # base_from_tcp, tracker_from_marker

    def board_side(x: np.ndarray, y: np.ndarray | None) -> tuple[float, float]:
        if y is not None:  # AX = YB: Y = base_from_tracker = inv(H)
            return distance(invert_transform(y), smartliver)
        each = b @ invert_transform(x) @ invert_transform(a)  # H per view, then their mean
        return distance(
            make_transform(mean_rotation(each[:, :3, :3]), each[:, :3, 3].mean(axis=0)), smartliver
        )

    def camera_side(x: np.ndarray, y: np.ndarray | None) -> tuple[float, float]:
        return distance(invert_transform(x), smartliver)  # X = inv(H) for both forms

    return [
        ("Storz, board (registry)", board_side, [(a, b)]),
        ("Storz, camera (X = H^-1)", camera_side, [(invert_transform(a), invert_transform(b))]),
    ]


# ---------------------------------------------------------------- KinHEC


def kinhec_cases() -> list[tuple[str, Callable, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]]:
    from kinhec.generator import generate_sequence
    from kinhec.io import Sequence
    from kinhec.motions import select_keyframes
    from kinhec.plans import build_plan, load_tier

    groups: dict[str, list] = {"KinHEC noise c1": [], "KinHEC noise c4": [], "KinHEC outliers": []}
    plan = build_plan(load_tier("smoke"), ["noise", "outliers"])
    for config in plan["noise"] + plan["outliers"]:
        record = generate_sequence(config)
        sequence = Sequence(record.manifest, record.robot_table, record.camera_table)
        a, b = sequence.axyb_poses()
        keep = select_keyframes(a)
        a, b, x = a[keep].copy(), b[keep].copy(), sequence.X.copy()
        for transform in (a, b, x):
            transform[..., :3, 3] *= 1000.0
        if config.track == "outliers":
            group = "KinHEC outliers"
        else:
            group = "KinHEC noise c1" if "camera=c1" in config.level else "KinHEC noise c4"
        groups[group].append((a, b, x))
    return [(name, None, cases) for name, cases in groups.items()]


# ---------------------------------------------------------------- table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parents[1].parent / "shared" / "realdata"
    parser.add_argument("--realdata", type=Path, default=default)
    args = parser.parse_args()

    datasets = []
    storz = args.realdata / "handeye_storz_sksurgery"
    if storz.exists():
        datasets += storz_cases(storz)
    else:
        print(f"(no Storz set at {storz}: skipped)")
    try:
        datasets += kinhec_cases()
    except ImportError:
        print("(kinhec not installed: KinHEC skipped)")

    print(f"OpenCV {cv2.__version__}; error of H from SmartLiver's (Storz) or of X from the truth (KinHEC);")
    print("KinHEC: median over the sequences (worst in brackets); n/a = failed or not finite\n")
    print(
        "| dataset | solver | spacecal (deg) | OpenCV (deg) | spacecal (mm) | OpenCV (mm) "
        "| spacecal (ms) | OpenCV (ms) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for label, score, cases in datasets:
        for name in SOLVERS:
            found: dict[str, dict[str, list]] = {
                library: {"deg": [], "mm": [], "ms": [], "failed": []} for library in ("spacecal", "OpenCV")
            }
            for case in cases:
                for library, solve in (("spacecal", spacecal_solve), ("OpenCV", opencv_solve)):
                    result, ms = timed(solve, name, case[0], case[1])
                    found[library]["ms"].append(ms)
                    if result is None:
                        found[library]["failed"].append(1)
                        continue
                    deg, mm = score(*result) if score is not None else distance(result[0], case[2])
                    found[library]["deg"].append(deg)
                    found[library]["mm"].append(mm)
            cells = [
                _cell(found[library][unit], len(found[library]["failed"]), len(cases))
                for unit in ("deg", "mm")
                for library in ("spacecal", "OpenCV")
            ]
            cells += [f"{np.median(found[library]['ms']):.1f}" for library in ("spacecal", "OpenCV")]
            print(f"| {label} | {name} | " + " | ".join(cells) + " |")


def _cell(values: list[float], failed: int, total: int) -> str:
    """Median (worst) over the cases, or the single value; failures counted."""
    finite = [v for v in values if np.isfinite(v)]
    failed += len(values) - len(finite)
    if not finite:
        return "n/a"
    text = f"{np.median(finite):.3g} ({max(finite):.3g})" if total > 1 else f"{finite[0]:.3g}"
    return text + (f", {failed} n/a" if failed else "")


if __name__ == "__main__":
    main()
