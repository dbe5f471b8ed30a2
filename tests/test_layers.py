"""The package's layers (CONVENTIONS §4): each module imports only from layers below it."""

from pathlib import Path

import pytest

importlinter_cli = pytest.importorskip("importlinter.cli")


def test_layer_contract_is_kept(monkeypatch):
    monkeypatch.chdir(Path(__file__).resolve().parents[1])
    assert importlinter_cli.lint_imports() == 0
