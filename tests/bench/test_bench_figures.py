"""Figures of the benchmarks (``bench guide --plot``, ``bench sim --plot``): size, content rules, atomic
writes."""

from __future__ import annotations

import os

import pytest
from matplotlib.figure import Figure
from matplotlib.image import imread

from lesscli.errors import OutputError
from lesscli.plots.sweeps import ladder_figure, touches_figure

MEANS = {"guided": [(3, 0.1), (6, 0.5)], "raster": [(3, 0.2), (6, 0.4)]}
LADDER = [{"check": "sphere", "tier": "fem", "mesh_mm": 2.0, "error": 0.08, "ms_per_step": 40.0},
          {"check": "indentation", "tier": "green", "mesh_mm": 1.5, "error": 0.0, "ms_per_step": 3.0},
          {"check": "indentation", "tier": "winkler", "mesh_mm": None, "error": 0.2, "ms_per_step": 0.01}]


def test_touches_figure_is_550_by_400_pixels(tmp_path):
    touches_figure(str(tmp_path / "f1.png"), MEANS, "3 phantoms x 1 seeds")
    img = imread(str(tmp_path / "f1.png"))
    assert img.shape[:2] == (400, 550) and float(img[..., :3].std()) > 0.02
    assert os.listdir(tmp_path) == ["f1.png"]


def test_ladder_figure_is_drawn_at_120_dpi_and_leaves_out_the_reference(tmp_path, monkeypatch):
    points = []
    original = Figure.add_subplot

    def spy(fig, *args, **kwargs):
        ax = original(fig, *args, **kwargs)
        scatter = ax.scatter
        ax.scatter = lambda x, y, **kw: points.append((x, y)) or scatter(x, y, **kw)
        return ax

    monkeypatch.setattr(Figure, "add_subplot", spy)
    ladder_figure(LADDER, str(tmp_path / "ladder.png"))
    assert points == [(40.0, 0.08), (0.01, 0.2)]                  # error 0 (the reference) is not drawn
    assert imread(str(tmp_path / "ladder.png")).shape[:2] == (600, 840)


@pytest.mark.parametrize("draw", [lambda p: touches_figure(p, MEANS, ""), lambda p: ladder_figure(LADDER, p)])
def test_a_failed_figure_leaves_no_file(tmp_path, monkeypatch, draw):
    def half_written(fig, path, **kwargs):
        with open(path, "wb") as fh:
            fh.write(b"\x89PNG partial")
        raise OSError("disk full")

    monkeypatch.setattr(Figure, "savefig", half_written)
    with pytest.raises(OutputError, match=r"out.png: cannot write it \(disk full\); nothing was written"):
        # one line naming the figure, not a bare OSError
        draw(str(tmp_path / "out.png"))
    assert os.listdir(tmp_path) == []
