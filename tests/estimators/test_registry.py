"""The method registry: one complete entry per method, and nobody else listing methods."""

import ast
import inspect
import re
from pathlib import Path

import pytest

from spacecal.cli import build_parser
from spacecal.core.errors import InvalidInputError, UnknownMethodError
from spacecal.estimators import ESTIMATORS, EstimatorSpec, Family, Need, calibrate, estimator
from spacecal.estimators.registry import estimators_of

ROOT = Path(__file__).resolve().parents[2]
REGISTRY = ROOT / "src" / "spacecal" / "estimators" / "registry.py"


@pytest.mark.parametrize("name", list(ESTIMATORS))
def test_every_entry_is_complete(name):
    spec = ESTIMATORS[name]
    assert isinstance(spec, EstimatorSpec) and spec.name == name
    assert isinstance(spec.family, Family) and callable(spec.solve)
    assert spec.summary.strip() and len(spec.summary.splitlines()) == 1
    assert spec.reference.strip()
    assert isinstance(spec.likelihood, bool) and spec.bootstrap is not spec.likelihood
    assert spec.held_out_refit == ("own" if spec.likelihood else "ML")
    assert all(isinstance(option, str) for option in spec.options)
    assert spec.needs and all(isinstance(need, Need) for need in spec.needs)
    closed = spec.family in (Family.ROBOT_WORLD, Family.HAND_EYE)
    assert (spec.closed_form is not None) == closed


@pytest.mark.parametrize("name", list(ESTIMATORS))
def test_declared_options_are_exactly_what_the_method_takes(name):
    # the registry no longer reads signatures at run time: here they check the declarations
    spec = ESTIMATORS[name]
    parameters = set(inspect.signature(spec.solve).parameters) - {"recording"}
    assert parameters - {"targets_in_base", "needle_tip"} == spec.options
    # a likelihood method predicts the TRE at the targets and states the error at a measured tip
    # itself; the others get both from the bootstrap
    assert ("targets_in_base" in parameters) == ("needle_tip" in parameters) == spec.likelihood


def test_an_entry_with_a_missing_field_or_a_stray_closed_form_is_refused():
    solve = ESTIMATORS["ml"].solve
    with pytest.raises(ValueError, match="reference"):
        EstimatorSpec("x", Family.LIKELIHOOD, solve, "a line", " ", likelihood=True)
    with pytest.raises(ValueError, match="closed form"):
        EstimatorSpec("x", Family.HAND_EYE, solve, "a line", "a paper", likelihood=False)
    with pytest.raises(ValueError, match="closed form"):
        EstimatorSpec(
            "x", Family.PAPER, solve, "a line", "a paper", likelihood=False, closed_form=lambda a, b: a
        )


def test_an_unknown_name_lists_the_valid_ones():
    with pytest.raises(UnknownMethodError) as raised:
        estimator("mll")
    assert all(name in str(raised.value) for name in ESTIMATORS)


def test_an_option_is_refused_by_the_methods_that_do_not_declare_it(white_simulation):
    takers = sorted(name for name, spec in ESTIMATORS.items() if "seed" in spec.options)
    assert takers == ["robust"]
    with pytest.raises(InvalidInputError, match=r"does not take seed \(methods that do: robust\)"):
        calibrate(white_simulation.recording, "shah", seed=3)


def test_families_select_the_closed_forms():
    closed = estimators_of(Family.ROBOT_WORLD, Family.HAND_EYE)
    assert set(closed) == {"shah", "li", "dornaika", "tsai", "park", "daniilidis"}
    assert all(not spec.likelihood for spec in closed.values())


@pytest.mark.parametrize("name", list(ESTIMATORS))
def test_the_likelihood_flag_is_what_the_result_reports(white_simulation, name):
    spec = ESTIMATORS[name]
    result = calibrate(white_simulation.recording, name)
    assert result.method == name
    note = result.covariance["note"]
    assert ("bootstrap" in note) == spec.bootstrap, note
    basis = result.expected_error.to_dict()["basis"]
    # a method that is not the ML fit is cross-validated by ML refits and its distance from ML
    assert ("distance from the ML solution" in basis) == (spec.held_out_refit == "ML"), basis


def _literal_method_names(node: ast.AST) -> set[str]:
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        items = node.elts
    elif isinstance(node, ast.Dict):
        items = [key for key in node.keys if key is not None]
    else:
        return set()
    return {e.value for e in items if isinstance(e, ast.Constant) and e.value in ESTIMATORS}


def _names_a_method(node: ast.AST) -> bool:
    text = node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else ""
    return "method" in text.lower()


def side_tables(path: Path) -> list[str]:
    """Collections of two or more method names, and comparisons of a method with a name."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        names = _literal_method_names(node)
        if len(names) >= 2:
            found.append(f"{path.name}:{node.lineno}: {sorted(names)}")
        if isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
            named = [o.value for o in operands if isinstance(o, ast.Constant) and o.value in ESTIMATORS]
            named += sorted(set().union(*(_literal_method_names(o) for o in operands)))
            if named and any(_names_a_method(o) for o in operands):
                found.append(f"{path.name}:{node.lineno}: method compared with {named}")
    return found


def test_the_scan_finds_a_side_table_and_a_comparison(tmp_path):
    planted = tmp_path / "planted.py"
    planted.write_text(
        'FAST = ("shah", "tsai")\nSLOW = {"ml": 1, "kinematic": 2}\n'
        'def f(method):\n    return method == "robust" or method in ("paper",)\n'
        'MOTIONS = ("paper", "stations")\n'
    )
    found = side_tables(planted)
    assert len(found) == 4 and not any(":5:" in line for line in found), found


def test_no_module_of_the_package_lists_methods_or_tells_them_apart_by_name():
    found = [
        line
        for path in sorted((ROOT / "src" / "spacecal").rglob("*.py"))
        if path != REGISTRY
        for line in side_tables(path)
    ]
    assert not found, "ask the registry entry (spacecal.estimators.ESTIMATORS) instead:\n" + "\n".join(found)


def test_the_cli_offers_exactly_the_registered_methods():
    parser = build_parser()
    commands = next(a for a in parser._actions if a.dest == "command")
    calibrate_command = commands.choices["calibrate"]
    option = next(a for a in calibrate_command._actions if "--method" in a.option_strings)
    offered = option.help.removeprefix("estimator: ").split(", ")
    assert offered == sorted(ESTIMATORS)


def test_the_methods_page_tables_exactly_the_registered_methods():
    text = (ROOT / "docs" / "methods.md").read_text()
    table = text[text.index("| name |") :].split("\n\n", 1)[0]
    rows = [line for line in table.splitlines()[2:] if line.startswith("|")]
    tabled = [name for row in rows for name in re.findall(r"`([a-z]+)`", row.split("|")[1])]
    assert sorted(tabled) == sorted(ESTIMATORS)
