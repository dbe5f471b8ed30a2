"""Every app command returns one shape, :class:`spacecal.app.CommandResult`; the command line
stays thin (under 700 lines) and imports only the app layer (its import-linter contract)."""

import ast
import inspect
import types
from pathlib import Path

import pytest

from spacecal import app
from spacecal.app.result import CommandResult, Quality

SRC = Path(app.__file__).resolve().parent
CLI = SRC.parent / "cli"
ROOT = Path(__file__).resolve().parents[2]  # the clone (the package may be installed elsewhere)


def _annotation(value) -> str:
    return value if isinstance(value, str) else getattr(value, "__name__", str(value))


def _commands(namespace) -> dict:
    """The public functions of ``namespace`` whose first parameter is a command's settings."""
    found = {}
    for name in getattr(namespace, "__all__", dir(namespace)):
        function = getattr(namespace, name)
        if inspect.isfunction(function) and not name.startswith("_"):
            parameters = list(inspect.signature(function).parameters.values())
            if parameters and _annotation(parameters[0].annotation).endswith("Settings"):
                found[name] = function
    return found


def _not_the_one_shape(commands: dict) -> list[str]:
    return [
        name
        for name, function in commands.items()
        if not _annotation(inspect.signature(function).return_annotation).startswith("CommandResult[")
    ]


def test_every_app_command_returns_a_command_result():
    commands = _commands(app)
    # the scan finds every command the command line runs (scenario takes a preset's name)
    assert set(commands.values()) >= set(app.COMMANDS.values()) - {app.scenario}
    assert _not_the_one_shape(commands) == []
    assert _not_the_one_shape(app.COMMANDS) == []


def test_the_scan_catches_a_command_returning_a_tuple():
    planted = types.SimpleNamespace()

    def plan(settings: "PlanSettings") -> "tuple[PlanRecord, Path | None]": ...  # noqa: F821

    def pivot(settings: "PivotSettings") -> "CommandResult[PivotResult]": ...  # noqa: F821

    def helper(text: str) -> int: ...

    planted.plan, planted.pivot, planted.helper = plan, pivot, helper
    assert set(_commands(planted)) == {"plan", "pivot"}
    assert _not_the_one_shape(_commands(planted)) == ["plan"]


def test_a_result_that_did_not_pass_exits_1():
    assert CommandResult(record=None).exit_code == 0
    judged = CommandResult(record=None, quality=Quality(False, "unusable", "calibration unusable"))
    assert not judged.passed and judged.exit_code == 1
    with pytest.raises(AttributeError):
        judged.record = 1  # frozen


def test_doctor_s_pure_result_from_findings():
    from spacecal.core.ports import FINDING_OK, FINDING_PROBLEM, DeviceFinding

    fine = app.doctor_result([("robot", DeviceFinding(FINDING_OK, "mode", "remote control"))])
    assert fine.passed and fine.lines[-1] == "every check passed: spacecal acquire can start"
    bad = app.doctor_result([("tracker", DeviceFinding(FINDING_PROBLEM, "tool", "not seen"))])
    assert not bad.passed and bad.quality is not None and "1 problem found" in bad.quality.failure


def test_the_command_line_stays_thin():
    lines = sum(len(path.read_text(encoding="utf-8").splitlines()) for path in CLI.glob("*.py"))
    assert lines < 700, lines


def test_the_command_line_imports_only_the_app_layer():
    """Also checked by import-linter's contract in pyproject.toml (tests/test_layers.py): here
    without it, by the imports written in the command line's files."""
    allowed = ("spacecal", "spacecal.app", "spacecal.cli", "spacecal.core", "spacecal.station")
    for path in CLI.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = []
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            for name in names:
                if name.startswith("spacecal"):
                    assert (
                        name == "spacecal"
                        or name.startswith(tuple(a + "." for a in allowed))
                        or (name in allowed)
                    ), (path.name, name)


def test_the_contract_is_declared():
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    assert 'source_modules = ["spacecal.cli"]' in text
