"""Property-based fuzzing of every command through the command line, in this process.

For each command and each class of mutation (encoding, types, numbers, consistency,
overwrite, arguments, valid variants) hypothesis draws cases, seeded (``derandomize``, no
database); each must exit 0, 1 or 2 with one line on stderr for an error, print no
traceback, write no NaN or Infinity, change no input file and finish within its time limit,
and valid variants of a recording must calibrate to the clean recording's result.
"""

from __future__ import annotations

import shutil

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from spacecal.testing.fuzz import COMMANDS, DrawPick, build_case, plan_cases, prepare, run_case

from .conftest import profile

PLAN = [(command, klass, count) for command, klass, count in plan_cases(profile()) if count > 0]


@pytest.fixture(scope="module")
def clean_calibration(fuzz_base, tmp_path_factory):
    """The calibration of the unmodified recording (what valid variants must reproduce)."""
    from spacecal.testing.fuzz import Case

    folder = tmp_path_factory.mktemp("clean") / "run"
    prepare(fuzz_base, folder)
    result = run_case(Case("calibrate", "valid", "clean", list(COMMANDS["calibrate"]["argv"]), "ok"), folder)
    assert result.outcome == "pass", result.detail
    return folder / "out.json"


@pytest.mark.parametrize(("command", "klass", "count"), PLAN, ids=[f"{c}-{k}" for c, k, _ in PLAN])
def test_command_survives_mutations(command, klass, count, fuzz_base, clean_calibration, tmp_path):
    @settings(
        max_examples=count,
        derandomize=True,
        database=None,
        deadline=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(data=st.data())
    def one_case(data):
        folder = tmp_path / "case"
        prepare(fuzz_base, folder)
        case = build_case(DrawPick(data), folder, command, klass, fast=profile() == "fast")
        result = run_case(case, folder, 20.0, clean_calibration)
        shutil.rmtree(folder, ignore_errors=True)
        assert result.outcome == "pass", (
            f"{result.outcome}: {case.label}\nargv: {case.argv}\nexit {result.code}\n{result.detail}"
        )

    one_case()
