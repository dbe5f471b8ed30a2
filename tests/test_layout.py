"""The README's layout is the package's: the folders it lists under ``src/spacecal/`` are the
package folders on disk, and ``tests/`` mirrors them."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "spacecal"
TESTS = ROOT / "tests"

#: Package folders whose tests have no folder of their own, and why.
TESTED_ELSEWHERE = {
    "cli": "the command line is tested end to end in tests/test_cli.py, beside the other "
    "whole-repository tests (the README's command, the layers, this layout)",
}
#: Folders of tests/ that mirror no package folder, and why.
NOT_A_PACKAGE = {
    "fuzz": "hostile inputs through every door at once (files, peers, names, the command line)",
    "igtl_reference": "the C++ OpenIGTLink reference sender and receiver the adapter tests build",
}


def layout_block() -> list[str]:
    """The lines of the first fenced block under ``## Layout`` in README.md."""
    text = (ROOT / "README.md").read_text()
    section = text.split("\n## Layout\n", 1)[1].split("\n## ", 1)[0]
    match = re.search(r"^```\n(.*?)^```", section, flags=re.S | re.M)
    assert match, "no fenced block under ## Layout"
    return match.group(1).splitlines()


def listed_package_folders(lines: list[str]) -> list[str]:
    """The ``name/`` entries indented under ``src/spacecal/``."""
    start = lines.index("src/spacecal/")
    names = []
    for line in lines[start + 1 :]:
        if not line.startswith(" "):
            break
        names.append(re.match(r"\s+(\S+)/(\s|$)", line).group(1))
    return names


def package_folders() -> set[str]:
    return {path.parent.name for path in PACKAGE.glob("*/__init__.py")}


def test_the_readme_lists_every_package_folder_and_no_other():
    listed = listed_package_folders(layout_block())
    assert len(listed) == len(set(listed)), listed
    assert set(listed) == package_folders(), (
        f"only in the README: {sorted(set(listed) - package_folders())}; "
        f"only on disk: {sorted(package_folders() - set(listed))}"
    )


def test_the_readme_lists_the_tests_and_the_benchmarks():
    top_level = {line.split()[0] for line in layout_block() if line and not line.startswith(" ")}
    assert {"src/spacecal/", "tests/", "benchmarks/"} <= top_level, top_level
    for folder in top_level:
        assert (ROOT / folder).is_dir(), folder


def test_the_tests_mirror_the_package():
    test_folders = {
        path.name for path in TESTS.iterdir() if path.is_dir() and not path.name.startswith((".", "_"))
    }
    without = package_folders() - test_folders - set(TESTED_ELSEWHERE)
    assert not without, f"package folders without a folder in tests/: {sorted(without)}"
    extra = test_folders - package_folders() - set(NOT_A_PACKAGE)
    assert not extra, f"folders in tests/ that mirror no package folder: {sorted(extra)}"
    # an exception stays honest: it names a folder that exists and that has no tests folder
    assert set(TESTED_ELSEWHERE) <= package_folders() - test_folders
    assert (TESTS / "test_cli.py").is_file()
    assert all((TESTS / name).is_dir() for name in NOT_A_PACKAGE)
