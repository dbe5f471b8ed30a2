"""The ``spacecal`` command line: parse, call one app function, print.

Every default comes from the app's settings dataclasses, so none is written twice. Exit
codes: 0 success; 1 a known error, printed as one line (``--debug`` shows the traceback);
2 a usage error.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import warnings
from collections.abc import Callable
from typing import Any, TypeVar

from spacecal import app
from spacecal.cli import parser
from spacecal.core import interrupts
from spacecal.core.errors import InvalidInputError, MissingExtraError, SpacecalError
from spacecal.core.strict_numbers import parse_float
from spacecal.core.text import sanitize_for_terminal

S = TypeVar("S")

#: Longest error, note or finding line printed (text from files and devices is cut there).
ERROR_CHARS = 2000


class CheckFailed(SpacecalError):
    """A calibration check did not pass (exit code 1, like any known failure)."""


def _numbers(text: str, count: int, option: str, what: str) -> Any:
    try:
        values = tuple(parse_float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count:
        raise InvalidInputError(f"{option} takes {what}, got {text!r}")
    return values


def _optional(name: str, count: int, option: str, what: str) -> Callable[[argparse.Namespace], Any]:
    return lambda a: _numbers(getattr(a, name), count, option, what) if getattr(a, name) else None


def _time_offset(text: str) -> float | None:
    return None if text == "estimate" else _numbers(text, 1, "--time-offset-ms", "a number or 'estimate'")[0]


def _tool(a: argparse.Namespace) -> Any:
    """``--tool controller`` (None) or X,Y,Z,RX,RY,RZ; ``--tool-offset-mm X,Y,Z`` is X,Y,Z,0,0,0."""
    if a.tool is not None and a.tool_offset_mm is not None:
        raise InvalidInputError("give --tool or --tool-offset-mm, not both")
    if a.tool_offset_mm is not None:
        return (*_numbers(a.tool_offset_mm, 3, "--tool-offset-mm", "x,y,z in mm"), 0.0, 0.0, 0.0)
    if a.tool is None or a.tool.strip().lower() == "controller":
        return None
    return _numbers(a.tool, 6, "--tool", "controller or X,Y,Z,RX,RY,RZ (mm, rotation vector in rad)")


#: Options whose text becomes a settings value, by destination, in the order they are checked.
CONVERSIONS: dict[str, Callable[[argparse.Namespace], Any]] = {
    "time_offset_ms": lambda a: _time_offset(a.time_offset_ms),
    "targets_in_base": lambda a: tuple(
        _numbers(t, 3, "--target", "x,y,z in mm") for t in a.targets_in_base or []
    ),
    "error_thresholds": lambda a: (
        app.ErrorThresholds.parse(a.error_thresholds) if a.error_thresholds else None
    ),
    "site_mm": _optional("site_mm", 3, "--site", "x,y,z in mm"),
    "needle_path_mm": _optional("needle_path_mm", 6, "--needle-path", "entry x,y,z and target x,y,z in mm"),
    "rom": lambda a: tuple(a.rom or ()),
    "tool": _tool,
    "workspace_box": _optional("workspace_box", 6, "--workspace-box", "xmin,xmax,ymin,ymax,zmin,zmax in mm"),
}


def _converted(a: argparse.Namespace) -> argparse.Namespace:
    """The parsed arguments with every option's text turned into its settings value."""
    values = dict(vars(a))
    values.update({name: convert(a) for name, convert in CONVERSIONS.items() if name in values})
    return argparse.Namespace(**values)


def settings(cls: type[S], a: argparse.Namespace) -> S:
    """Settings of class ``cls`` from parsed arguments: each field from the option of its name
    (``--tracker-rate-hz`` gives ``tracker_rate_hz``), a nested settings field (the devices)
    from the same options; a field no option names keeps its default."""
    values: dict[str, Any] = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.default_factory is not dataclasses.MISSING and dataclasses.is_dataclass(f.default_factory()):
            values[f.name] = settings(type(f.default_factory()), a)
        elif hasattr(a, f.name):
            values[f.name] = getattr(a, f.name)
    return cls(**values)


def _progress(total_moves: int):
    """A one-line progress display on stderr: bar, move, samples, markers seen."""
    tty = sys.stderr.isatty()

    def show(samples: int, visible: int, move_index: int, label: str) -> None:
        if samples % (10 if tty else 100):
            return
        done = int(30 * (move_index + 1) / max(1, total_moves))
        print(
            f"[{'#' * done}{'.' * (30 - done)}] move {move_index + 1}/{total_moves} "
            f"{sanitize_for_terminal(label, 40):8s} samples "  # a plan file names the moves
            f"{samples} (marker seen {visible})",
            end="\r" if tty else "\n",
            file=sys.stderr,
            flush=True,
        )

    return show


def _acquire(a: argparse.Namespace) -> app.CommandResult:
    holder: dict[str, int] = {}
    return app.acquire(
        settings(app.AcquireSettings, a),
        on_sample=lambda *sample: _progress(holder.get("moves", 1))(*sample),
        on_plan=lambda moves: holder.update(moves=moves),
        on_line=lambda line: print(line, flush=True),
    )


def _station(a: argparse.Namespace) -> None:
    try:
        from spacecal.station.server import StationOptions, serve
    except ImportError as exc:
        raise MissingExtraError(
            "spacecal station needs the station extra: pip install 'spacecal[station]'"
        ) from exc
    serve(settings(StationOptions, a))


def _calling(name: str) -> Callable[[argparse.Namespace], app.CommandResult]:
    """Command ``name``: its app function (looked up at each call) called with its settings."""
    function = app.COMMANDS[name].__name__
    return lambda a: getattr(app, function)(*(settings(c, a) for c in parser.settings_classes(name)))


#: Each command and what runs it; each returns the app's result (the station serves instead).
COMMANDS: dict[str, Callable[[argparse.Namespace], app.CommandResult | None]] = {
    **{name: _calling(name) for name in app.COMMANDS},
    "acquire": _acquire,
    "touch": lambda a: app.touch(settings(app.TouchCommandSettings, a), on_line=print),
    "scenario": lambda a: app.scenario(a.preset),
    "station": _station,
}


def _run(a: argparse.Namespace) -> None:
    """Run the command, print its lines; a result that does not pass exits 1 with its line."""
    result = a.run(_converted(a))
    if result is None:
        return
    for line in result.lines:
        print(line)
    if result.quality is not None and not result.quality.passed:
        raise CheckFailed(result.quality.failure)


def build_parser() -> argparse.ArgumentParser:
    """The ``spacecal`` argument parser."""
    return parser.build_parser(COMMANDS)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``spacecal`` console script.

    Exit codes: 0 success; 1 a known error, an interruption (Ctrl-C, SIGTERM, SIGHUP) or an
    internal error, each printed as one line (``--debug`` shows the traceback); 2 a usage
    error (argparse's message: an unknown option, a missing value, a value that does not
    parse as the option's type).
    """
    args = build_parser().parse_args(parser.join_negative_coordinates(sys.argv[1:] if argv is None else argv))
    try:
        with interrupts.signals_as_interrupts(), warnings.catch_warnings():
            if not args.debug:
                # the one-line error says what went wrong; library warnings (numpy's overflow
                # notes, an empty file) would only add lines to it
                warnings.simplefilter("ignore")
            _run(args)
    except (Exception, KeyboardInterrupt) as exc:
        if args.debug:
            raise
        print(f"spacecal: {_error_line(exc)}", file=sys.stderr)
        return 1
    return 0


def _error_line(exc: BaseException) -> str:
    """What a failure prints after ``spacecal:``, one line."""
    if isinstance(exc, (SpacecalError, OSError)):
        return f"error: {interrupts.signal_named(exc, _one_line(exc))}"
    if isinstance(exc, KeyboardInterrupt):
        what = exc.args[0] if isinstance(exc, interrupts.StopRequested) and exc.args else "Ctrl-C"
        # the same words as an interruption the acquisition catches itself
        who = "interrupted by the user" if what == "Ctrl-C" else "interrupted"
        return f"error: {who} ({what}); every file written is complete"
    if isinstance(exc, RecursionError):
        return "error: input nested too deeply"
    reported = "(please report it; --debug shows the traceback)"
    return f"internal error: {type(exc).__name__}: {_one_line(exc)} {reported}"


def _one_line(exc: BaseException) -> str:
    """The error as one bounded line whose control characters are escaped (a message may quote
    names from files, bags and devices)."""
    return sanitize_for_terminal(" ".join(str(exc).split()), ERROR_CHARS) or type(exc).__name__


def console_main() -> None:
    """The console script: :func:`main`, then the exit; at once, without the interpreter's
    teardown, when a robot library left threads running (see ``app.end_programs_left_running``)."""
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    if app.end_programs_left_running():
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":
    console_main()
