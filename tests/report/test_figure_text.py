"""Text from data in the PNG figures is drawn as the characters it holds: no mathtext parsing
(an unknown TeX command would raise), no label dropped for a leading underscore."""

import numpy as np
import pytest

from spacecal.report import figures

LABELS = [r"$\undefinedcommand{x}$", r"\undefinedcommand{x}", "$x^$", "a$b$c$", "_hidden", "rot_x"]


@pytest.fixture
def drawn(monkeypatch):
    """The figures a plot function makes, drawn and kept instead of closed."""
    made = []

    def keep(fig, path):
        fig.canvas.draw()  # tick labels and legend text are laid out (and parsed) here
        made.append(fig)
        return path

    monkeypatch.setattr(figures, "_save", keep)
    yield made
    figures._pyplot().close("all")


def test_segment_labels_are_legend_text_as_written(drawn, tmp_path):
    segment = np.repeat(LABELS, 5)
    time_s = np.arange(len(segment), dtype=float)
    figures.plot_residuals(
        time_s, np.full(len(segment), 0.2), tmp_path / "r.png", np.full(len(segment), 0.1), segment
    )
    (fig,) = drawn
    shown = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert shown == [" _hidden" if label == "_hidden" else label for label in LABELS]


def test_the_real_file_is_written_for_tex_labels(tmp_path):
    segment = np.repeat(LABELS, 3)
    path = figures.plot_residuals(
        np.arange(len(segment), dtype=float), np.ones(len(segment)), tmp_path / "r.png", segment=segment
    )
    assert path.read_bytes()[:4] == b"\x89PNG"
