"""The one shape every app command returns: :class:`CommandResult`.

A command's typed result (a calibration, a check, a plan, ...) travels with what a caller
needs beside it, the same for every command: whether the result passes its own bar, where it
came from, the files written, notes for a person, and the lines the command line prints. A
notebook reads ``result.record``; the command line prints ``result.lines`` and exits 1 when
``result.quality`` did not pass.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Generic, TypeVar

from spacecal.core.text import sanitize_for_terminal
from spacecal.records import Provenance

#: Covariant: a result is only read, so a command result of a subtype serves where a supertype is asked.
R = TypeVar("R", covariant=True)

#: Longest note line shown (text from files and devices is cut there).
NOTE_CHARS = 2000


@dataclass(frozen=True)
class Quality:
    """Whether a command's result passes its own bar (a calibration's verdict, a check's pass).

    Attributes
    ----------
    passed : bool
        False: the command did its work and wrote its files, but the result does not pass (the
        command line exits 1).
    summary : str
        One line naming the grade or the outcome, e.g. ``good: expected error 0.43 mm``.
    failure : str
        The one line the command line exits with when ``passed`` is False.
    """

    passed: bool
    summary: str
    failure: str = ""


@dataclass(frozen=True)
class CommandResult(Generic[R]):
    """What an app command returns.

    Attributes
    ----------
    record : R
        The command's typed result: a :class:`~spacecal.records.CalibrationResult`, a
        :class:`~spacecal.records.PlanRecord`, ... (see each command).
    files_written : tuple of Path
        Every file the command wrote, in the order written (empty when it wrote none).
    notes : tuple of str
        What a person should know about the result (a calibration that cannot be verified,
        skipped messages of a stream), each one line.
    lines : tuple of str
        The command's report as the command line prints it, one line each (notes included,
        names from files and devices already escaped for a terminal).
    quality : Quality or None
        Whether the result passes its own bar, where the command judges one.
    provenance : Provenance or None
        Where the result's data came from, where the command knows it.
    """

    record: R
    files_written: tuple[Path, ...] = ()
    notes: tuple[str, ...] = ()
    lines: tuple[str, ...] = ()
    quality: Quality | None = None
    provenance: Provenance | None = None

    @property
    def passed(self) -> bool:
        """False only when the command judged its result and it did not pass."""
        return self.quality is None or self.quality.passed

    @property
    def exit_code(self) -> int:
        """The command line's exit code for this result: 0, or 1 for a result that did not pass."""
        return 0 if self.passed else 1


def note_lines(notes: Iterable[str]) -> list[str]:
    """``note: ...`` lines of ``notes``, each escaped and cut for a terminal (notes quote names
    from files and devices)."""
    return [f"note: {sanitize_for_terminal(note, NOTE_CHARS)}" for note in notes]


def paths(*items: Path | str | None) -> tuple[Path, ...]:
    """The files written among ``items`` (None: not written), as paths."""
    return tuple(Path(item) for item in items if item is not None)
