"""The command line's fuzz harness: base input files, mutations of them and of the options, and
one runner.

Every case runs ``spacecal.cli.main(argv)`` in this process on copies of the base files in a
fresh folder, and is classified by what went wrong (or ``pass``):

``traceback``
    An exception escaped ``main`` (or a traceback was printed).
``exit-code``
    An exit code other than 0, 1 or 2.
``stderr``
    Exit 1 with other than exactly one line on stderr.
``nan-output``
    NaN or Infinity in a JSON, CSV, XML, TFM or YAML file written.
``hang``
    The case ran longer than its time limit.
``changed-input``
    A file that existed before the run was changed (other than the files the command appends to).
``accepted``
    A mutation that must be refused exited 0.
``refused``
    A valid variant was refused.

Mutations are drawn through a ``pick`` object (:class:`RandomPick` for the benchmark,
:class:`DrawPick` under hypothesis), so the same generators serve both.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import gzip
import hashlib
import io
import json
import random
import re
import shutil
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spacecal.io.csv_core import JOINT_COLUMNS, MARKER_COLUMNS, TCP_COLUMNS
from spacecal.io.recordings import metadata_path, stream_paths

#: The base recording's metadata file and the raw streams' files, named as spacecal names them.
REC_META = metadata_path("rec.csv").name
RAW_ROBOT, RAW_TRACKER, RAW_META = (path.name for path in stream_paths("raw"))

CLASSES = ("encoding", "types", "numbers", "consistency", "overwrite", "arguments", "valid")
OUTCOMES = (
    "traceback",
    "exit-code",
    "stderr",
    "nan-output",
    "hang",
    "changed-input",
    "accepted",
    "refused",
    "pass",
)

#: Mutated text values of a number: not numbers, not finite, absurd, or the wrong form.
BAD_NUMBERS = ("nan", "NaN", "inf", "-inf", "Infinity", "1e308", "-1e308", "abc", "", "1e-320", "0x10", "1,2")
BAD_FLOATS_FOR_OPTIONS = ("nan", "inf", "-inf", "1e308", "-1e308", "abc", "1e-320", "-1", "0", "1,2")
BAD_INTS_FOR_OPTIONS = ("-1", "0", "nan", "abc", "1e308", "99999999999999999999", "2.5", "-5")


class Hang(BaseException):
    """Raised by the alarm when a case runs too long (a BaseException: nothing may swallow it)."""


@dataclass
class Case:
    """One run of the command line."""

    command: str
    klass: str
    label: str
    argv: list[str]
    expect: str = "any"  # "refuse" (exit 1 or 2), "usage" (exit 2), "ok" (exit 0), "any"
    appends: tuple[str, ...] = ()  # files the command may append to (check history)
    compare: str | None = None  # output file to compare with the clean run's


@dataclass
class Result:
    case: Case
    outcome: str
    code: int | None
    stdout: str
    stderr: str
    detail: str = ""
    seconds: float = 0.0


# -- picks ------------------------------------------------------------------------------------
class RandomPick:
    """Draws from a seeded :class:`random.Random` (the benchmark)."""

    def __init__(self, rng: random.Random):
        self.rng = rng

    def choice(self, options):
        options = list(options)
        return options[self.rng.randrange(len(options))]

    def integer(self, low: int, high: int) -> int:
        return self.rng.randint(low, high)


class DrawPick:
    """Draws through hypothesis's ``data.draw`` (the test suite)."""

    def __init__(self, data):
        from hypothesis import strategies as st

        self.data, self.st = data, st

    def choice(self, options):
        return self.data.draw(self.st.sampled_from(list(options)))

    def integer(self, low: int, high: int) -> int:
        return self.data.draw(self.st.integers(low, high))


# -- base files -------------------------------------------------------------------------------
#: A quick scenario for valid simulated runs: a few static stations instead of the sweeps.
QUICK_SCENARIO = {
    "preset": "paper-white",
    "name": "fuzz-quick",
    "motion": "stations",
    "stations": 8,
    "frames_per_station": 4,
    "verification_targets": 3,
}


def build_base(folder: Path) -> Path:
    """Write the base inputs of every command into ``folder`` (one simulation, one calibration)."""
    from spacecal import app
    from spacecal.geometry.transforms import transform_to_position_quaternion
    from spacecal.io.easy_handeye import easy_handeye2_samples_text
    from spacecal.io.plus_config import plus_coordinate_definition
    from spacecal.io.recordings import open_path, write_raw_recording
    from spacecal.records import RawRecording

    folder.mkdir(parents=True, exist_ok=True)
    if (folder / "done").is_file():
        return folder
    app.simulate(app.SimulateSettings(str(folder / "rec.csv"), "paper-white"))
    app.calibrate(app.CalibrateSettings(str(folder / "rec.csv"), str(folder / "cal.json"), "ml"))
    app.verify(app.VerifySettings(str(folder / "cal.json"), points=3, output=str(folder / "ver.json")))
    (folder / "scen.json").write_text(json.dumps(QUICK_SCENARIO, indent=2) + "\n")
    recording = open_path(folder / "rec.csv").recording
    seen = recording.visible
    write_raw_recording(
        RawRecording.from_paired(recording),
        folder / "raw",
    )
    poses = folder / "poses"
    poses.mkdir()
    for k, matrix in enumerate(recording.tracker_from_marker_stack[seen][::20][:30]):
        np.savetxt(poses / f"pose_{k:03d}.txt", matrix)
    # a PLUS sequence of the recording's TCP and marker poses
    lines = ["ObjectType = Image", "NDims = 3", f"DimSize = 0 0 {int(seen.sum())}"]
    for k, index in enumerate(np.flatnonzero(seen)[::5]):
        for name, matrix in (
            ("MarkerToTracker", recording.tracker_from_marker_stack[index]),
            ("TCPToBase", recording.base_from_tcp_stack[index]),
        ):
            cells = " ".join(f"{v:.9g}" for v in matrix.ravel())
            lines += [
                f"Seq_Frame{k:04d}_{name}Transform = {cells}",
                f"Seq_Frame{k:04d}_{name}TransformStatus = OK",
            ]
        lines.append(f"Seq_Frame{k:04d}_Timestamp = {recording.time_s[index]:.4f}")
    lines.append("ElementDataFile = LOCAL")
    (folder / "seq.igs.mha").write_text("\n".join(lines) + "\n")
    stylus = np.eye(4)
    stylus[:3, 3] = [0.0, 0.0, 150.0]
    (folder / "config.xml").write_text(
        "<PlusConfiguration>\n  <CoordinateDefinitions>\n"
        + plus_coordinate_definition(stylus, "StylusTip", "Stylus")
        + "\n  </CoordinateDefinitions>\n  <PhantomDefinition><Landmarks>\n"
        + '    <Landmark Name="A" Position="0 0 0" />\n    <Landmark Name="B" Position="50 0 0" />\n'
        + '    <Landmark Name="C" Position="0 60 0" />\n  </Landmarks></PhantomDefinition>\n'
        + "</PlusConfiguration>\n"
    )
    (folder / "rec.samples").write_text(
        easy_handeye2_samples_text(
            recording.base_from_tcp_stack[seen][::10],
            recording.tracker_from_marker_stack[seen][::10],
            name="fuzz",
            robot_base_frame="base_link",
            robot_effector_frame="tool0",
            tracking_base_frame="tracker",
            tracking_marker_frame="marker",
        )
    )
    (folder / "bag.bag").write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 4)
    _ = transform_to_position_quaternion
    (folder / "done").write_text("")
    return folder


# -- mutations of file contents --------------------------------------------------------------
def _text(path: Path) -> str:
    return path.read_bytes().decode("utf-8", errors="replace")


def _rows(text: str) -> list[list[str]]:
    return list(csv.reader(io.StringIO(text, newline="")))


def _csv_text(rows: list[list[str]], newline: str = "\n") -> str:
    out = io.StringIO()
    csv.writer(out, lineterminator=newline).writerows(rows)
    return out.getvalue()


def encoding_mutations(pick, data: bytes) -> tuple[str, bytes]:
    """Bytes that are not UTF-8 text: binary, gzip, UTF-16, Latin-1, NUL, truncated."""
    kind = pick.choice(["binary", "gzip", "utf16", "utf16-be", "latin1", "nul", "empty", "garbage-utf8"])
    if kind == "binary":
        rng = random.Random(pick.integer(0, 10_000))
        return kind, bytes(rng.randrange(256) for _ in range(pick.integer(1, 4000)))
    if kind == "gzip":
        return kind, gzip.compress(data)
    if kind == "utf16":
        return kind, data.decode("utf-8", errors="replace").encode("utf-16")
    if kind == "utf16-be":
        return kind, b"\xfe\xff" + data.decode("utf-8", errors="replace").encode("utf-16-be")
    if kind == "latin1":
        cut = pick.integer(0, len(data))
        return kind, data[:cut] + "é°".encode("latin-1") + data[cut:]
    if kind == "nul":
        cut = pick.integer(0, len(data))
        return kind, data[:cut] + b"\x00" + data[cut:]
    if kind == "empty":
        return kind, b""
    return kind, "\u00e9\u4e2d\u6587 not this format\n".encode() * pick.integer(1, 5)


def csv_mutation(pick, text: str, klass: str, numeric_columns: list[str]) -> tuple[str, str, str]:
    """A mutated CSV (label, text, expectation) of mutation class ``klass``."""
    rows = _rows(text)
    header = rows[0]
    body = [r for r in rows[1:] if r]
    if klass == "types":
        kind = pick.choice(
            ["drop-column", "short-row", "header-only", "rename-column", "text-row", "long-row"]
        )
        if kind == "drop-column":
            column = pick.choice(numeric_columns)
            j = header.index(column)
            return f"drop {column}", _csv_text([r[:j] + r[j + 1 :] for r in rows if r]), "refuse"
        if kind == "short-row":
            k = pick.integer(1, len(body) - 1)
            body[k] = body[k][: pick.integer(0, len(body[k]) - 1)]
            return f"short row {k + 2}", _csv_text([header] + body), "refuse"
        if kind == "header-only":
            return kind, _csv_text([header]), "refuse"
        if kind == "rename-column":
            column = pick.choice(numeric_columns)
            j = header.index(column)
            new = list(header)
            new[j] = column.upper() + "_"
            return f"rename {column}", _csv_text([new] + body), "refuse"
        if kind == "long-row":
            k = pick.integer(0, len(body) - 1)
            body[k] = body[k] + ["1.0", "2.0"]
            return f"long row {k + 2}", _csv_text([header] + body), "any"
        k = pick.integer(0, len(body) - 1)
        body[k] = ["this is not a data row"]
        return f"text row {k + 2}", _csv_text([header] + body), "refuse"
    if klass == "numbers":
        column = pick.choice(numeric_columns)
        j = header.index(column)
        candidates = [k for k, r in enumerate(body) if len(r) > j and r[j].strip()]
        k = pick.choice(candidates)
        value = pick.choice(BAD_NUMBERS)
        body[k][j] = value
        expect = "refuse"
        if value == "1e-320" and not column.startswith(("time", "tcp_q", "marker_q")):
            expect = "any"  # a tiny number where zero is fine
        if value == "" and column.startswith("marker_rms"):
            expect = "any"
        return f"{column}={value!r} at line {k + 2}", _csv_text([header] + body), expect
    raise ValueError(klass)


def recording_consistency(pick, text: str) -> tuple[str, str, str]:
    """Data that is well formed but wrong: quaternion order, conjugate, swapped columns, units,
    negative or absurd RMS, a robot that never moved, shuffled or repeated time."""
    rows = _rows(text)
    header, body = rows[0], [r for r in rows[1:] if r]
    col = {name: header.index(name) for name in header}
    kind = pick.choice(
        [
            "tcp-xyzw",
            "marker-xyzw",
            "tcp-conjugate",
            "marker-conjugate",
            "swap-tcp-marker",
            "tcp-cm",
            "tcp-inch",
            "marker-cm",
            "all-m",
            "rms-negative",
            "rms-absurd",
            "never-moved",
            "time-shuffled",
            "time-repeated",
            "marker-never-seen",
        ]
    )

    def quats(prefix: str):
        return [col[f"{prefix}_q{a}"] for a in "wxyz"]

    def scale(prefix: str, factor: float) -> None:
        for r in body:
            for a in "xyz":
                j = col[f"{prefix}_{a}_mm"]
                if r[j].strip():
                    r[j] = repr(float(r[j]) * factor)
            if prefix == "marker" and "sphere1_x_mm" in col:
                for name, j in col.items():
                    if name.startswith("sphere") and r[j].strip():
                        r[j] = repr(float(r[j]) * factor)

    if kind.endswith("xyzw"):
        w, x, y, z = quats(kind.split("-")[0])
        for r in body:
            if r[w].strip():
                r[w], r[x], r[y], r[z] = r[x], r[y], r[z], r[w]
    elif kind.endswith("conjugate"):
        _, x, y, z = quats(kind.split("-")[0])
        for r in body:
            for j in (x, y, z):
                if r[j].strip():
                    r[j] = repr(-float(r[j]))
    elif kind == "swap-tcp-marker":
        body = [r for r in body if r[col["marker_x_mm"]].strip()]
        for r in body:
            for a in ("x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz"):
                i, j = col[f"tcp_{a}"], col[f"marker_{a}"]
                r[i], r[j] = r[j], r[i]
    elif kind == "tcp-cm":
        scale("tcp", 0.1)
    elif kind == "tcp-inch":
        scale("tcp", 1 / 25.4)
    elif kind == "marker-cm":
        scale("marker", 0.1)
    elif kind == "all-m":
        scale("tcp", 0.001)
        scale("marker", 0.001)
    elif kind.startswith("rms"):
        value = "-0.2" if kind == "rms-negative" else pick.choice(["50", "1e6", "1e308"])
        for r in body:
            if r[col["marker_rms_mm"]].strip():
                r[col["marker_rms_mm"]] = value
    elif kind == "never-moved":
        first = body[0]
        for r in body:
            for name in [*(f"q{i}_rad" for i in range(1, 7)), "tcp_x_mm", "tcp_y_mm", "tcp_z_mm"]:
                r[col[name]] = first[col[name]]
            for a in "wxyz":
                r[col[f"tcp_q{a}"]] = first[col[f"tcp_q{a}"]]
    elif kind == "time-shuffled":
        times = [r[col["time_s"]] for r in body]
        random.Random(pick.integer(0, 100)).shuffle(times)
        for r, t in zip(body, times):
            r[col["time_s"]] = t
    elif kind == "time-repeated":
        k = pick.integer(1, len(body) - 1)
        body[k][col["time_s"]] = body[k - 1][col["time_s"]]
    elif kind == "marker-never-seen":
        for r in body:
            for name in header:
                if name.startswith(("marker_", "sphere")):
                    r[col[name]] = ""
    return kind, _csv_text([header] + body), "refuse"


def recording_valid_variant(pick, text: str) -> tuple[str, str]:
    """The same recording written differently: columns reordered, CRLF, BOM, whitespace, extra column."""
    rows = [r for r in _rows(text) if r]
    kind = pick.choice(["reorder", "crlf", "bom", "whitespace", "extra-column", "blank-lines", "all"])
    if kind in ("reorder", "all"):
        order = list(range(len(rows[0])))
        random.Random(pick.integer(0, 1000)).shuffle(order)
        rows = [[r[j] for j in order] for r in rows]
    if kind in ("whitespace", "all"):
        rows = [[f" {c} " if c else c for c in r] for r in rows]
    if kind in ("extra-column", "all"):
        rows = [r + (["note"] if k == 0 else [f"x{k}"]) for k, r in enumerate(rows)]
    newline = "\r\n" if kind in ("crlf", "all") else "\n"
    out = _csv_text(rows, newline)
    if kind == "blank-lines":
        out = out.replace("\n", "\n\n", 5)
    if kind in ("bom", "all"):
        out = "\ufeff" + out
    return kind, out


def json_mutation(pick, data: dict, klass: str, keys: dict[str, list]) -> tuple[str, str, str]:
    """A mutated JSON object: ``keys`` maps a key path to wrong values to put there."""
    data = json.loads(json.dumps(data))
    if klass == "types":
        kind = pick.choice(["wrong-type", "deep", "not-object", "delete", "truncated"])
        if kind == "deep":
            depth = pick.choice([100, 5000, 100_000])
            path = pick.choice(list(keys))
            _set(data, path, "REPLACE")
            text = json.dumps(data).replace('"REPLACE"', "[" * depth + "]" * depth)
            return f"deep {path} ({depth})", text, "refuse" if depth > 1000 else "any"
        if kind == "not-object":
            return kind, json.dumps(pick.choice([[1, 2], "text", 3, None])), "refuse"
        if kind == "truncated":
            text = json.dumps(data, indent=1)
            return kind, text[: pick.integer(0, len(text) - 2)], "refuse"
        path = pick.choice(list(keys))
        if kind == "delete":
            parent, last = _parent(data, path)
            if isinstance(parent, dict):
                parent.pop(last, None)
            return f"delete {path}", json.dumps(data), "any"
        value = pick.choice(keys[path])
        _set(data, path, value)
        return f"{path}={json.dumps(value)[:30]}", json.dumps(data), "refuse"
    if klass == "numbers":
        paths = [p for p, v in keys.items() if isinstance(_get(data, p), (int, float, list))]
        path = pick.choice(paths or list(keys))
        value = pick.choice(["NaN", "Infinity", "-Infinity", "1e308", "-1e400"])
        _set(data, path, "REPLACE")
        target = _get(json.loads(json.dumps(data).replace('"REPLACE"', "0")), path)
        _ = target
        return f"{path}={value}", json.dumps(data).replace('"REPLACE"', value), "refuse"
    raise ValueError(klass)


def _parent(data, path: str):
    parts = path.split(".")
    node = data
    for part in parts[:-1]:
        node = node[int(part)] if isinstance(node, list) else node.setdefault(part, {})
    last = parts[-1]
    return node, int(last) if isinstance(node, list) else last


def _get(data, path: str):
    node = data
    for part in path.split("."):
        try:
            node = node[int(part)] if isinstance(node, list) else node[part]
        except (KeyError, IndexError, TypeError, ValueError):
            return None
    return node


def _set(data, path: str, value) -> None:
    parent, last = _parent(data, path)
    parent[last] = value


# -- running a case ---------------------------------------------------------------------------
_NAN_JSON = re.compile(r"(?<![\w\"])-?(NaN|Infinity)(?![\w\"])")
_NAN_CELL = re.compile(r"^\s*[-+]?(nan|inf|infinity)\s*$", re.IGNORECASE)
_NAN_TEXT = re.compile(r"(?<![\w.])[-+]?(nan|inf|infinity)(?![\w])", re.IGNORECASE)


def _hashes(folder: Path) -> dict[Path, str]:
    return {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.rglob("*") if p.is_file()}


def nan_in_file(path: Path) -> str | None:
    """Where a written file holds NaN or Infinity (None when it holds none)."""
    suffix = "".join(path.suffixes[-2:]) if path.name.endswith(".launch.py") else path.suffix
    if suffix not in (".json", ".jsonl", ".csv", ".xml", ".tfm", ".yaml", ".calib", ".urdf", ".launch.py"):
        return None
    try:
        text = path.read_text(encoding="utf-8")
    except (UnicodeDecodeError, OSError):
        return "unreadable"
    if suffix in (".json", ".jsonl"):
        match = _NAN_JSON.search(text)
        return match.group(0) if match else None
    if suffix == ".csv":
        for line, row in enumerate(csv.reader(io.StringIO(text, newline="")), 1):
            for cell in row:
                if _NAN_CELL.match(cell):
                    return f"line {line}: {cell!r}"
        return None
    match = _NAN_TEXT.search(text)
    return match.group(0) if match else None


#: A case blocked without computing (waiting on a device or a file) counts as a hang after this
#: many times its limit in wall-clock time; one that computes, after its limit in CPU time.
WALL_LIMIT_FACTOR = 6.0


@contextlib.contextmanager
def time_limit(seconds: float):
    """Raise :class:`Hang` after ``seconds`` of the process's CPU time, or
    :data:`WALL_LIMIT_FACTOR` times that on the wall clock (main thread only; elsewhere no
    limit). CPU time, not the wall clock, is what a case that computes for ever uses up: on a
    busy machine a sound case may take three times its CPU time on the wall clock."""
    import threading

    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "SIGALRM"):
        yield
        return

    def expired(signum, frame):
        raise Hang()

    previous = {number: signal.signal(number, expired) for number in (signal.SIGALRM, signal.SIGPROF)}
    signal.setitimer(signal.ITIMER_PROF, seconds)
    signal.setitimer(signal.ITIMER_REAL, WALL_LIMIT_FACTOR * seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.setitimer(signal.ITIMER_PROF, 0)
        for number, handler in previous.items():
            signal.signal(number, handler)


def run_case(case: Case, folder: Path, limit_s: float = 20.0, clean: Path | None = None) -> Result:
    """Run ``case`` in ``folder`` (which holds its inputs) and classify what happened."""
    from spacecal.cli import main

    before = _hashes(folder)
    stdout, stderr = io.StringIO(), io.StringIO()
    code: int | None = None
    outcome, detail = "pass", ""
    started = time.monotonic()
    cwd = Path.cwd()
    try:
        with (
            contextlib.redirect_stdout(stdout),
            contextlib.redirect_stderr(stderr),
            time_limit(limit_s),
        ):
            import os

            os.chdir(folder)
            try:
                code = main(list(case.argv))
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    except Hang:
        outcome, detail = "hang", f"longer than {limit_s:.0f} s of CPU or {WALL_LIMIT_FACTOR * limit_s:.0f} s"
    except BaseException as exc:
        import traceback

        outcome, detail = "traceback", "".join(traceback.format_exception(exc))[-2000:]
    finally:
        import os

        os.chdir(cwd)
    seconds = time.monotonic() - started
    out, err = stdout.getvalue(), stderr.getvalue()
    if outcome == "pass":
        outcome, detail = _classify(case, folder, before, code, out, err, clean)
    return Result(case, outcome, code, out, err, detail, seconds)


def _classify(case, folder, before, code, out, err, clean) -> tuple[str, str]:
    if "Traceback" in out or "Traceback" in err or "internal error" in err:
        return "traceback", err[-2000:]
    if code not in (0, 1, 2):
        return "exit-code", f"exit {code}"
    lines = [line for line in err.splitlines() if line.strip()]
    if code == 1 and len(lines) != 1:
        return "stderr", f"{len(lines)} lines on stderr: {err[-600:]}"
    if code == 2 and not (lines and "error:" in lines[-1] and sum("error:" in x for x in lines) == 1):
        return "stderr", f"usage error without one error line: {err[-600:]}"
    after = _hashes(folder)
    for path, digest in before.items():
        if path.name in case.appends:
            continue
        if after.get(path) != digest:
            return "changed-input", f"{path.name} {'removed' if path not in after else 'changed'}"
    for path, digest in after.items():
        if before.get(path) != digest:
            found = nan_in_file(path)
            if found:
                return "nan-output", f"{path.name}: {found}"
    if case.expect in ("refuse", "usage") and code == 0:
        return "accepted", out[-400:]
    if case.expect == "usage" and code != 2:
        return "refused", f"expected a usage error (2), got {code}: {err.strip()[-300:]}"
    if case.expect == "ok" and code != 0:
        return "refused", err.strip()[-400:]
    if case.compare and clean is not None and code == 0:
        problem = compare_calibrations(folder / case.compare, clean)
        if problem:
            return "refused", problem
    return "pass", ""


def compare_calibrations(path: Path, clean: Path) -> str | None:
    """None when the two calibration files hold the same transforms (to 1e-9 mm)."""
    a, b = json.loads(path.read_text()), json.loads(clean.read_text())
    for key in ("tracker_from_base", "tcp_from_marker"):
        if np.max(np.abs(np.array(a[key]) - np.array(b[key]))) > 1e-9:
            return f"{key} differs from the clean recording's"
    return None


# -- the commands -----------------------------------------------------------------------------
Builder = Callable[[object, Path, str], Case]


def _write(folder: Path, name: str, content: str | bytes) -> None:
    path = folder / name
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_bytes(content.encode("utf-8"))


#: The numeric columns of a recording, in file order (time, joints, TCP, marker).
REC_NUMERIC = ["time_s", *JOINT_COLUMNS, *TCP_COLUMNS, *MARKER_COLUMNS]
CAL_KEYS: dict[str, list] = {
    "tracker_from_base": ["text", [[1, 2], [3, 4]], {"a": 1}, [[0] * 4] * 4, None],
    "tcp_from_marker": ["text", [1, 2, 3], [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 2]]],
    "provenance": ["text", [1, 2], 3, True],
    "provenance.recording": [3, ["a"], {"x": 1}],
    "provenance.scenario": ["paper-white", [1], 3, {"white_noise_rms_mm": "lots"}],
    "provenance.simulated": ["yes", 1],
    "diagnostics": [[1, 2], "text", 3],
    "sample_counts": [[1], "text"],
    "predicted_tre_mm": ["text", [1], {"site": "small"}, {"site": [1]}, {"cube_rms": True}],
    "robot_model": ["UR10", [1], {"name": "UR10", "a_mm": "x"}, {"name": 3}],
    "units": ["mm", {"length": "m"}, {"length": "cm"}, {"length": "inch"}, [1]],
    "method": [3, None, ["ml"]],
    "schema_version": ["2", 99, True, 2.5],
    "covariance": ["text", [1]],
    "tracker_from_base.0.3": ["x", None, [1]],
}


def _mutate_file(pick, folder: Path, name: str, klass: str) -> tuple[str, str]:
    """Mutate ``folder/name`` by class; returns (label, expectation)."""
    path = folder / name
    if klass == "encoding":
        kind, data = encoding_mutations(pick, path.read_bytes())
        path.write_bytes(data)
        # a PLUS sequence is Latin-1 (binary pixel data may follow the header); the bag is binary
        harmless = (name.endswith(".mha") and kind == "latin1") or name.endswith(".bag")
        return f"{name}: {kind}", "any" if harmless else "refuse"
    if name.endswith(".csv"):
        numeric = REC_NUMERIC if not name.endswith("tracker.csv") else ["time_s", *REC_NUMERIC[14:]]
        if name.endswith("robot.csv"):
            numeric = REC_NUMERIC[:14]
        if klass == "consistency" and name == "rec.csv":
            label, text, expect = recording_consistency(pick, _text(path))
        else:
            label, text, expect = csv_mutation(
                pick, _text(path), klass if klass != "consistency" else "numbers", numeric
            )
        _write(folder, name, text)
        return f"{name}: {label}", expect
    if name.endswith(".json"):
        data = json.loads(_text(path))
        keys = JSON_KEYS.get(name) or JSON_KEYS[REC_META]
        label, text, expect = json_mutation(
            pick, data, klass if klass in ("types", "numbers") else "types", keys
        )
        _write(folder, name, text)
        return f"{name}: {label}", expect
    # other text files: insert junk or numbers where numbers belong
    text = _text(path)
    # numbers standing alone (not the digits of a name such as tool0 or Seq_Frame0001)
    numbers = list(re.finditer(r"(?<=[\s=:\[,\"])-?\d+\.?\d*(e[-+]?\d+)?(?=[\s,\]\"]|$)", text))
    if name.endswith(".mha"):  # the frames' numbers, not the image header's
        numbers = [
            m
            for m in numbers
            if text.rfind("\n", 0, m.start()) + 1 == text.find("Seq_", text.rfind("\n", 0, m.start()) + 1)
        ]
    if numbers and klass == "numbers":
        match = pick.choice(numbers[:400])
        value = pick.choice(["nan", "inf", "-inf", "1e308", "abc"])
        _write(folder, name, text[: match.start()] + value + text[match.end() :])
        return f"{name}: number -> {value}", "refuse"
    cut = pick.integer(0, len(text))
    _write(
        folder, name, text[:cut] + pick.choice(["<<<", "]]]", "\n\n:::\n", "{", "x = ", "- [\n"]) + text[cut:]
    )
    return f"{name}: junk at {cut}", "any"


JSON_KEYS: dict[str, dict[str, list]] = {
    "cal.json": CAL_KEYS,
    REC_META: {
        "robot": ["UR10", [1], 3],
        "robot.model": [3, ["UR10"], "UR99"],
        "robot.flange_from_tcp": ["x", [[1, 2]], [[2, 0, 0, 0]] * 4],
        "scenario": ["paper-white", [1], {"seed": "one"}],
        "marker": ["x", [1], {"spheres_in_marker_mm": "x"}],
        "units": [{"length": "m"}, "mm", [1]],
        "source": [3, ["x"], {"a": 1}],
        "simulated": ["yes", 3],
    },
    "ver.json": {
        "points": [[], "text", [{"a": 1}], [[1, "x"]], None],
        "position_error_mm": ["text", [], ["x"], [-1.0, 2.0]],
        "posture_error_deg": ["text", [], ["x"]],
        "schema_version": ["1", 99],
    },
    "scen.json": {
        "white_noise_rms_mm": [-1, "lots", 1e308, None, [1]],
        "tracker_rate_hz": [0, -20, 1e9, "fast"],
        "dropout_probability": [-0.1, 1.5, 2, "x"],
        "outlier_fraction": [-0.5, 1.01, "x"],
        "tracker_distance_mm": [-950, 0, 1e308, "far"],
        "linear_speed_mm_s": [0, -100, 1e-300, 1e308],
        "angular_speed_deg_s": [0, -45, 1e-300],
        "stations": [-5, 0, 1e9, 2.5, "many"],
        "frames_per_station": [-1, 0, 1e9, 2.5],
        "verification_targets": [-1, 0, 1e9],
        "tool_offset_mm": ["0,0,200", [0, 0], [0, 0, "x"], ["nan", 0, 0]],
        "home_joints_deg": ["x", [0] * 5, [1e308] * 6],
        "seed": [-1, "one", 1.5, 2**70],
        "motion": ["circles", 3, None],
        "record_spheres": ["yes", 3, [1]],
        "repeatability_mm": [-0.1, 1e308],
        "rotation_sample_period_s": [0, -0.1, 1e-300],
        "preset": ["nope", 3],
        "robot_model": ["UR99", 10],
        "max_view_angle_deg": [-10, 1000],
        "rotation_deg": [-90, 0, 1e308],
        "translation_mm": [-500, 0, 1e308],
    },
}


def _files_case(command: str, files: list[str], argv: list[str], clean_ok: bool = True) -> Builder:
    """A builder that mutates one of ``files`` (or none, for a valid run) of a command."""

    def build(pick, folder: Path, klass: str) -> Case:
        if klass == "valid":
            return Case(command, klass, "clean", argv, "ok" if clean_ok else "any")
        name = pick.choice(files)
        label, expect = _mutate_file(pick, folder, name, klass)
        return Case(command, klass, label, argv, expect)

    return build


def _option_values(pick, kind: str) -> tuple[str, str]:
    if kind == "float":
        return pick.choice(BAD_FLOATS_FOR_OPTIONS), "refuse"
    return pick.choice(BAD_INTS_FOR_OPTIONS), "refuse"


OUTPUT_NAMES = {
    "simulate": "-o",
    "calibrate": "-o",
    "pivot": "-o",
    "verify": "-o",
    "acquire": "-o",
    "register-landmarks": "-o",
    "import-plus": "-o",
    "import-easy-handeye": "-o",
    "phantom": "-o",
    "report": "-o",
    "plan": "-o",
    "import-bag": "-o",
}

#: Each command: base argv, the input files it reads, options to fuzz (name -> kind),
#: the output option and whether a clean run is cheap enough for the fast profile.
COMMANDS: dict[str, dict] = {
    "calibrate": {
        "argv": ["calibrate", "rec.csv", "--method", "ml", "-o", "out.json"],
        "files": ["rec.csv", REC_META],
        "options": {"--sigma-mm": "float", "--target": "point", "--method": "method"},
        "inputs": ["rec.csv", REC_META, RAW_ROBOT, RAW_META],
    },
    "calibrate-raw": {
        "argv": [
            "calibrate",
            RAW_ROBOT,
            "--tracker-stream",
            RAW_TRACKER,
            "--method",
            "paper",
            "-o",
            "out.json",
        ],
        "files": [RAW_ROBOT, RAW_TRACKER, RAW_META],
        "options": {"--time-offset-ms": "offset"},
        "inputs": [RAW_ROBOT, RAW_TRACKER, RAW_META],
    },
    "bound": {
        "argv": ["bound", "rec.csv", "--calibration", "cal.json", "--sigma-mm", "0.1"],
        "files": ["rec.csv", "cal.json"],
        "options": {"--sigma-mm": "float", "--target": "point"},
        "inputs": [],
    },
    "pivot": {
        "argv": ["pivot", "poses", "-o", "out.json"],
        "files": ["poses/pose_003.txt"],
        "options": {"--method": "method"},
        "inputs": ["poses/pose_000.txt"],
    },
    "pivot-csv": {
        "argv": ["pivot", "rec.csv", "--method", "sphere", "-o", "out.json"],
        "files": ["rec.csv"],
        "options": {},
        "inputs": ["rec.csv", REC_META],
    },
    "verify": {
        "argv": ["verify", "cal.json", "--points", "3", "-o", "out.json"],
        "files": ["cal.json"],
        "options": {"--points": "int"},
        "inputs": ["cal.json", "rec.csv", REC_META],
    },
    "check": {
        "argv": ["check", "cal.json", "--recording", "rec.csv"],
        "files": ["cal.json", "rec.csv", "cal.checks.jsonl"],
        "options": {"--threshold-mm": "float", "--threshold-deg": "float", "--poses": "int"},
        "inputs": [],
        "appends": ("cal.checks.jsonl",),
    },
    "report": {
        "argv": [
            "report",
            "cal.json",
            "--recording",
            "rec.csv",
            "--verification",
            "ver.json",
            "-o",
            "out.html",
        ],
        "files": ["cal.json", "rec.csv", "ver.json", "cal.checks.jsonl"],
        "options": {},
        "inputs": ["cal.json", "rec.csv", "ver.json", REC_META],
        "slow": True,
    },
    "export": {
        "argv": ["export", "cal.json", "--slicer", "out.tfm", "--plus", "out.xml", "--urdf", "out.urdf"],
        "files": ["cal.json"],
        "options": {},
        "inputs": ["cal.json"],
        "output_option": "--slicer",
    },
    "import-plus": {
        "argv": ["import-plus", "seq.igs.mha", "-o", "out.csv"],
        "files": ["seq.igs.mha"],
        "options": {},
        "inputs": ["seq.igs.mha", "rec.csv"],
    },
    "import-easy-handeye": {
        "argv": ["import-easy-handeye", "rec.samples", "-o", "out.csv"],
        "files": ["rec.samples"],
        "options": {},
        "inputs": ["rec.samples", "rec.csv"],
    },
    "register-landmarks": {
        "argv": [
            "register-landmarks",
            "seq.igs.mha",
            "--config",
            "config.xml",
            "--stylus",
            "TCP",
            "--reference",
            "Marker",
            "-o",
            "out.json",
        ],
        "files": ["seq.igs.mha", "config.xml"],
        "options": {},
        "inputs": ["seq.igs.mha", "config.xml"],
        "clean_any": True,
    },
    "import-bag": {
        "argv": ["import-bag", "bag.bag", "-o", "out"],
        "files": ["bag.bag"],
        "options": {},
        "inputs": ["bag.bag"],
        "clean_any": True,
    },
    "simulate": {
        "argv": ["simulate", "--scenario", "scen.json", "-o", "out.csv"],
        "files": ["scen.json"],
        "options": {"--seed": "int", "--clock-offset-ms": "float"},
        "inputs": ["scen.json", "rec.csv", REC_META],
        "slow": True,
    },
    "acquire": {
        "argv": ["acquire", "--scenario", "scen.json", "-o", "out.csv"],
        "files": ["scen.json"],
        "options": {
            "--speed-mm-s": "float",
            "--accel-mm-s2": "float",
            "--angular-speed-deg-s": "float",
            "--tracker-rate-hz": "float",
            "--rotation-deg": "float",
            "--translation-mm": "float",
            "--workspace-box": "box",
            "--tool-offset-mm": "point",
        },
        "inputs": ["scen.json", "rec.csv", REC_META],
        "slow": True,
    },
    "phantom": {
        "argv": ["phantom", "--scenario", "scen.json", "--cases", "1", "-o", "out.json"],
        "files": ["scen.json"],
        "options": {"--cases": "int"},
        "inputs": ["scen.json", "rec.csv"],
        "slow": True,
        "clean_any": True,
    },
    "plan": {
        "argv": ["plan", "--scenario", "scen.json", "--budget", "5s", "-o", "out.json"],
        "files": ["scen.json"],
        "options": {"--budget": "budget", "--frames-per-station": "int"},
        "inputs": ["scen.json", "rec.csv"],
        "slow": True,
        "clean_any": True,
    },
    "demo": {
        "argv": ["demo", "--scenario", "scen.json", "--out", "demo"],
        "files": ["scen.json"],
        "options": {},
        "inputs": [],
        "slow": True,
        "clean_any": True,
    },
    "scenario": {
        "argv": ["scenario", "paper-white"],
        "files": [],
        "options": {"preset": "word"},
        "inputs": [],
    },
}


def build_case(pick, folder: Path, command: str, klass: str, fast: bool) -> Case:
    """Draw one case of ``command`` and mutation class ``klass``, preparing ``folder``."""
    spec = COMMANDS[command]
    argv = list(spec["argv"])
    appends = tuple(spec.get("appends", ()))
    name = argv[0]
    if klass == "valid":
        if name == "calibrate" and command == "calibrate":
            label, text = recording_valid_variant(pick, _text(folder / "rec.csv"))
            _write(folder, "rec.csv", text)
            return Case(command, klass, f"rec.csv: {label}", argv, "ok", appends, compare="out.json")
        return Case(command, klass, "clean", argv, "any" if spec.get("clean_any") else "ok", appends)
    if klass == "arguments":
        return _argument_case(pick, command, spec, argv, appends)
    if klass == "overwrite":
        return _overwrite_case(pick, folder, command, spec, argv, appends)
    if klass == "numbers" and spec["options"] and pick.choice([True, False]):
        return _option_case(pick, command, spec, argv, appends)
    if not spec["files"]:
        return _option_case(pick, command, spec, argv, appends)
    file_name = pick.choice(spec["files"])
    if not (folder / file_name).exists():
        (folder / file_name).write_text('{"schema": "spacecal.check"}\nnot json\n[1]\n{"passed": "yes"}\n')
        return Case(command, klass, f"{file_name}: corrupt lines", argv, "any", appends)
    file_klass = klass
    if klass == "consistency" and file_name != "rec.csv":
        file_klass = "types"
    label, expect = _mutate_file(pick, folder, file_name, file_klass)
    if file_name == "cal.checks.jsonl" or (
        file_name == REC_META and expect == "refuse" and klass != "encoding"
    ):
        expect = "any"  # advisory history; metadata the estimators do not need
    if command in ("pivot", "pivot-csv") and klass != "encoding":
        expect = "any"  # pivot uses the marker poses only
    if command == "check" and file_name == "rec.csv" and klass == "consistency":
        expect = "any"  # a recording checked against a calibration: FAIL is the answer
    if "provenance.scenario" in label and command != "verify":
        expect = "any"  # only verify (and check without --recording) simulates the calibration's world
    if command == "register-landmarks":
        expect = "refuse" if klass == "encoding" else "any"
    return Case(command, klass, label, argv, expect, appends)


def _option_case(pick, command, spec, argv, appends) -> Case:
    if not spec["options"]:
        return Case(command, "numbers", "clean", argv, "any", appends)
    option, kind = pick.choice(sorted(spec["options"].items()))
    if kind == "word":
        value = pick.choice(["nope", "", "../../etc/passwd", "paper-white\x00", "-1"])
        return Case(command, "numbers", f"preset {value!r}", [argv[0], value], "any", appends)
    if kind == "method":
        value = pick.choice(["nope", "", "ML", "ml ", "\u00e9"])
        return Case(
            command, "numbers", f"{option} {value!r}", _with_option(argv, option, value), "refuse", appends
        )
    if kind == "point":
        value = pick.choice(["nan,0,0", "inf,1,2", "1,2", "1,2,3,4", "a,b,c", "1e308,0,0", "", "1;2;3"])
        expect = "refuse"
    elif kind == "box":
        value = pick.choice(["1,2,3", "nan,1,0,1,0,1", "10,0,0,1,0,1", "a,b,c,d,e,f", "inf,-inf,0,1,0,1"])
        expect = "refuse"
    elif kind == "budget":
        value = pick.choice(["1min", "nan", "inf", "-5s", "0", "1e308s", "abc", "5 s s", "1e-320"])
        expect = "usage" if value in ("1min", "nan", "inf", "abc", "5 s s") else "refuse"
    elif kind == "offset":  # a number or 'estimate', checked by the command: exit 1
        value = pick.choice(["nan", "inf", "-inf", "1e308", "abc", "1e-320", "1,2", "estimate "])
        expect = "refuse" if value not in ("1e-320",) else "any"
        return Case(
            command, "numbers", f"{option} {value!r}", _with_option(argv, option, value), expect, appends
        )
    elif kind == "float":
        value, expect = _option_values(pick, "float")
        if option == "--time-offset-ms" and value in ("-1", "0"):
            expect = "any"
        if option == "--clock-offset-ms" and value in ("-1", "0"):
            expect = "any"
    else:
        value, expect = _option_values(pick, "int")
        if option == "--seed" and value == "0":
            expect = "any"
        if option == "--poses":
            expect = "usage"  # choices=[2, 3]
    if expect == "refuse" and _is_malformed(value, kind):
        expect = "usage"
    return Case(command, "numbers", f"{option} {value!r}", _with_option(argv, option, value), expect, appends)


def _is_malformed(value: str, kind: str) -> bool:
    """Text that argparse cannot turn into the option's type: a usage error (exit 2)."""
    if kind not in ("int", "float"):
        return False
    try:
        float(value) if kind == "float" else int(value)
    except ValueError:
        return True
    return False


def _with_option(argv: list[str], option: str, value: str) -> list[str]:
    argv = list(argv)
    if option in argv:
        argv[argv.index(option) + 1] = value
        return argv
    return argv + [option, value]


def _argument_case(pick, command, spec, argv, appends) -> Case:
    kind = pick.choice(
        ["negative-target", "missing-value", "unknown-option", "missing-input", "folder-input", "duplicate"]
    )
    if kind == "negative-target" and ("--target" in spec["options"] or "--workspace-box" in spec["options"]):
        if "--target" in spec["options"]:
            value = pick.choice(["-573,-168,327", "-1e2,-0.5,-3", "-0,-0,-0"])
            style = pick.choice(["space", "equals"])
            extra = ["--target", value] if style == "space" else [f"--target={value}"]
            return Case(command, "arguments", f"--target {value} ({style})", argv + extra, "ok", appends)
        value = pick.choice(["-2000,2000,-2000,2000,-2000,2000", "-1e4,1e4,-1e4,1e4,-1e4,1e4"])
        return Case(
            command,
            "arguments",
            f"--workspace-box {value}",
            argv + ["--workspace-box", value],
            "any",
            appends,
        )
    if kind == "missing-value":
        option = pick.choice(sorted(spec["options"]) or ["-o"])
        if option == "preset":
            option = "-o"
        return Case(command, "arguments", f"{option} without a value", argv + [option], "usage", appends)
    if kind == "unknown-option":
        return Case(command, "arguments", "unknown option", argv + ["--frobnicate", "3"], "usage", appends)
    if kind == "missing-input":
        if len(argv) > 1 and not argv[1].startswith("-"):
            return Case(
                command,
                "arguments",
                "missing input file",
                [argv[0], "missing.csv"] + argv[2:],
                "refuse",
                appends,
            )
        return Case(command, "arguments", "unknown option", argv + ["--frobnicate"], "usage", appends)
    if kind == "folder-input" and len(argv) > 1 and not argv[1].startswith("-") and argv[0] != "pivot":
        return Case(
            command, "arguments", "a folder as input", [argv[0], "poses"] + argv[2:], "refuse", appends
        )
    return Case(command, "arguments", "no arguments", [argv[0], "--output"], "usage", appends)


def _overwrite_case(pick, folder, command, spec, argv, appends) -> Case:
    option = spec.get("output_option", "-o")
    inputs = spec["inputs"]
    if not inputs or option not in argv and option not in ("--slicer",):
        return Case(command, "overwrite", "clean", argv, "any", appends)
    target = pick.choice(inputs)
    if command == "demo":
        return Case(command, "overwrite", "clean", argv, "any", appends)
    argv = _with_option(argv, option, target)
    if command == "simulate" and pick.choice([True, False]):
        argv = argv + ["--raw"]
        argv = _with_option(argv, "-o", "raw")
        return Case(command, "overwrite", "-o raw (an existing raw recording)", argv, "refuse", appends)
    return Case(command, "overwrite", f"{option} {target}", argv, "refuse", appends)


def prepare(base: Path, folder: Path) -> None:
    """Copy the base inputs into a fresh ``folder``."""
    if folder.exists():
        shutil.rmtree(folder)
    shutil.copytree(base, folder, ignore=shutil.ignore_patterns("done"))


PROFILES = {
    # cases per (command, class) for each profile; slow commands get fewer valid runs
    "fast": {"cases": 4, "slow_cases": 2, "valid_slow": 0},
    "thorough": {"cases": 20, "slow_cases": 14, "valid_slow": 2},
}


def plan_cases(profile: str) -> list[tuple[str, str, int]]:
    """(command, class, count) for a profile."""
    settings = PROFILES[profile]
    out = []
    for command, spec in COMMANDS.items():
        for klass in CLASSES:
            count = settings["slow_cases"] if spec.get("slow") else settings["cases"]
            if klass == "valid":
                count = (
                    settings["valid_slow"]
                    if spec.get("slow")
                    else min(count, 6 if command == "calibrate" else 1)
                )
                if command == "calibrate" and profile == "fast":
                    count = 3
            out.append((command, klass, count))
    return out


def fields_of(obj) -> dict:
    return dataclasses.asdict(obj)


def main_summary(results: list[Result]) -> str:
    """A table of outcomes per command and per class."""
    lines = []
    header = f"{'':24s}" + "".join(f"{o:>14s}" for o in OUTCOMES) + f"{'total':>8s}"
    for title, key in (("command", lambda r: r.case.command), ("class", lambda r: r.case.klass)):
        lines.append(f"per {title}:")
        lines.append(header)
        for name in sorted({key(r) for r in results}):
            subset = [r for r in results if key(r) == name]
            lines.append(
                f"{name:24s}"
                + "".join(f"{sum(r.outcome == o for r in subset):14d}" for o in OUTCOMES)
                + f"{len(subset):8d}"
            )
        lines.append("")
    lines.append(
        f"{'all':24s}"
        + "".join(f"{sum(r.outcome == o for r in results):14d}" for o in OUTCOMES)
        + f"{len(results):8d}"
    )
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover
    sys.exit("run benchmarks/fuzz.py")
