"""ROS bags in: a ROS 1 ``.bag`` or a ROS 2 bag (sqlite3 ``.db3`` or ``.mcap``) -> :class:`RawRecording`.

Read with the pure-Python ``rosbags`` package (``pip install 'spacecal[ros]'``; no ROS install).
The two streams keep their own time stamps, taken from the message headers, so the clock
offset between robot and tracker is estimated afterwards as for any raw recording
(:func:`spacecal.estimators.time_offset.estimate_time_offset`).

Sources:

* robot, from ``/tf`` (+ ``/tf_static``): the chain from a base frame to a tool frame, composed
  through the tf tree (``base_from_tool``; edges that are published at other times are
  interpolated, linearly in position and along the geodesic in rotation, at the stamps of the
  chain's most frequent edge);
* robot, from ``sensor_msgs/JointState``: spacecal's kinematics, ``forward_kinematics(model, q)``
  with joints taken by name (the UR driver's names, any prefix);
* marker, from ``/tf``: the chain tracker frame -> marker frame (``tracker_from_marker``);
* marker, from a ``geometry_msgs/PoseStamped`` topic (``header.frame_id`` = tracker frame, the
  pose of the marker in it) or a ``geometry_msgs/TransformStamped`` topic (``header.frame_id`` =
  tracker, ``child_frame_id`` = marker).

Boundary conversions: a ROS transform with ``header.frame_id = P`` and ``child_frame_id = C`` is
the pose of C in P, our ``p_from_c``; translations in metres become mm; quaternions ``x, y, z,
w`` become rotation matrices (stored by spacecal as ``w, x, y, z`` where quaternions appear).
Times are seconds since the earliest header stamp used (kept as integer nanoseconds until
then, so no precision is lost to the epoch); the origin is in ``metadata["ros_bag"]``.

Which streams: when the bag has one obvious choice (exactly one PoseStamped/TransformStamped
topic for the marker; exactly one JointState topic when a robot model is given; tf chains that
fit the frames named in one way only, or in one way whose frame names say robot and tracker)
no names are needed and the recording's metadata says what was picked; otherwise the error
lists every way with the arguments that choose it (see :func:`list_bag_contents`). Bags
without embedded message definitions (older ROS 2 sqlite3 bags) are decoded with a standard
type store (``ros1_noetic`` for ``.bag``, ``ros2_humble`` otherwise; choose another with
``typestore=``).

Frame names lose a leading ``/`` (ROS 1 tf). The recording's ``base`` is the base frame you
name; for UR robots the controller's base is ur_description's ``base`` (not ``base_link``), and
``tool0_controller`` is the TCP the controller reports.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from spacecal.core.errors import InvalidInputError, MissingExtraError, SpacecalError
from spacecal.core.text import quoted, sanitize_for_terminal
from spacecal.geometry.transforms import invert_transform, make_transform
from spacecal.io.ros_common import (
    MAX_TRANSLATION_M,
    QUATERNION_NORM_TOLERANCE,
    UR_JOINT_NAMES,
    transform_from_ros,
)
from spacecal.io.yaml_text import check_yaml_file
from spacecal.models.kinematics import RobotModel, forward_kinematics
from spacecal.models.robot_kinds import robot_kind
from spacecal.records import RawRecording

TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
POSE_TYPES = ("geometry_msgs/msg/PoseStamped",)
TRANSFORM_TYPES = ("geometry_msgs/msg/TransformStamped",)
MARKER_TYPES = POSE_TYPES + TRANSFORM_TYPES
JOINT_STATE_TYPES = ("sensor_msgs/msg/JointState",)
ROBOT_SEGMENT = "ros_bag"
#: Longest topic or frame name shown in full by :meth:`BagContents.describe`.
NAME_DISPLAY_CHARS = 120
#: Longest clue from a library's exception quoted in an error line.
CAUSE_CHARS = 200
#: Most messages read from one topic (a calibration run at 500 Hz for an hour is 1.8 million):
#: a longer stream is refused as it is read, before it fills the memory.
MAX_TOPIC_MESSAGES = 2_000_000
#: Largest serialized message read (a tf message of a few hundred frames is tens of kB).
MAX_MESSAGE_BYTES = 1 << 20
#: Largest joint position accepted, rad (UR joints turn +-360 deg).
MAX_JOINT_RAD = 4 * np.pi
#: Largest share of a stream's messages that may be invalid or out of time order and be
#: skipped (named in the recording's notes); a stream with more is refused.
MAX_UNUSABLE_FRACTION = 0.05


def _rosbags():
    try:
        from rosbags.highlevel import AnyReader, AnyReaderError
        from rosbags.typesys import Stores, get_typestore
    except ImportError as exc:
        raise MissingExtraError(
            "reading ROS bags needs the rosbags package: pip install 'spacecal[ros]'"
        ) from exc
    return AnyReader, AnyReaderError, Stores, get_typestore


def _check_bag_metadata(metadata: Path) -> None:
    """Refuse YAML anchors and aliases in a ROS 2 bag's ``metadata.yaml`` before rosbags reads it
    (ROS writes none; a few hundred bytes of aliases can stand for gigabytes). Without PyYAML the
    file is left to rosbags alone."""
    try:
        import yaml  # noqa: F401 - the ros extra brings it with rosbags
    except ImportError:  # pragma: no cover - the extra installs both
        return
    check_yaml_file(metadata, "ROS 2 bag metadata")


def _cause(exc: BaseException) -> str:
    """A library's exception as a short clue for an error line (the full text of some, e.g. a
    message definition that does not parse, runs to kilobytes)."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return sanitize_for_terminal(text, CAUSE_CHARS)


def _check_listing(reader, path: Path) -> None:
    """Refuse a bag whose index (ROS 2 ``metadata.yaml``, an mcap summary, a ROS 1 index) gives
    a topic a name, type or count of the wrong kind: rosbags passes them on as found."""
    for number, connection in enumerate(reader.connections, 1):
        count = getattr(connection, "msgcount", 0)
        if not isinstance(connection.topic, str) or not connection.topic:
            raise InvalidInputError(
                f"{path}: the bag's index names topic {number} {quoted(connection.topic)}, not a topic name"
            )
        if not isinstance(connection.msgtype, str):
            raise InvalidInputError(
                f"{path}: the bag's index gives topic {quoted(connection.topic)} the type "
                f"{quoted(connection.msgtype)}, not a message type name"
            )
        if isinstance(count, bool) or not isinstance(count, int) or count < 0:
            raise InvalidInputError(
                f"{path}: the bag's index gives topic {quoted(connection.topic)} the message count "
                f"{quoted(count)}, not a count"
            )


# -- MCAP declared sizes --------------------------------------------------------------------
# rosbags reads an MCAP file's records, chunks and chunk index entries by the sizes they declare:
# it asks for that many bytes before it learns the file is shorter (a record of 2**62 bytes ends
# only in a MemoryError), and it decompresses a whole chunk before it compares the result with
# the declared size (a zstd chunk of 1 kB may expand to 30 MB, a 1 MB file to 30 GB). So every
# size is checked here against the file's real size, and every compressed chunk is expanded once
# with its output bounded, before rosbags opens the file. Layout (MCAP specification): 8 bytes of
# magic, then records of an opcode (1 byte), a length (u64 LE) and that many bytes.

_MCAP_MAGIC = b"\x89MCAP0\r\n"
_MCAP_FOOTER, _MCAP_CHUNK, _MCAP_CHUNK_INDEX, _MCAP_SUMMARY_OFFSET = 0x02, 0x06, 0x08, 0x0E
_MCAP_FOOTER_BYTES = 37
#: Largest chunk read, uncompressed, bytes: ROS 2's MCAP writer closes its chunks at 768 kB and
#: its presets at a few MB; a larger one is damaged or hostile, not a recording.
MAX_MCAP_CHUNK_BYTES = 128 << 20


@dataclass(frozen=True)
class _McapChunk:
    """Where a chunk's compressed records lie and what it declares of them."""

    data_offset: int
    compressed_bytes: int
    compression: str
    uncompressed_bytes: int
    declared_at: str


class _McapBody:
    """The body of one MCAP record, read field by field within its declared length."""

    def __init__(self, file, path: Path, start: int, length: int, what: str):
        self.file, self.path, self.end, self.what = file, path, start + length, what
        file.seek(start)

    def take(self, count: int) -> bytes:
        if count > self.end - self.file.tell():
            raise InvalidInputError(f"{self.path}: damaged MCAP file: {self.what} runs past its own end")
        return self.file.read(count)

    def u32(self) -> int:
        return int.from_bytes(self.take(4), "little")

    def u64(self) -> int:
        return int.from_bytes(self.take(8), "little")

    def text(self) -> str:
        return self.take(self.u32()).decode("utf-8", errors="replace")


def _mcap_records(file, path: Path, size: int, start: int, ends: set[int], chunks: list[_McapChunk]) -> None:
    """Walk the records from byte ``start`` to one whose opcode is in ``ends`` (or the file's end),
    refusing any that declares more bytes than the file has left; the chunks and chunk index
    entries met are added to ``chunks``."""
    position = start
    while position + 9 <= size:
        file.seek(position)
        head = file.read(9)
        opcode, length = head[0], int.from_bytes(head[1:], "little")
        left = size - position - 9
        if length > left:
            raise InvalidInputError(
                f"{path}: damaged MCAP file: the record at byte {position} (opcode 0x{opcode:02x}) "
                f"declares {length} bytes, and {left} are left in the file"
            )
        if opcode in ends:
            return
        if opcode == _MCAP_CHUNK:
            where = f"the chunk at byte {position}"
            body = _McapBody(file, path, position + 9, length, where)
            body.take(16)  # message start and end times
            uncompressed, _crc, compression = body.u64(), body.u32(), body.text()
            compressed = body.u64()
            if compressed > body.end - file.tell():
                raise InvalidInputError(
                    f"{path}: damaged MCAP file: {where} declares {compressed} bytes of records in a "
                    f"record of {length}"
                )
            chunks.append(_McapChunk(file.tell(), compressed, compression, uncompressed, where))
        elif opcode == _MCAP_CHUNK_INDEX:
            where = f"the chunk index entry at byte {position}"
            body = _McapBody(file, path, position + 9, length, where)
            body.take(16)
            chunk_start, chunk_length = body.u64(), body.u64()
            body.take(body.u32())  # message index offsets
            body.take(8)  # message index length
            compression = body.text()
            compressed, uncompressed = body.u64(), body.u64()
            if chunk_start + chunk_length > size:
                raise InvalidInputError(
                    f"{path}: damaged MCAP file: {where} puts a chunk "
                    f"of {chunk_length} bytes at byte {chunk_start}, beyond the file's {size} bytes"
                )
            # rosbags reads the records from where a chunk record of this compression holds them
            data_offset = chunk_start + 9 + 40 + len(compression.encode("utf-8"))
            if data_offset + compressed > size:
                raise InvalidInputError(
                    f"{path}: damaged MCAP file: {where} declares "
                    f"{compressed} compressed bytes at byte {data_offset}, beyond the file's {size} bytes"
                )
            chunks.append(_McapChunk(data_offset, compressed, compression, uncompressed, where))
        position += 9 + length


def _check_mcap_chunk(file, path: Path, chunk: _McapChunk) -> None:
    """Refuse a chunk larger than :data:`MAX_MCAP_CHUNK_BYTES` uncompressed, or one that expands
    beyond the size it declares (checked with the output bounded)."""
    if chunk.uncompressed_bytes > MAX_MCAP_CHUNK_BYTES or chunk.compressed_bytes > MAX_MCAP_CHUNK_BYTES:
        raise InvalidInputError(
            f"{path}: {chunk.declared_at} declares a chunk of {chunk.uncompressed_bytes} bytes "
            f"({chunk.compressed_bytes} compressed), more than spacecal reads of one chunk "
            f"({MAX_MCAP_CHUNK_BYTES} bytes)"
        )
    if chunk.compression not in ("lz4", "zstd"):
        return  # uncompressed (or unknown: rosbags refuses it) holds only its declared bytes
    file.seek(chunk.data_offset)
    data = file.read(chunk.compressed_bytes)
    bound = chunk.uncompressed_bytes + 1
    try:
        if chunk.compression == "lz4":
            import lz4.frame  # type: ignore[import-untyped]

            # lz4.frame.decompress allocates the content size a frame header states, first
            stated = lz4.frame.get_frame_info(data).get("content_size") or 0
            if stated > chunk.uncompressed_bytes:
                raise InvalidInputError(
                    f"{path}: damaged MCAP file: {chunk.declared_at} declares a chunk of "
                    f"{chunk.uncompressed_bytes} bytes whose lz4 frame states {stated}"
                )
            expanded = len(lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=bound))
        else:
            try:
                from compression import zstd  # type: ignore[import-not-found]
            except ImportError:
                from backports import zstd
            expanded = len(zstd.ZstdDecompressor().decompress(data, max_length=bound))
    except SpacecalError:
        raise
    except Exception:  # damaged compressed data: rosbags refuses it, with its own words
        return
    if expanded > chunk.uncompressed_bytes:
        raise InvalidInputError(
            f"{path}: damaged MCAP file: {chunk.declared_at} declares a chunk of {chunk.uncompressed_bytes} "
            f"bytes that expands to more"
        )


def check_mcap_sizes(path: Path) -> None:
    """Refuse an MCAP file whose records, chunks or chunk index declare sizes it does not hold.

    Raises
    ------
    InvalidInputError
        A record longer than the rest of the file, a chunk index entry beyond the file's end, a
        chunk larger than :data:`MAX_MCAP_CHUNK_BYTES` or expanding beyond its declared size.
        A file that is no MCAP (no magic) is left to the reader.
    """
    size = path.stat().st_size
    chunks: list[_McapChunk] = []
    with path.open("rb") as file:
        if file.read(len(_MCAP_MAGIC)) != _MCAP_MAGIC:
            return
        # the data section record by record, and the summary where the footer says it starts,
        # as rosbags walks it (a footer may point anywhere)
        _mcap_records(file, path, size, len(_MCAP_MAGIC), {_MCAP_FOOTER}, chunks)
        if size >= len(_MCAP_MAGIC) + _MCAP_FOOTER_BYTES:
            file.seek(size - _MCAP_FOOTER_BYTES)
            footer = file.read(_MCAP_FOOTER_BYTES)
            summary_start = int.from_bytes(footer[9:17], "little")
            if footer[0] == _MCAP_FOOTER and len(_MCAP_MAGIC) <= summary_start < size - _MCAP_FOOTER_BYTES:
                _mcap_records(file, path, size, summary_start, {_MCAP_FOOTER, _MCAP_SUMMARY_OFFSET}, chunks)
        for chunk in dict.fromkeys(chunks):
            _check_mcap_chunk(file, path, chunk)


def _mcap_files(path: Path) -> list[Path]:
    """The MCAP files of a bag: the file itself, or those of a ROS 2 bag folder."""
    if path.is_dir():
        return sorted(p for p in path.iterdir() if p.suffix == ".mcap" and p.is_file())
    return [path] if path.suffix == ".mcap" and path.is_file() else []


@contextmanager
def _open_bag(path: Path, typestore: str | None):
    AnyReader, AnyReaderError, Stores, get_typestore = _rosbags()
    if not path.exists():
        raise InvalidInputError(f"{path}: no such bag")
    metadata = path / "metadata.yaml"
    if path.is_dir() and metadata.is_file():
        _check_bag_metadata(metadata)
    for mcap in _mcap_files(path):
        check_mcap_sizes(mcap)
    store_name = typestore or ("ros1_noetic" if path.suffix == ".bag" else "ros2_humble")
    try:
        store = get_typestore(Stores(store_name))
    except ValueError:
        known = ", ".join(s.value for s in Stores)
        raise InvalidInputError(f"unknown ROS type store {store_name!r}; known: {known}") from None
    try:
        reader = AnyReader([path], default_typestore=store)
        reader.open()
    except SpacecalError:
        raise
    except Exception as exc:  # a damaged file or index: rosbags and sqlite3 raise many kinds
        raise InvalidInputError(f"{path}: not a readable ROS 1 or ROS 2 bag ({_cause(exc)})") from None
    try:
        _check_listing(reader, path)
        # Types the bag does not define are taken from the standard store (bags may define some only).
        missing = {k: v for k, v in store.fielddefs.items() if k not in reader.typestore.fielddefs}
        if missing:
            try:
                reader.typestore.register(missing)
            except Exception:  # a conflicting definition: keep the bag's own
                pass
        reader.spacecal_store_name = store_name
        yield reader
    finally:
        with suppress(Exception):  # closing a damaged bag must not hide why it was refused
            reader.close()


def _listing(names: Sequence[str], count: int = 20) -> str:
    """Names from a bag for an error message: each escaped and cut, at most ``count`` of them."""
    shown = ", ".join(sanitize_for_terminal(n, 60) for n in names[:count])
    return shown + (f", ... ({len(names)} in all)" if len(names) > count else "")


def _frame(name: str) -> str:
    if not isinstance(name, str):
        raise TypeError(f"a frame name of type {type(name).__name__}")
    return name.lstrip("/")


def _stamp_ns(header) -> int:
    """A header stamp in ns since the epoch; -1 for one that is no time (negative seconds,
    nanoseconds outside 0..999999999)."""
    sec, nanosec = int(header.stamp.sec), int(header.stamp.nanosec)
    if sec < 0 or not 0 <= nanosec < 1_000_000_000:
        return -1
    return sec * 1_000_000_000 + nanosec


@contextmanager
def _layout(path: Path, topic: str, index: int, msgtype: str):
    """Fields of a message read as numbers and names: a bag may define a standard type its own
    way (a ROS 1 bag embeds the definitions), so a field of the wrong kind is one clear line."""
    try:
        yield
    except (AttributeError, TypeError, ValueError, OverflowError, IndexError) as exc:
        raise InvalidInputError(
            f"{path}: message {index} on {topic} is not a {msgtype} as ROS defines it ({_cause(exc)})"
        ) from None


def _pose_problems(
    translations_m: np.ndarray, quaternions_xyzw: np.ndarray, unseen_ok: bool
) -> list[str | None]:
    """Why each pose sample cannot be used (None: it can).

    Parameters
    ----------
    translations_m : numpy.ndarray, shape (N, 3)
        Translations from the messages, metres.
    quaternions_xyzw : numpy.ndarray, shape (N, 4)
        Rotations from the messages, ROS order ``x, y, z, w``.
    unseen_ok : bool
        A translation of three NaN is a marker the tracker did not see (kept as such).
    """
    translations_m = np.asarray(translations_m, dtype=float).reshape(-1, 3)
    quaternions_xyzw = np.asarray(quaternions_xyzw, dtype=float).reshape(-1, 4)
    with np.errstate(all="ignore"):
        finite = np.all(np.isfinite(translations_m), axis=1) & np.all(np.isfinite(quaternions_xyzw), axis=1)
        unseen = np.all(np.isnan(translations_m), axis=1) if unseen_ok else np.zeros(len(finite), bool)
        distance = np.max(np.abs(np.where(finite[:, None], translations_m, 0.0)), axis=1)
        norms = np.linalg.norm(np.where(finite[:, None], quaternions_xyzw, 1.0), axis=1)
    problems: list[str | None] = []
    for k in range(len(finite)):
        if unseen[k]:
            problems.append(None)
        elif not finite[k]:
            problems.append("a value that is not a finite number")
        elif not distance[k] <= MAX_TRANSLATION_M:
            problems.append(f"a translation of {distance[k]:.3g} m along an axis")
        elif not abs(norms[k] - 1.0) <= QUATERNION_NORM_TOLERANCE:
            problems.append(f"a quaternion of norm {norms[k]:.6g}, not a unit quaternion")
        else:
            problems.append(None)
    return problems


def _nondecreasing(values: np.ndarray) -> np.ndarray:
    """Mask of a longest non-decreasing subsequence of ``values`` (N,): the samples that keep
    their time order when the fewest are dropped (a lone stamp out of place is the one dropped)."""
    n = len(values)
    if n == 0 or np.all(np.diff(values) >= 0):
        return np.ones(n, dtype=bool)
    tails: list[int] = []  # value ending the best subsequence of each length
    ends: list[int] = []  # index of that value
    previous = np.full(n, -1, dtype=np.int64)
    for k, value in enumerate(values.tolist()):
        j = bisect_right(tails, value)
        if j == len(tails):
            tails.append(value)
            ends.append(k)
        else:
            tails[j], ends[j] = value, k
        previous[k] = ends[j - 1] if j > 0 else -1
    keep = np.zeros(n, dtype=bool)
    k = ends[-1]
    while k >= 0:
        keep[k] = True
        k = int(previous[k])
    return keep


def _usable(
    stamps_ns: Sequence[int],
    problems: Sequence[str | None],
    sources: Sequence[tuple[str, int]],
    where: str,
    notes: list[str],
) -> np.ndarray:
    """Indices (K,) of the samples of a stream to keep, in strictly increasing time.

    Dropped, in this order: samples with a problem (``problems[k]``, or a stamp that is no
    time), samples whose stamp is out of the stream's time order (the fewest that restore it),
    and samples repeating the stamp of the one before. A stream whose dropped invalid and
    out-of-order samples exceed :data:`MAX_UNUSABLE_FRACTION` is refused with one line naming
    the first; otherwise what was dropped is appended to ``notes``.

    Parameters
    ----------
    stamps_ns : sequence of int, length N
        Header stamps in ns since the epoch (-1: not a time), in bag order.
    problems : sequence of str or None, length N
        Why a sample's values cannot be used (None: they can).
    sources : sequence of (str, int), length N
        The topic and message index (on that topic, from 0) each sample came from.
    where : str
        Names the bag and stream in the refusal and the note.
    notes : list of str
        Receives one line when anything was dropped.
    """
    n = len(stamps_ns)
    stamps = np.array(stamps_ns, dtype=np.int64)
    reasons = [
        p if p is not None else ("a time stamp that is no time" if t < 0 else None)
        for p, t in zip(problems, stamps_ns)
    ]
    valid = np.array([r is None for r in reasons], dtype=bool)
    ordered = np.zeros(n, dtype=bool)
    ordered[valid] = _nondecreasing(stamps[valid])
    keep = np.flatnonzero(ordered)
    repeated = np.concatenate([[False], np.diff(stamps[keep]) == 0]) if len(keep) else np.zeros(0, bool)
    invalid = np.flatnonzero(~valid)
    out_of_order = np.flatnonzero(valid & ~ordered)

    def at(k: int) -> str:
        topic, index = sources[k]
        return f"message {index} on {topic}"

    unusable = len(invalid) + len(out_of_order)
    if unusable > MAX_UNUSABLE_FRACTION * n:
        first = min(np.concatenate([invalid, out_of_order]).tolist())
        why = reasons[first] or "a time stamp earlier than the stamps before it"
        raise InvalidInputError(
            f"{where}: {unusable} of {n} messages are unusable, too many to skip "
            f"(the first, {at(first)}, has {why})"
        )
    dropped = []
    if len(invalid):
        dropped.append(
            f"{len(invalid)} invalid (the first, {at(int(invalid[0]))}, has {reasons[int(invalid[0])]})"
        )
    if len(out_of_order):
        dropped.append(f"{len(out_of_order)} out of time order (the first: {at(int(out_of_order[0]))})")
    if repeated.any():
        first_repeat = int(keep[np.flatnonzero(repeated)[0]])
        dropped.append(
            f"{int(repeated.sum())} repeating the time stamp of the one before "
            f"(the first: {at(first_repeat)})"
        )
    if dropped:
        notes.append(
            f"{where}: skipped {unusable + int(repeated.sum())} of {n} messages: {'; '.join(dropped)}"
        )
    return keep[~repeated]


def _messages(reader, path: Path, topics: Sequence[str]):
    """(topic, index on the topic, log time ns, message) of the named topics in bag order.

    A damaged file, an undecodable or oversized message and a topic with more messages than
    :data:`MAX_TOPIC_MESSAGES` each end the read with one line naming the bag, the topic and
    the message's index on it (counted from 0), before more is read.
    """
    connections = [c for c in reader.connections if c.topic in topics]
    for connection in connections:
        if connection.msgtype not in reader.typestore.fielddefs:
            raise InvalidInputError(
                f"{path}: topic {connection.topic} has type {connection.msgtype}, defined neither in the bag "
                f"nor in the {reader.spacecal_store_name} type store (choose another with typestore=)"
            )
    counts: dict[str, int] = {}
    try:
        stream = iter(reader.messages(connections=connections))
    except Exception as exc:
        raise InvalidInputError(f"{path}: cannot read the messages of the bag ({_cause(exc)})") from None
    while True:
        try:
            connection, log_ns, raw = next(stream)
        except StopIteration:
            return
        except Exception as exc:  # a truncated or damaged file, found as it is read
            done = ", ".join(f"{n} on {t}" for t, n in counts.items()) or "none"
            raise InvalidInputError(
                f"{path}: the bag is damaged after {sum(counts.values())} messages read "
                f"({done}): {_cause(exc)}"
            ) from None
        topic = connection.topic
        index = counts.get(topic, 0)
        counts[topic] = index + 1
        if index >= MAX_TOPIC_MESSAGES:
            raise InvalidInputError(
                f"{path}: topic {topic} holds more than {MAX_TOPIC_MESSAGES} messages; cut the bag to the "
                "calibration run (ros2 bag convert, rosbag filter)"
            )
        if len(raw) > MAX_MESSAGE_BYTES:
            raise InvalidInputError(
                f"{path}: message {index} on {topic} is {len(raw)} bytes, more than a "
                f"{connection.msgtype} of a calibration can hold ({MAX_MESSAGE_BYTES})"
            )
        try:
            message = reader.deserialize(raw, connection.msgtype)
        except Exception as exc:  # rosbags raises several kinds here
            raise InvalidInputError(
                f"{path}: cannot decode message {index} on {topic}, a {connection.msgtype} ({_cause(exc)})"
            ) from None
        yield topic, index, log_ns, message


@dataclass(frozen=True)
class BagTopic:
    """A topic of a bag: name, message type (``pkg/msg/Name``), message count."""

    name: str
    msgtype: str
    count: int


@dataclass(frozen=True)
class TfEdge:
    """A tf edge found in a bag: ``parent -> child`` (pose of child in parent), count, static or not."""

    parent: str
    child: str
    count: int
    static: bool


@dataclass
class BagContents:
    """What a bag holds, for choosing the streams (:func:`list_bag_contents`)."""

    path: str
    topics: list[BagTopic]
    tf_edges: list[TfEdge] = field(default_factory=list)

    def topics_of(self, msgtypes: Sequence[str]) -> list[str]:
        """Names of the topics whose type is one of ``msgtypes``."""
        return [t.name for t in self.topics if t.msgtype in msgtypes]

    @property
    def marker_topics(self) -> list[str]:
        """PoseStamped and TransformStamped topics (candidate marker streams)."""
        return self.topics_of(MARKER_TYPES)

    @property
    def joint_state_topics(self) -> list[str]:
        """JointState topics (candidate robot streams with a kinematic model)."""
        return self.topics_of(JOINT_STATE_TYPES)

    def tf_chains(self) -> list[tuple[str, str]]:
        """``(root, leaf)`` of every branch of the tf forest that moves (holds a non-static edge)."""
        return _tf_chains(self.tf_edges)

    def describe(self) -> str:
        """A table for people: topics with types and counts, tf edges, candidate chains.

        Names come from the bag: each is shown with its control characters escaped and cut to
        :data:`NAME_DISPLAY_CHARS` characters, so a hostile bag cannot drive the terminal.
        """

        def show(name: str) -> str:
            return sanitize_for_terminal(name, NAME_DISPLAY_CHARS)

        lines = [show(self.path), "topics:"]
        names = [show(t.name) for t in self.topics]
        width = max((len(n) for n in names), default=0)
        for name, t in zip(names, self.topics):
            lines.append(f"  {name:<{width}}  {show(t.msgtype)}  ({t.count} messages)")
        if self.tf_edges:
            lines.append("tf edges (parent -> child):")
            for e in self.tf_edges:
                lines.append(
                    f"  {show(e.parent)} -> {show(e.child)}  ({e.count}{', static' if e.static else ''})"
                )
            cycle = _tf_cycle((e.parent, e.child) for e in self.tf_edges)
            if cycle is not None:
                lines.append(f"tf loop (no pose is composed through it): {_cycle_text(cycle)}")
            chains = self.tf_chains()
            if chains:
                lines.append(
                    "moving tf chains (root -> leaf): "
                    + "; ".join(f"{show(a)} -> {show(b)}" for a, b in chains)
                )
        return "\n".join(lines)


def _tf_cycle(pairs) -> list[str] | None:
    """The frames of one loop of tf edges ``(parent, child)`` (first frame repeated at the end),
    or None: tf is a tree, and a walk up a loop never reaches a root."""
    children: dict[str, list[str]] = {}
    for parent, child in pairs:
        children.setdefault(parent, []).append(child)
        children.setdefault(child, [])
    state: dict[str, int] = {}  # 1 on the path being walked, 2 done
    for root in sorted(children):
        if root in state:
            continue
        path, branches = [root], [iter(children[root])]
        state[root] = 1
        while path:
            child = next(branches[-1], None)
            if child is None:
                state[path.pop()] = 2
                branches.pop()
            elif state.get(child) == 1:
                return path[path.index(child) :] + [child]
            elif child not in state:
                state[child] = 1
                path.append(child)
                branches.append(iter(children[child]))
    return None


def _cycle_text(cycle: list[str], count: int = 8) -> str:
    """A tf loop for a message: its frames escaped and cut, the loop cut to ``count`` frames."""
    shown = [sanitize_for_terminal(f, 60) for f in cycle]
    if len(shown) > count + 1:
        shown = shown[:count] + [f"... ({len(cycle) - 1} frames)", shown[-1]]
    return " -> ".join(shown)


def _refuse_tf_cycle(pairs, where: str) -> None:
    """Refuse tf edges that form a loop, naming its frames."""
    cycle = _tf_cycle(pairs)
    if cycle is not None:
        raise InvalidInputError(
            f"{where}: the tf frames form a loop ({_cycle_text(cycle)}); tf is a tree, so no pose "
            "can be composed through it"
        )


def _parents(edges) -> dict[str, str]:
    parents: dict[str, str] = {}
    for e in edges:
        parents.setdefault(e.child, e.parent)
    return parents


def _tf_chains(edges: Sequence[TfEdge]) -> list[tuple[str, str]]:
    parents = _parents(edges)
    moving = {(e.parent, e.child) for e in edges if not e.static}
    frames = set(parents) | set(parents.values())
    has_children = set(parents.values())
    chains = []
    for leaf in sorted(frames - has_children):
        node, moves = leaf, False
        seen = {leaf}
        while node in parents:
            moves |= (parents[node], node) in moving
            node = parents[node]
            if node in seen:
                break
            seen.add(node)
        if moves:
            chains.append((node, leaf))
    return chains


@dataclass
class _EdgeSeries:
    """The samples of one tf edge in bag order: stamps (ns), translations (m), quaternions
    (x, y, z, w) as the messages hold them, and the (topic, message index) of each."""

    times_ns: list[int] = field(default_factory=list)
    translations_m: list[tuple[float, float, float]] = field(default_factory=list)
    quaternions_xyzw: list[tuple[float, float, float, float]] = field(default_factory=list)
    sources: list[tuple[str, int]] = field(default_factory=list)
    static: bool = False


def _read_tf(reader, path: Path, topics: Sequence[str]) -> dict[tuple[str, str], _EdgeSeries]:
    edges: dict[tuple[str, str], _EdgeSeries] = {}
    for topic, index, _, message in _messages(reader, path, topics):
        with _layout(path, topic, index, "tf2_msgs/msg/TFMessage"):
            for ts in message.transforms:
                key = (_frame(ts.header.frame_id), _frame(ts.child_frame_id))
                series = edges.setdefault(key, _EdgeSeries())
                series.static |= topic.rstrip("/").endswith("tf_static")
                t, r = ts.transform.translation, ts.transform.rotation
                series.times_ns.append(_stamp_ns(ts.header))
                series.translations_m.append((float(t.x), float(t.y), float(t.z)))
                series.quaternions_xyzw.append((float(r.x), float(r.y), float(r.z), float(r.w)))
                series.sources.append((topic, index))
    return edges


def list_bag_contents(path: str | Path, typestore: str | None = None) -> BagContents:
    """The topics of a bag (type, count) and its tf edges, to choose the streams from.

    Parameters
    ----------
    path : str or Path
        A ROS 1 ``.bag``, a ROS 2 bag directory, or a bare ``.db3`` / ``.mcap`` file.
    typestore : str, optional
        Type store for bags without message definitions (e.g. ``"ros2_humble"``).
    """
    path = Path(path)
    with _open_bag(path, typestore) as reader:
        topics = [
            BagTopic(name, info.msgtype or "?", int(info.msgcount)) for name, info in reader.topics.items()
        ]
        tf_topics = [t.name for t in topics if t.msgtype in TF_TYPES]
        series = _read_tf(reader, path, tf_topics) if tf_topics else {}
    edges = [
        TfEdge(parent, child, len(s.times_ns), s.static or _constant(s))
        for (parent, child), s in sorted(series.items())
    ]
    return BagContents(str(path), sorted(topics, key=lambda t: t.name), edges)


def _constant(series: _EdgeSeries) -> bool:
    if len(series.times_ns) < 2:
        return True
    values = np.hstack([np.array(series.translations_m), np.array(series.quaternions_xyzw)])
    return bool(np.all(values == values[0]))


def _edge_stack(
    series: _EdgeSeries, what: str, notes: list[str], moving: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """(times ns (K,), parent_from_child (K, 4, 4) mm) of the usable samples of a tf edge in
    increasing time (see :func:`_usable`). The stamps of an edge that does not move are not
    used, so only its values are checked there."""
    translations = np.array(series.translations_m, dtype=float).reshape(-1, 3)
    quaternions = np.array(series.quaternions_xyzw, dtype=float).reshape(-1, 4)
    problems = _pose_problems(translations, quaternions, unseen_ok=False)
    if moving:
        keep = _usable(series.times_ns, problems, series.sources, what, notes)
    else:
        keep = np.flatnonzero([p is None for p in problems])[-1:]
        if len(keep) == 0:
            topic, index = series.sources[-1]
            raise InvalidInputError(
                f"{what}: no usable message (message {index} on {topic} has {problems[-1]})"
            )
    times = np.array(series.times_ns, dtype=np.int64)[keep]
    return times, transform_from_ros(translations[keep], quaternions[keep], what)


def _interpolate(times_ns, stack, query_ns) -> np.ndarray:
    """Poses (Q, 4, 4) at ``query_ns`` inside ``times_ns``: position linear, rotation slerp."""
    if len(times_ns) == len(query_ns) and np.array_equal(times_ns, query_ns):
        return stack
    base = times_ns[0]
    t = (times_ns - base).astype(float)
    q = (query_ns - base).astype(float)
    rotation = Slerp(t, Rotation.from_matrix(stack[:, :3, :3]))(q).as_matrix()
    position = np.column_stack([np.interp(q, t, stack[:, k, 3]) for k in range(3)])
    return make_transform(rotation, position)


def _path_to_root(parents: dict[str, str], frame: str) -> list[str]:
    path = [frame]
    while path[-1] in parents:
        path.append(parents[path[-1]])
        if len(path) > len(parents) + 1:
            break
    return path


def _chain(
    edges: dict[tuple[str, str], _EdgeSeries],
    from_frame: str,
    to_frame: str,
    where: str,
    notes: list[str] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``from_frame <- to_frame`` through the tf tree at the stamps of its most frequent moving edge.

    Returns times (N,) in ns and ``from_from_to`` (N, 4, 4) in mm; what was skipped of the
    edges walked is appended to ``notes``.
    """
    notes = [] if notes is None else notes
    _refuse_tf_cycle(edges, where)
    parents: dict[str, str] = {}
    for parent, child in edges:
        if child in parents and parents[child] != parent:
            raise InvalidInputError(
                f"{where}: tf frame {quoted(child)} has two parents ({_listing([parents[child], parent])})"
            )
        parents[child] = parent
    frames = set(parents) | set(parents.values())
    for frame in (from_frame, to_frame):
        if frame not in frames:
            raise InvalidInputError(
                f"{where}: tf has no frame {quoted(frame)}; frames: {_listing(sorted(frames))}"
            )
    up_from, up_to = _path_to_root(parents, from_frame), _path_to_root(parents, to_frame)
    common = next((f for f in up_from if f in up_to), None)
    if common is None:
        raise InvalidInputError(
            f"{where}: tf frames {quoted(from_frame)} and {quoted(to_frame)} are not connected"
        )
    # edges (parent, child, sign): +1 walked down (parent_from_child), -1 walked up (its inverse)
    walk = [(up_from[k + 1], up_from[k], -1) for k in range(up_from.index(common))]
    walk += [(up_to[k + 1], up_to[k], +1) for k in reversed(range(up_to.index(common)))]
    moving = [(p, c) for p, c, _ in walk if not (edges[(p, c)].static or _constant(edges[(p, c)]))]
    stacks = {
        (p, c): _edge_stack(edges[(p, c)], f"{where}: tf {p} -> {c}", notes, (p, c) in moving)
        for p, c, _ in walk
    }
    if not moving:
        raise InvalidInputError(f"{where}: the tf chain {from_frame} -> {to_frame} never moves")
    reference = max(moving, key=lambda key: len(stacks[key][0]))
    times = stacks[reference][0]
    for key in moving:
        edge_times = stacks[key][0]
        times = times[(times >= edge_times[0]) & (times <= edge_times[-1])]
    if len(times) == 0:
        raise InvalidInputError(
            f"{where}: the moving edges of {from_frame} -> {to_frame} do not overlap in time"
        )
    result = np.broadcast_to(np.eye(4), (len(times), 4, 4)).copy()
    for parent, child, sign in walk:
        edge_times, stack = stacks[(parent, child)]
        pose = _interpolate(edge_times, stack, times) if (parent, child) in moving else stack[-1][None]
        result = result @ (pose if sign > 0 else invert_transform(pose))
    return times, result


def _one(candidates: list, what: str, hint: str, where: str):
    if len(candidates) == 1:
        return candidates[0]
    listing = _listing([str(c) for c in candidates]) if candidates else "none"
    raise InvalidInputError(
        f"{where}: cannot choose the {what} ({len(candidates)} candidates: {listing}); {hint}"
    )


#: How :func:`read_ros_bag`'s messages name its arguments by default (a command line passes its
#: flags instead, see ``option_names``); ``list`` is how to look inside the bag.
PYTHON_NAMES = {
    "base_frame": "base_frame",
    "tool_frame": "tool_frame",
    "tracker_frame": "tracker_frame",
    "marker_frame": "marker_frame",
    "joint_state_topic": "joint_state_topic",
    "marker_topic": "marker_topic",
    "robot_model": "robot_model",
    "list": "list_bag_contents",
}

#: Words of frame names that say a tf chain is the robot's or the tracker's (names split at
#: ``_``, ``/``, ``-`` and ``.``, digits dropped: ``tool0`` is ``tool``).
ROBOT_WORDS = frozenset(
    {"base", "tool", "tcp", "flange", "ee", "effector", "wrist", "gripper", "robot", "ur"}
)
TRACKER_WORDS = frozenset(
    {"tracker", "camera", "cam", "ndi", "polaris", "vicra", "aurora", "optical", "marker", "rigid", "body"}
    | {"optitrack", "vicon", "atracsys", "fusiontrack", "reference", "stylus", "drf"}
)


def _words(chain: tuple[str, str]) -> set[str]:
    import re

    return {w.rstrip("0123456789") for name in chain for w in re.split(r"[_/.\-]+", name.lower())} - {""}


def _robot_like(chain: tuple[str, str]) -> bool:
    words = _words(chain)
    return bool(words & ROBOT_WORDS) and not words & TRACKER_WORDS


def _tracker_like(chain: tuple[str, str]) -> bool:
    words = _words(chain)
    return bool(words & TRACKER_WORDS) and not words & ROBOT_WORDS


def _option(say: dict[str, str], name: str, value: str) -> str:
    """``--base-frame base`` for a command line's flag, ``base_frame='base'`` for Python's."""
    import shlex

    flag = say[name]
    if flag.startswith("-"):
        return f"{flag} {shlex.quote(sanitize_for_terminal(value, 60))}"
    return f"{flag}={sanitize_for_terminal(value, 60)!r}"


def _choose_tf_chains(
    chains: list[tuple[str, str]],
    robot_from_tf: bool,
    marker_from_tf: bool,
    frames: dict[str, str | None],
    say: dict[str, str],
    where: str,
) -> tuple[tuple[str, str] | None, tuple[str, str] | None, str | None]:
    """The robot chain (``base_frame <- tool_frame``) and the marker chain (``tracker_frame <-
    marker_frame``) to read from tf, from the frames named and the bag's moving chains.

    A chain named in full is taken as named; otherwise the candidates are the moving chains
    that fit the names given. One way to assign them is taken; among several, the one whose
    frame names say robot (``base``, ``tool0``, ``tcp``...) and tracker (``tracker``,
    ``camera``, ``marker``...) is taken. Returns (robot chain, marker chain, a sentence saying
    what was picked, None when everything was named); raises listing every way with its
    options when the choice is still open.
    """

    def options(first: str, second: str) -> list[tuple[str, str] | None]:
        a, b = frames[first], frames[second]
        if a and b:
            return [(a, b)]
        return [c for c in chains if a in (None, c[0]) and b in (None, c[1])]

    robots: list[tuple[str, str] | None] = options("base_frame", "tool_frame") if robot_from_tf else [None]
    markers: list[tuple[str, str] | None] = (
        options("tracker_frame", "marker_frame") if marker_from_tf else [None]
    )
    ways = [(r, m) for r in robots for m in markers if r is None or m is None or r[1] != m[1]]
    how = "the only way the moving tf chains fit"
    if len(ways) > 1:
        named = [(r, m) for r, m in ways if (r is None or _robot_like(r)) and (m is None or _tracker_like(m))]
        if len(named) == 1:
            ways, how = named, "by their frame names"

    def flags(robot: tuple[str, str] | None, marker: tuple[str, str] | None) -> str:
        parts = []
        if robot is not None:
            parts += [_option(say, "base_frame", robot[0]), _option(say, "tool_frame", robot[1])]
        if marker is not None:
            parts += [_option(say, "tracker_frame", marker[0]), _option(say, "marker_frame", marker[1])]
        return " ".join(parts)

    if len(ways) != 1:
        what = " and ".join(
            w for w, needed in (("robot", robot_from_tf), ("marker", marker_from_tf)) if needed
        )
        moving = ", ".join(f"{a} -> {b}" for a, b in chains) or "none"
        listed = "; or ".join(flags(r, m) for r, m in ways[:20]) + (
            f"; ... ({len(ways)} in all)" if len(ways) > 20 else ""
        )
        raise InvalidInputError(
            f"{where}: cannot choose the {what} tf chain{'s' if robot_from_tf and marker_from_tf else ''} "
            f"(moving tf chains: {sanitize_for_terminal(moving, 400)}); "
            + (f"give {listed}" if ways else f"name the frames (see {say['list']})")
        )
    robot, marker = ways[0]
    needed = (["base_frame", "tool_frame"] if robot is not None else []) + (
        ["tracker_frame", "marker_frame"] if marker is not None else []
    )
    given = all(frames[k] for k in needed)
    picked = []
    if robot is not None:
        picked.append(f"robot {robot[0]} -> {robot[1]}")
    if marker is not None:
        picked.append(f"marker {marker[0]} -> {marker[1]}")
    sentence = None
    if not given:
        sentence = f"picked the tf chains {' and '.join(picked)} ({how}; {flags(robot, marker)})"
    return robot, marker, sentence


def _marker_from_topic(
    reader, path: Path, topic: str, msgtype: str, tracker_frame, marker_frame, notes: list[str]
):
    """Times (K,) ns, ``tracker_from_marker`` (K, 4, 4) mm (NaN where the marker was not seen:
    a translation of three NaN), the source entry; invalid or misordered messages dropped."""
    times, translations, quaternions, sources, frames = [], [], [], [], set()
    for _, index, _, message in _messages(reader, path, [topic]):
        with _layout(path, topic, index, msgtype):
            times.append(_stamp_ns(message.header))
            parent = _frame(message.header.frame_id)
            if msgtype in POSE_TYPES:
                p, r = message.pose.position, message.pose.orientation
                child = marker_frame or ""
            else:
                p, r = message.transform.translation, message.transform.rotation
                child = _frame(message.child_frame_id)
            translations.append((float(p.x), float(p.y), float(p.z)))
            quaternions.append((float(r.x), float(r.y), float(r.z), float(r.w)))
        sources.append((topic, index))
        if (parent, child) not in frames:
            frames.add((parent, child))
            if tracker_frame and parent != tracker_frame:
                raise InvalidInputError(
                    f"{path}: {topic} is in frame {quoted(parent)} (message {index}), "
                    f"not the tracker frame {quoted(tracker_frame)}"
                )
            if marker_frame and msgtype in TRANSFORM_TYPES and child != marker_frame:
                raise InvalidInputError(
                    f"{path}: {topic} has child frame {quoted(child)} (message {index}), "
                    f"not the marker frame {quoted(marker_frame)}"
                )
            if len(frames) > 1:
                pairs = [f"{a} -> {b}" if b else a for a, b in sorted(frames)]
                raise InvalidInputError(
                    f"{path}: {topic} changes frames at message {index} ({_listing(pairs)}); "
                    "one stream must keep one tracker and marker frame"
                )
    if not times:
        raise InvalidInputError(f"{path}: topic {topic} has no messages")
    translation_array = np.array(translations, dtype=float).reshape(-1, 3)
    quaternion_array = np.array(quaternions, dtype=float).reshape(-1, 4)
    problems = _pose_problems(translation_array, quaternion_array, unseen_ok=True)
    keep = _usable(times, problems, sources, f"{path}: {topic}", notes)
    translation_array, quaternion_array = translation_array[keep], quaternion_array[keep]
    seen = np.all(np.isfinite(translation_array), axis=1)
    stack = np.full((len(keep), 4, 4), np.nan)
    if seen.any():
        stack[seen] = transform_from_ros(translation_array[seen], quaternion_array[seen], f"{path}: {topic}")
    ((parent, child),) = frames
    return (
        np.array(times, dtype=np.int64)[keep],
        stack,
        {"topic": topic, "tracker_frame": parent, "marker_frame": child},
    )


def _joint_columns(names: Sequence[str], wanted: Sequence[str], where: str) -> list[int]:
    columns = []
    for joint in wanted:
        matches = [k for k, n in enumerate(names) if n == joint or n.endswith(joint)]
        if len(matches) != 1:
            raise InvalidInputError(
                f"{where}: joint {quoted(joint)} found {len(matches)} times in the names {_listing(names)}"
            )
        columns.append(matches[0])
    return columns


def _robot_from_joint_states(
    reader, path: Path, topic: str, model: RobotModel, joint_names, notes: list[str]
):
    """Times (K,) ns, joints (K, 6) rad, ``base_from_tcp`` (K, 4, 4) mm, the source entry;
    invalid or misordered messages dropped."""
    where = f"{path}: {topic}"
    times, log_times, joints, sources = [], [], [], []
    problems: list[str | None] = []
    columns, names_seen = None, None
    for _, index, log_ns, message in _messages(reader, path, [topic]):
        with _layout(path, topic, index, "sensor_msgs/msg/JointState"):
            names = [str(n) for n in message.name]
            if names != names_seen:
                columns, names_seen = _joint_columns(names, joint_names, f"{where} (message {index})"), names
            positions = np.asarray(message.position, dtype=float).reshape(-1)
            if len(positions) != len(names):
                raise InvalidInputError(
                    f"{where}: message {index} has {len(positions)} positions for {len(names)} names"
                )
            times.append(_stamp_ns(message.header))
        log_times.append(log_ns)
        values = positions[columns]
        joints.append(values)
        sources.append((topic, index))
        if not np.all(np.isfinite(values)):
            problems.append("a joint position that is not a finite number")
        elif np.max(np.abs(values)) > MAX_JOINT_RAD:
            problems.append(f"a joint position of {np.max(np.abs(values)):.3g} rad")
        else:
            problems.append(None)
    if not times:
        raise InvalidInputError(f"{where}: no messages")
    source = "header.stamp"
    if 0 in times:
        times, source = log_times, "bag receive time (header stamps are zero)"
    keep = _usable(times, problems, sources, where, notes)
    joint_array = np.array(joints, dtype=float).reshape(-1, 6)[keep]
    return (
        np.array(times, dtype=np.int64)[keep],
        joint_array,
        forward_kinematics(model, joint_array),
        {"topic": topic, "model": model.name, "time": source},
    )


def _sorted_unique(times_ns, *arrays):
    order = np.argsort(times_ns, kind="stable")
    times_ns = times_ns[order]
    keep = np.concatenate([[True], np.diff(times_ns) > 0])
    return (times_ns[keep],) + tuple(a[order][keep] for a in arrays)


def read_ros_bag(
    path: str | Path,
    *,
    base_frame: str | None = None,
    tool_frame: str | None = None,
    tracker_frame: str | None = None,
    marker_frame: str | None = None,
    joint_state_topic: str | None = None,
    marker_topic: str | None = None,
    robot_model: RobotModel | str | None = None,
    joint_names: Sequence[str] = UR_JOINT_NAMES,
    typestore: str | None = None,
    metadata: dict | None = None,
    option_names: dict[str, str] | None = None,
) -> RawRecording:
    """Read the robot and tracker streams of a ROS bag into a raw two-stream recording.

    Parameters
    ----------
    path : str or Path
        A ROS 1 ``.bag``, a ROS 2 bag directory, or a bare ``.db3`` / ``.mcap`` file.
    base_frame, tool_frame : str, optional
        Robot pose from tf: ``base_from_tcp`` = the chain ``base_frame <- tool_frame``.
    tracker_frame, marker_frame : str, optional
        Marker pose from tf (``tracker_frame <- marker_frame``); with a marker topic they are
        checked against its ``header.frame_id`` / ``child_frame_id``.
    joint_state_topic : str, optional
        Robot pose from this JointState topic through ``robot_model``'s forward kinematics.
    marker_topic : str, optional
        Marker pose from this PoseStamped or TransformStamped topic.
    robot_model : RobotModel or str, optional
        For joint states: a model, or a robot kind's name
        (:func:`~spacecal.models.robot_kinds.robot_kind`; tool offset identity).
    joint_names : sequence of str
        The six joint names in kinematic order (matched exactly or as a name's suffix).
    typestore : str, optional
        rosbags type store for bags without message definitions (``ros1_noetic``, ``ros2_humble``...).
    metadata : dict, optional
        Merged into the recording's metadata (e.g. the marker geometry, the robot).
    option_names : dict, optional
        How the messages name the arguments (keys of :data:`PYTHON_NAMES`), e.g. a command
        line's flags.

    Returns
    -------
    RawRecording
        Robot stream (R samples, header-stamp times, ``joints_rad`` NaN when read from tf) and
        tracker stream (T frames, ``marker_rms_mm`` NaN: ROS messages do not carry it); times in
        s since the earliest stamp used; lengths in mm. ``metadata["ros_bag"]["picked"]`` says
        which tf chains were picked when they were not all named (else None); ``["notes"]`` lists,
        one line per stream, the messages skipped: invalid ones (a NaN or infinite value other
        than a marker not seen, a translation beyond :data:`MAX_TRANSLATION_M`, a quaternion
        that is not a unit quaternion, a joint beyond :data:`MAX_JOINT_RAD`, a stamp that is no
        time), those out of time order, and those repeating a stamp.

    Raises
    ------
    InvalidInputError
        An unreadable or damaged bag, a missing or ambiguous stream (the message lists the
        candidates), an undecodable message type or message, a frame that is not in the bag, a
        stream whose invalid and out-of-order messages exceed :data:`MAX_UNUSABLE_FRACTION`,
        a topic of more than :data:`MAX_TOPIC_MESSAGES` messages. Each names the bag, the topic
        and the index of the first message at fault.
    MissingExtraError
        Without the ``rosbags`` package (``spacecal[ros]``).
    """
    path = Path(path)
    contents = list_bag_contents(path, typestore)
    where = str(path)
    types = {t.name: t.msgtype for t in contents.topics}
    tf_topics = contents.topics_of(TF_TYPES)
    if isinstance(robot_model, str):
        robot_model = robot_kind(robot_model).model()
    say = {**PYTHON_NAMES, **(option_names or {})}

    # marker stream
    if marker_topic is None and not (tracker_frame and marker_frame) and contents.marker_topics:
        marker_topic = _one(contents.marker_topics, "marker topic", f"give {say['marker_topic']}", where)
    if marker_topic is not None and types.get(marker_topic) not in MARKER_TYPES:
        found = types.get(marker_topic, "absent")
        raise InvalidInputError(
            f"{where}: marker topic {marker_topic} is {found}; expected PoseStamped or TransformStamped"
        )

    # robot stream: joint states (with a model), or a tf chain
    if joint_state_topic is None and not (base_frame and tool_frame):
        if robot_model is not None and contents.joint_state_topics:
            joint_state_topic = _one(
                contents.joint_state_topics,
                "joint state topic",
                f"give {say['joint_state_topic']}",
                where,
            )
        elif contents.joint_state_topics and not contents.tf_chains():
            raise InvalidInputError(
                f"{where}: no moving tf chain for the robot, whose pose then needs a JointState topic "
                f"and a robot model; give {say['joint_state_topic']} "
                f"(JointState topics: {_listing(contents.joint_state_topics)}) and {say['robot_model']}"
            )
    picked = None
    robot_from_tf = joint_state_topic is None
    marker_from_tf = marker_topic is None
    if robot_from_tf or marker_from_tf:
        _refuse_tf_cycle(((e.parent, e.child) for e in contents.tf_edges), where)
        frames = {
            "base_frame": base_frame,
            "tool_frame": tool_frame,
            "tracker_frame": tracker_frame,
            "marker_frame": marker_frame,
        }
        robot_chain, marker_chain, picked = _choose_tf_chains(
            contents.tf_chains(), robot_from_tf, marker_from_tf, frames, say, where
        )
        if robot_chain is not None:
            base_frame, tool_frame = robot_chain
        if marker_chain is not None:
            tracker_frame, marker_frame = marker_chain
    if joint_state_topic is not None:
        if types.get(joint_state_topic) not in JOINT_STATE_TYPES:
            raise InvalidInputError(
                f"{where}: {joint_state_topic} is {types.get(joint_state_topic, 'absent')}, not JointState"
            )
        if robot_model is None:
            raise InvalidInputError(
                f"{where}: joint states need a robot model ({_option(say, 'robot_model', 'UR10')})"
            )

    notes: list[str] = []
    with _open_bag(path, typestore) as reader:
        tf = _read_tf(reader, path, tf_topics) if tf_topics else {}
        if marker_topic is not None:
            tracker_ns, tracker_from_marker, marker_source = _marker_from_topic(
                reader, path, marker_topic, types[marker_topic], tracker_frame, marker_frame, notes
            )
        else:
            assert tracker_frame is not None and marker_frame is not None  # chosen above
            tracker_ns, tracker_from_marker = _chain(tf, tracker_frame, marker_frame, where, notes)
            marker_source = {"tf": True, "tracker_frame": tracker_frame, "marker_frame": marker_frame}
        if joint_state_topic is not None:
            assert robot_model is not None  # checked above
            robot_ns, joints, base_from_tcp, robot_source = _robot_from_joint_states(
                reader, path, joint_state_topic, robot_model, joint_names, notes
            )
        else:
            assert base_frame is not None and tool_frame is not None  # chosen above
            robot_ns, base_from_tcp = _chain(tf, base_frame, tool_frame, where, notes)
            joints = np.full((len(robot_ns), 6), np.nan)
            robot_source = {"tf": True, "base_frame": base_frame, "tool_frame": tool_frame}

    robot_ns, joints, base_from_tcp = _sorted_unique(robot_ns, joints, base_from_tcp)
    tracker_ns, tracker_from_marker = _sorted_unique(tracker_ns, tracker_from_marker)
    for label, count in (("robot", len(robot_ns)), ("tracker", len(tracker_ns))):
        if count < 10:
            raise InvalidInputError(
                f"{where}: the {label} stream has {count} samples; at least 10 are needed"
            )
    origin_ns = int(min(robot_ns[0], tracker_ns[0]))
    info = {
        "ros_bag": {
            "path": str(path),
            "time_origin_ns": origin_ns,
            "time": "seconds since time_origin_ns (header stamps)",
            "robot": robot_source,
            "marker": marker_source,
            "picked": picked,
            "notes": notes,
        },
        "units": {"length": "mm", "angle": "rad", "time": "s"},
    }
    if robot_model is not None:
        info["robot"] = {
            "model": robot_model.name,
            "flange_from_tcp": robot_model.flange_from_tcp.tolist(),
            "controller_hz": robot_model.controller_hz,
        }
    return RawRecording(
        robot_time_s=(robot_ns - origin_ns) * 1e-9,
        robot_segment=np.array([ROBOT_SEGMENT] * len(robot_ns)),
        joints_rad=joints,
        base_from_tcp_stack=base_from_tcp,
        tracker_time_s=(tracker_ns - origin_ns) * 1e-9,
        tracker_from_marker_stack=tracker_from_marker,
        marker_rms_mm=np.full(len(tracker_ns), np.nan),
        metadata={**info, **(metadata or {})},
    )
