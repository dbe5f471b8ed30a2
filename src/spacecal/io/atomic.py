"""Atomic writes: every file spacecal writes goes through a temporary file in the same folder
and a rename, so an interrupted write (Ctrl-C, a full disk, a crash) leaves either the old
file or the new one, never half of one.

Permissions are those a plain ``open(path, "w")`` gives: a new file gets ``0o666`` less the
process's umask (the kernel applies it, as for any file created; ``tempfile.mkstemp`` would
make it ``0o600``, unreadable for 3D Slicer, PLUS or a ROS node running as another user), and
a file that is replaced keeps its permission bits.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import stat
from collections.abc import Iterator
from pathlib import Path

from spacecal.core.errors import InvalidInputError
from spacecal.core.text import quoted

#: Mode of a new file before the umask, as ``open()`` uses.
NEW_FILE_MODE = 0o666
#: Characters of the target's name kept in the temporary file's name (names have a length limit).
_NAME_CHARS = 80


def _create_temporary(path: Path) -> Path:
    """A new, empty file beside ``path``, created exclusively with :data:`NEW_FILE_MODE` (so the
    umask applies) or with the permission bits of the file it will replace."""
    try:
        keep_mode = stat.S_IMODE(os.stat(path).st_mode) if path.is_file() else None
    except OSError:
        keep_mode = None
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NOFOLLOW", 0)
    for _ in range(100):
        temporary = path.with_name(f".{path.name[:_NAME_CHARS]}.{secrets.token_hex(4)}.tmp{path.suffix}")
        try:
            handle = os.open(temporary, flags, NEW_FILE_MODE)
        except FileExistsError:
            continue
        try:
            if keep_mode is not None:
                os.fchmod(handle, keep_mode)
        finally:
            os.close(handle)
        return temporary
    raise FileExistsError(f"{path.parent}: cannot create a temporary file beside {path.name}")


def _check_file_name(path: str | Path) -> None:
    """One clear line for a name no file system can store (os.open would raise ValueError)."""
    try:
        encoded = os.fsencode(path)
    except UnicodeEncodeError:
        raise InvalidInputError(f"{quoted(os.fspath(path))}: not a file name this system can store") from None
    if b"\x00" in encoded:
        raise InvalidInputError(f"{quoted(os.fspath(path))}: a file name cannot hold a NUL character")


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` (same suffix, so writers that infer the format from it
    work) that replaces ``path`` when the block completes; removed if the block raises."""
    _check_file_name(path)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = _create_temporary(path)
    try:
        yield temporary
        with open(temporary, "rb") as stream:
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


def write_bytes_atomic(data: bytes, path: str | Path) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as temporary:
        temporary.write_bytes(data)
    return Path(path)


def write_text_atomic(text: str, path: str | Path) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns the path."""
    return write_bytes_atomic(text.encode("utf-8"), path)
