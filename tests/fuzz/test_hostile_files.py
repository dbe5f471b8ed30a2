"""Hostile input files through the command line: damaged ROS bags (``import-bag``), easy_handeye2
samples files (``import-easy-handeye``) and TUM trajectories (``import-poses``).

Every case is seeded. Each must exit 0 or 1, with exactly one line on stderr for 1, no
traceback and no "internal error", finish within its time limit, leave its inputs unchanged,
and write no NaN or Infinity (:func:`spacecal.testing.fuzz.run_case` classifies it). Cases whose right answer
is known (a NaN pose among good ones is skipped and named; a stream that is mostly garbage is
refused, naming the message) also check that answer.
"""

from __future__ import annotations

import copy
import random
import shutil
from pathlib import Path

import numpy as np
import pytest

from spacecal.testing.fuzz import Case, run_case

from .bags import write_small_bag

pytest.importorskip("rosbags")
yaml = pytest.importorskip("yaml")

#: Generous: a case takes well under a second.
LIMIT_S = 20.0
#: Mutated bags per storage format (byte flips and truncations of a valid bag).
BAG_CASES = 52
SEED = 20261126


def _run(folder: Path, argv: list[str], label: str):
    result = run_case(Case(argv[0], "hostile", label, argv, "any"), folder, LIMIT_S)
    problem = None
    if result.outcome != "pass" or result.code not in (0, 1):
        problem = f"{label}: {result.outcome} (exit {result.code}): {result.detail or result.stderr}"[:1200]
    return result, problem


def _assert_none(problems: list[str | None]) -> None:
    found = [p for p in problems if p]
    assert not found, f"{len(found)} bad cases:\n" + "\n".join(found[:20])


# -- ROS bags ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def clean_bags(tmp_path_factory):
    root = tmp_path_factory.mktemp("bags")
    return {storage: write_small_bag(root / storage, storage) for storage in ("sqlite3", "mcap")}


def _storage(folder: Path) -> Path:
    (found,) = [p for p in folder.iterdir() if p.suffix in (".db3", ".mcap")]
    return found


def _import(folder: Path, bag: str = "bag", extra: tuple[str, ...] = ()):
    return ["import-bag", bag, "-o", "out", *extra]


def test_the_clean_small_bags_import(clean_bags, tmp_path):
    for storage, bag in clean_bags.items():
        folder = tmp_path / storage
        shutil.copytree(bag, folder / "bag")
        result, problem = _run(folder, _import(folder), f"clean {storage}")
        assert problem is None and result.code == 0, problem or result.stderr
        assert "note:" not in result.stdout


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_byte_flipped_and_truncated_bags(clean_bags, tmp_path, storage):
    rng = random.Random(f"{SEED}-{storage}")
    data = _storage(clean_bags[storage]).read_bytes()
    problems = []
    for k in range(BAG_CASES):
        folder = tmp_path / f"case{k}"
        shutil.copytree(clean_bags[storage], folder / "bag")
        target = _storage(folder / "bag")
        if k % 3 == 2:
            cut = rng.randrange(len(data))
            target.write_bytes(data[:cut])
            label = f"{storage} truncated to {cut} bytes"
        else:
            damaged = bytearray(data)
            spots = [rng.randrange(len(data)) for _ in range(rng.randint(1, 8))]
            for spot in spots:
                damaged[spot] ^= 1 << rng.randrange(8)
            target.write_bytes(bytes(damaged))
            label = f"{storage} bits flipped at {spots}"
        result, problem = _run(folder, _import(folder), label)
        if problem is None and result.code == 0:
            problem = _implausible_output(folder, label)
        problems.append(problem)
        shutil.rmtree(folder)
    _assert_none(problems)


def _implausible_output(folder: Path, label: str) -> str | None:
    """A stream written from a damaged bag must hold only finite, plausible poses (mm)."""
    from spacecal.io.raw_streams import read_raw_recording

    raw = read_raw_recording(folder / "out.robot.csv", folder / "out.tracker.csv")
    for name, stack in (("robot", raw.base_from_tcp_stack), ("tracker", raw.tracker_from_marker_stack)):
        seen = stack[np.isfinite(stack[:, 0, 3])]
        if len(seen) and np.max(np.abs(seen[:, :3, 3])) > 1e5:
            return (
                f"{label}: the {name} stream holds a translation of {np.max(np.abs(seen[:, :3, 3])):.3g} mm"
            )
    if not (np.all(np.diff(raw.robot_time_s) > 0) and np.all(np.diff(raw.tracker_time_s) > 0)):
        return f"{label}: times not increasing"
    return None


def _metadata_nodes(data, path=()):
    yield path
    if isinstance(data, dict):
        for key, value in data.items():
            yield from _metadata_nodes(value, (*path, key))
    elif isinstance(data, list):
        for index, value in enumerate(data):
            yield from _metadata_nodes(value, (*path, index))


WRONG_VALUES = ["x", 10**30, -5, None, [], {}, 1e300, "9" * 40, [1, 2], {"a": 1}, True, 0, 2**63]
METADATA_TEXTS = [
    "",
    "[1, 2",
    "- a\n- b\n",
    "rosbag2_bagfile_information: 3\n",
    "\x00\x01",
    "a: &x [1]\nb: *x\n",
    "rosbag2_bagfile_information:\n  version: 9\n",
    "[" * 5000 + "]" * 5000,
]


def test_metadata_yaml_that_lies(clean_bags, tmp_path):
    rng = random.Random(SEED + 1)
    problems = []
    for storage, bag in clean_bags.items():
        metadata = yaml.safe_load((bag / "metadata.yaml").read_text())
        nodes = [p for p in _metadata_nodes(metadata) if p]
        for k in range(16):
            folder = tmp_path / f"{storage}{k}"
            shutil.copytree(bag, folder / "bag")
            target = folder / "bag" / "metadata.yaml"
            if k < len(METADATA_TEXTS):
                target.write_text(METADATA_TEXTS[k])
                label = f"metadata.yaml is {METADATA_TEXTS[k][:30]!r}"
            elif k == len(METADATA_TEXTS):
                target.unlink()
                label = "no metadata.yaml"
            else:
                lie = copy.deepcopy(metadata)
                node = rng.choice(nodes)
                parent = lie
                for key in node[:-1]:
                    parent = parent[key]
                if rng.random() < 0.3:
                    del parent[node[-1]]
                    label = f"metadata.yaml without {node}"
                else:
                    value = rng.choice(WRONG_VALUES)
                    parent[node[-1]] = value
                    label = f"metadata.yaml with {node} = {value!r}"[:200]
                target.write_text(yaml.safe_dump(lie))
            argv = ["import-bag", "bag", "--list"] if k % 2 else _import(folder)
            problems.append(_run(folder, argv, label)[1])
            shutil.rmtree(folder)
    _assert_none(problems)


def _tweak_one(kind: str, index: int, change):
    def tweak(stream: str, k: int, values: dict) -> None:
        if stream == kind and k == index:
            change(values)

    return tweak


def _set(key, value):
    return lambda values: values.__setitem__(key, value)


#: One message of a 30-message stream made bad: skipped, and named in a note.
ONE_BAD_MESSAGE = {
    "robot NaN": ("robot", _set("xyz", [np.nan, 0.1, 0.2]), "not a finite number"),
    "robot inf": ("robot", _set("xyz", [np.inf, 0.1, 0.2]), "not a finite number"),
    "robot 1e300": ("robot", _set("xyz", [1e300, 0.1, 0.2]), "translation of 1e+300 m"),
    "robot zero quaternion": ("robot", _set("q", [0.0, 0.0, 0.0, 0.0]), "norm 0"),
    "marker 1e300": ("marker", _set("xyz", [0.1, 1e300, 0.2]), "translation of 1e+300 m"),
    "marker inf": ("marker", _set("xyz", [0.1, -np.inf, 0.2]), "not a finite number"),
    "marker half quaternion": ("marker", _set("q", [0.0, 0.0, 0.0, 0.5]), "norm 0.5"),
    "marker NaN quaternion": ("marker", _set("q", [np.nan, 0.0, 0.0, 1.0]), "not a finite number"),
    "marker stamp backwards": ("marker", _set("stamp", 1_699_999_000 * 10**9), "out of time order"),
    "robot stamp far ahead": (
        "robot",
        _set("stamp", 1_700_000_000 * 10**9 + 12 * 10**8),
        "out of time order",
    ),
    "marker stamp repeated": (
        "marker",
        _set("stamp", 1_700_000_000 * 10**9 + 9 * 50_000_000 + 7_000_000),
        "repeating the time stamp",
    ),
}


@pytest.mark.parametrize("name", sorted(ONE_BAD_MESSAGE))
def test_one_bad_message_is_skipped_and_named(tmp_path, name):
    stream, change, words = ONE_BAD_MESSAGE[name]
    write_small_bag(tmp_path / "bag", tweak=_tweak_one(stream, 10, change))
    result, problem = _run(tmp_path, _import(tmp_path), name)
    assert problem is None and result.code == 0, problem or result.stderr
    notes = [line for line in result.stdout.splitlines() if line.startswith("note:")]
    topic = "/tf" if stream == "robot" else "/tracker/marker"
    assert len(notes) == 1 and words in notes[0] and f"message 10 on {topic}" in notes[0], notes
    assert "skipped 1 of 30 messages" in notes[0]


def test_a_marker_not_seen_is_kept_as_not_seen(tmp_path):
    write_small_bag(tmp_path / "bag", tweak=_tweak_one("marker", 4, _set("xyz", [np.nan] * 3)))
    result, problem = _run(tmp_path, _import(tmp_path), "marker not seen")
    assert problem is None and result.code == 0 and "note:" not in result.stdout
    assert "30 tracker poses" in result.stdout


MOSTLY_GARBAGE = {
    "robot NaN": ("robot", _set("xyz", [np.nan, 0.0, 0.0]), "message 0 on /tf, has a value that"),
    "marker 1e300": ("marker", _set("xyz", [1e300, 0.0, 0.0]), "message 0 on /tracker/marker, has a trans"),
    "marker unit-less": ("marker", _set("q", [0.1, 0.1, 0.1, 0.1]), "not a unit quaternion"),
}


@pytest.mark.parametrize("name", sorted(MOSTLY_GARBAGE))
def test_a_stream_that_is_mostly_garbage_is_refused(tmp_path, name):
    stream, change, words = MOSTLY_GARBAGE[name]

    def tweak(kind: str, k: int, values: dict) -> None:
        if kind == stream and k % 3 == 0:
            change(values)

    write_small_bag(tmp_path / "bag", tweak=tweak)
    result, problem = _run(tmp_path, _import(tmp_path), name)
    assert problem is None and result.code == 1, problem or result.stdout
    assert "10 of 30 messages are unusable" in result.stderr and words in result.stderr, result.stderr
    assert not (tmp_path / "out.robot.csv").exists()


def test_a_clock_that_jumps_back_is_refused(tmp_path):
    def tweak(kind: str, k: int, values: dict) -> None:
        if kind == "marker" and k >= 20:
            values["stamp"] -= 15 * 50_000_000  # the second part re-runs the first's times

    write_small_bag(tmp_path / "bag", tweak=tweak)
    result, problem = _run(tmp_path, _import(tmp_path), "clock reset")
    assert problem is None and result.code == 1
    assert "/tracker/marker" in result.stderr and "earlier than the stamps before it" in result.stderr


HOSTILE_FRAMES = ["base\nflange", "tool'\"", "tracker\x1b[2J", "\x00", "a" * 5000, "\u202eevil"]


@pytest.mark.parametrize("frame", HOSTILE_FRAMES, ids=range(len(HOSTILE_FRAMES)))
def test_hostile_frame_names(tmp_path, frame):
    def tweak(kind: str, k: int, values: dict) -> None:
        if kind == "marker":
            values["parent"] = frame
        elif k == 3:
            values["child"] = frame  # one tf message names a new edge

    write_small_bag(tmp_path / "bag", tweak=tweak)
    for argv in (["import-bag", "bag", "--list"], _import(tmp_path), _import(tmp_path, extra=("--force",))):
        result, problem = _run(tmp_path, argv, f"frame {frame[:20]!r}")
        assert problem is None, problem
        assert "\x1b" not in result.stdout + result.stderr and "\u202e" not in result.stdout + result.stderr


def test_a_topic_too_long_is_refused_as_it_is_read(tmp_path, monkeypatch):
    from spacecal.io import ros_bag

    monkeypatch.setattr(ros_bag, "MAX_TOPIC_MESSAGES", 20)
    write_small_bag(tmp_path / "bag")
    result, problem = _run(tmp_path, _import(tmp_path), "long topic")
    assert problem is None and result.code == 1 and "more than 20 messages" in result.stderr


def test_an_undecodable_message_is_named(tmp_path):
    import sqlite3

    write_small_bag(tmp_path / "bag")
    (database,) = (tmp_path / "bag").glob("*.db3")
    with sqlite3.connect(database) as connection:
        (topic_id,) = connection.execute("SELECT id FROM topics WHERE name = '/tracker/marker'").fetchone()
        rows = connection.execute(
            "SELECT id FROM messages WHERE topic_id = ? ORDER BY timestamp", (topic_id,)
        ).fetchall()
        connection.execute("UPDATE messages SET data = ? WHERE id = ?", (b"\x00\x01\x00\x00\x07", rows[4][0]))
    result, problem = _run(tmp_path, _import(tmp_path), "undecodable")
    assert problem is None and result.code == 1
    assert "cannot decode message 4 on /tracker/marker" in result.stderr


# -- easy_handeye2 samples (YAML) -------------------------------------------------------------
def _samples_text(count: int = 12, seed: int = 3) -> str:
    from scipy.spatial.transform import Rotation

    from spacecal.geometry.transforms import make_transform
    from spacecal.io.easy_handeye import easy_handeye2_samples_text

    rng = np.random.default_rng(seed)
    robot = make_transform(
        Rotation.random(count, random_state=seed).as_matrix(), rng.normal(0, 300, (count, 3))
    )
    marker = make_transform(
        Rotation.random(count, random_state=seed + 1).as_matrix(),
        rng.normal(0, 300, (count, 3)) + [0, 0, -1200],
    )
    return easy_handeye2_samples_text(
        robot,
        marker,
        name="fuzz",
        robot_base_frame="base_link",
        robot_effector_frame="tool0",
        tracking_base_frame="tracker",
        tracking_marker_frame="marker",
    )


def _yaml_mutation(rng: random.Random, text: str) -> tuple[str, str]:
    kind = rng.choice(["alias", "nesting", "huge-scalar", "wrong-type", "delete", "bytes", "truncate", "tag"])
    if kind == "alias":
        names = "abcdefghi"
        bomb = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
            f"{names[i + 1]}: &{names[i + 1]} [{', '.join([f'*{names[i]}'] * 4)}]\n" for i in range(8)
        )
        return kind, bomb + text if rng.random() < 0.5 else text.replace(
            "samples:", "samples: &s", 1
        ) + "again: *s\n"
    if kind == "nesting":
        depth = rng.choice([100, 1000, 20000])
        return f"{kind} {depth}", text + "deep: " + "[" * depth + "]" * depth + "\n"
    if kind == "huge-scalar":
        value = rng.choice(["1e300", "-1e308", "9" * 5000, "nan", ".inf", "x" * 200_000, "0x" + "f" * 100])
        lines = text.splitlines()
        numbers = [k for k, line in enumerate(lines) if line.rstrip() and line.rstrip()[-1].isdigit()]
        k = rng.choice(numbers)
        head, _, _ = lines[k].rpartition(":")
        lines[k] = f"{head}: {value}"
        return f"{kind} {value[:12]} at line {k + 1}", "\n".join(lines) + "\n"
    if kind in ("wrong-type", "delete"):
        data = yaml.safe_load(text)
        nodes = [p for p in _metadata_nodes(data) if p]
        node = rng.choice(nodes)
        parent = data
        for key in node[:-1]:
            parent = parent[key]
        if kind == "delete":
            del parent[node[-1]]
        else:
            parent[node[-1]] = rng.choice(WRONG_VALUES)
        return f"{kind} {node}", yaml.safe_dump(data)
    if kind == "tag":
        return kind, text.replace("samples:", "samples: !!python/object/apply:os.system", 1)
    data = bytearray(text.encode())
    if kind == "truncate":
        return kind, bytes(data[: rng.randrange(len(data))]).decode("utf-8", errors="replace")
    for _ in range(rng.randint(1, 6)):
        data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
    return kind, bytes(data).decode("latin-1")


def test_hostile_easy_handeye_samples(tmp_path):
    text = _samples_text()
    folder = tmp_path / "clean"
    folder.mkdir()
    (folder / "rec.samples").write_text(text)
    result, problem = _run(folder, ["import-easy-handeye", "rec.samples", "-o", "out.csv"], "clean samples")
    assert problem is None and result.code == 0, problem or result.stderr
    rng = random.Random(SEED + 2)
    problems = []
    for k in range(60):
        label, mutated = _yaml_mutation(rng, text)
        folder = tmp_path / f"case{k}"
        folder.mkdir()
        (folder / "rec.samples").write_text(mutated, encoding="utf-8", errors="surrogateescape")
        problems.append(_run(folder, ["import-easy-handeye", "rec.samples", "-o", "out.csv"], label)[1])
        shutil.rmtree(folder)
    _assert_none(problems)


# -- TUM trajectories -------------------------------------------------------------------------
def _tum_texts(count: int = 40, seed: int = 5) -> tuple[str, str]:
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    texts = []
    for offset in (0.0, 0.004):
        q = Rotation.random(count, random_state=rng.integers(1000)).as_quat()
        xyz = rng.normal(0, 0.3, (count, 3)) + [0.2, -0.1, 0.9]
        lines = ["# timestamp tx ty tz qx qy qz qw"]
        lines += [
            " ".join(f"{v:.9f}" for v in (100.0 + offset + 0.05 * k, *xyz[k], *q[k])) for k in range(count)
        ]
        texts.append("\n".join(lines) + "\n")
    return texts[0], texts[1]


def _tum_mutation(rng: random.Random, text: str) -> tuple[str, str]:
    lines = text.splitlines()
    kind = rng.choice(["value", "backwards", "repeat", "columns", "bytes", "truncate", "long-line", "zero-q"])
    k = rng.randrange(1, len(lines))
    cells = lines[k].split()
    if kind == "value":
        j = rng.randrange(len(cells))
        cells[j] = rng.choice(["nan", "inf", "-inf", "1e300", "-1e308", "abc", "", "1e-320", "0x10"])
        lines[k] = " ".join(cells)
    elif kind == "backwards":
        cells[0] = f"{float(cells[0]) - rng.choice([0.01, 1.0, 1000.0]):.9f}"
        lines[k] = " ".join(cells)
    elif kind == "repeat":
        lines.insert(k, lines[k])
    elif kind == "columns":
        lines[k] = " ".join(cells[: rng.randrange(len(cells))] if rng.random() < 0.5 else cells + ["1.0"])
    elif kind == "zero-q":
        lines[k] = " ".join(cells[:4] + ["0", "0", "0", rng.choice(["0", "0.5", "2"])])
    elif kind == "long-line":
        lines[k] = lines[k] + " " + "9" * 100_000
    elif kind == "truncate":
        return kind, text[: rng.randrange(len(text))]
    else:
        data = bytearray(text.encode())
        for _ in range(rng.randint(1, 6)):
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        return kind, bytes(data).decode("latin-1")
    return f"{kind} at line {k + 1}", "\n".join(lines) + "\n"


def test_hostile_tum_files(tmp_path):
    robot, tracker = _tum_texts()
    argv = ["import-poses", "--robot", "robot.tum", "--tracker", "tracker.tum", "-o", "out"]
    folder = tmp_path / "clean"
    folder.mkdir()
    (folder / "robot.tum").write_text(robot)
    (folder / "tracker.tum").write_text(tracker)
    result, problem = _run(folder, argv, "clean TUM")
    assert problem is None and result.code == 0, problem or result.stderr
    rng = random.Random(SEED + 3)
    problems = []
    for k in range(60):
        which = rng.choice(["robot", "tracker"])
        label, mutated = _tum_mutation(rng, robot if which == "robot" else tracker)
        folder = tmp_path / f"case{k}"
        folder.mkdir()
        (folder / "robot.tum").write_text(mutated if which == "robot" else robot, encoding="latin-1")
        (folder / "tracker.tum").write_text(mutated if which == "tracker" else tracker, encoding="latin-1")
        problems.append(_run(folder, argv, f"{which}.tum: {label}")[1])
        shutil.rmtree(folder)
    _assert_none(problems)
