"""Nothing outside ``tests/`` imports from it: the library, the benchmarks and the examples
import what they share with the tests from an installed spacecal (``spacecal.testing``)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: The folders that must not import from ``tests``.
FOLDERS = ("src", "benchmarks", "examples")


def _names_tests(name: str | None) -> bool:
    return name is not None and (name == "tests" or name.startswith("tests."))


def _imported_names(node: ast.AST) -> list[str | None]:
    """The modules an import statement, or a call of ``import_module``/``__import__`` with a
    literal name, imports (relative imports name nothing outside their own package)."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if isinstance(node, ast.ImportFrom):
        return [node.module] if node.level == 0 else []
    if isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
        function = node.func
        called = function.attr if isinstance(function, ast.Attribute) else getattr(function, "id", None)
        if called in ("import_module", "__import__") and isinstance(node.args[0].value, str):
            return [node.args[0].value]
    return []


def imports_from_tests(root: Path) -> list[str]:
    """``path:line`` of every import from the ``tests`` package in the folders under ``root``."""
    found = []
    for folder in FOLDERS:
        for path in sorted((root / folder).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
            for node in ast.walk(tree):
                if any(_names_tests(name) for name in _imported_names(node)):
                    found.append(f"{path.relative_to(root).as_posix()}:{node.lineno}")
    return found


def test_nothing_outside_the_tests_imports_from_them():
    assert (ROOT / "src" / "spacecal").is_dir() and (ROOT / "benchmarks").is_dir()
    assert imports_from_tests(ROOT) == []


@pytest.mark.parametrize(
    "planted",
    [
        "import tests",
        "import tests.fakes.client",
        "import numpy, tests.conftest as shared",
        "from tests.fuzz.harness import run_case",
        "from tests import conftest",
        "def later():\n    from tests.fakes.client import WorldProcess\n",
        "import importlib\nimportlib.import_module('tests.fakes.client')",
        "__import__('tests')",
    ],
)
@pytest.mark.parametrize("folder", FOLDERS)
def test_an_import_from_the_tests_is_found(tmp_path, folder, planted):
    for name in FOLDERS:
        (tmp_path / name).mkdir()
    (tmp_path / "src" / "clean.py").write_text("import testsuite\nfrom spacecal.testing import fakes\n")
    planted_file = tmp_path / folder / "deep" / "planted.py"
    planted_file.parent.mkdir()
    planted_file.write_text('"""A module."""\n\n' + planted + "\n")
    line = 3 + next(i for i, text in enumerate(planted.split("\n")) if "tests" in text)  # after the docstring
    assert imports_from_tests(tmp_path) == [f"{folder}/deep/planted.py:{line}"]


def test_names_that_only_begin_like_tests_are_not_imports_from_them(tmp_path):
    for name in FOLDERS:
        (tmp_path / name).mkdir()
    (tmp_path / "examples" / "fine.py").write_text(
        "import testsuite\nimport tests_of_mine\nfrom mypackage.tests import helper\nfrom . import tests\n"
    )
    assert imports_from_tests(tmp_path) == []
