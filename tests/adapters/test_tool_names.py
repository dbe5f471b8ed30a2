"""The names the NDI adapter gives the tools after the marker (no tracker needed)."""

import pytest

from spacecal.adapters.ndi import further_tool_names
from spacecal.core.errors import InvalidInputError


def test_names_default_to_the_files_and_a_repeated_file_is_numbered():
    assert further_tool_names(["roms/pointer.rom", "guide.rom"]) == ("pointer", "guide")
    assert further_tool_names(["a/marker.rom", "b/marker.rom"]) == ("marker", "marker-2")
    assert further_tool_names(["x.rom"], ["reference"]) == ("reference",)


@pytest.mark.parametrize(
    "names, match",
    [(["a", "a"], "two tools are named 'a'"), (["a"], "1 tool name"), (["a", " "], "needs a name")],
)
def test_bad_names_are_one_line(names, match):
    with pytest.raises(InvalidInputError, match=match):
        further_tool_names(["p.rom", "q.rom"], names)
