"""Figures say what they show: a figure's format is its name's extension, the noise sweep's axis does not
zoom a small change into a collapse (and its lines stay visible), a prediction's colours fade where it is
unsure, and the pad's touches are marked."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lesscli.io.predictions import PredictionSet, ScanPrediction, save_predictions
from lesscli.plots import sweeps
from lesscli.plots.palette import CLASS_RGBA

LOG = [{"epoch": e, "train_loss": 1.0 / e, "val_loss": 1.2 / e, "seconds": 0.1} for e in range(1, 6)]


@pytest.fixture
def log_file(tmp_path):
    path = tmp_path / "run.log.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in LOG))
    return path


@pytest.mark.parametrize("name, magic", [("c.png", b"\x89PNG"), ("c.pdf", b"%PDF"), ("c.svg", b"<?xml"),
                                         ("C.SVG", b"<?xml")])
def test_plot_log_writes_the_format_its_extension_names(run_less, tmp_path, log_file, name, magic):
    proc = run_less("plot", "log", log_file.name, "-o", name, "--format", "jsonl")
    assert proc.returncode == 0, proc.stderr.decode()
    data = (tmp_path / name).read_bytes()
    assert data.startswith(magic)
    if magic == b"<?xml":
        assert b"<svg" in data[:2000]


def test_a_figure_of_another_extension_is_a_usage_error(run_less, tmp_path, log_file):
    proc = run_less("plot", "log", log_file.name, "-o", "c.jpg")
    assert proc.returncode == 2 and b"'c.jpg': a figure is written as .png, .pdf or .svg" in proc.stderr
    assert not (tmp_path / "c.jpg").exists()


def test_vector_figures_of_the_same_data_are_the_same_bytes(tmp_path, log_file):
    from lesscli.plots.curves import plot_logs

    for name in ("a.pdf", "b.pdf", "a.svg", "b.svg"):
        plot_logs([str(log_file)], str(tmp_path / name))
    assert (tmp_path / "a.pdf").read_bytes() == (tmp_path / "b.pdf").read_bytes()
    assert (tmp_path / "a.svg").read_bytes() == (tmp_path / "b.svg").read_bytes()


def _noise_axes(monkeypatch, rows, metric="f1_micro"):
    """The axes the noise figure draws (the file is not written)."""
    drawn = []
    monkeypatch.setattr(sweeps, "save_figure", lambda fig, path, dpi=None: drawn.append(fig))
    sweeps.noise_figure(rows, "unused.png", metric)
    return drawn[0].axes[0]


ROWS = [{"pos_mm": p, "ang_rad": a, "f1_micro": 0.62 - 0.01 * p, "f1_micro_std": 0.005,
         "com_error_mm": 1.0 + p, "com_error_mm_std": 0.1} for p in (0, 1, 2) for a in (0, 0.05, 0.1)]


def test_the_noise_sweep_shows_f1_on_its_full_axis_and_keeps_coinciding_lines_apart(monkeypatch):
    ax = _noise_axes(monkeypatch, ROWS)
    assert ax.get_ylim() == (0.0, 100.0)              # a 2-point fall reads as 2 points, not a collapse
    lines = [line for line in ax.get_lines() if line.get_linestyle() not in ("None", "none")]   # not the caps
    assert len(lines) == 3                            # one line per angle level (their y values coincide)
    firsts = sorted(float(line.get_xdata()[0]) for line in lines)
    assert firsts[0] < firsts[1] < firsts[2]          # ... shifted apart along x
    assert len({line.get_marker() for line in lines}) == 3 and len({line.get_linestyle()
                                                                    for line in lines}) == 3
    ax = _noise_axes(monkeypatch, ROWS, "com_error_mm")
    assert ax.get_ylim()[0] == 0.0 and ax.get_ylim()[1] >= 3.1


def _scan(probs: np.ndarray, touches=None) -> ScanPrediction:
    return ScanPrediction(probs.astype(np.float32), np.array([0.0, -15.5, -15.5]), np.ones(3),
                          insert="St12C13", steps=5, touch_xy_mm=touches)


def _prediction_panel(path):
    import matplotlib.image

    img = matplotlib.image.imread(str(path))[..., :3]
    return img[:, img.shape[1] // 3: 2 * img.shape[1] // 3]          # truth | prediction | uncertainty


def test_near_uniform_probabilities_are_drawn_faintly_and_confident_ones_in_full_colour(tmp_path):
    from lesscli.plots.render import scan_figure

    near_uniform = np.full((4, 1, 32, 32), 0.24)
    near_uniform[3] = 0.28                              # "inclusion" everywhere, barely above a guess
    certain = np.zeros((4, 1, 32, 32))
    certain[3] = 1.0
    faint = _prediction_panel(scan_figure(_scan(near_uniform), str(tmp_path / "u.png")))
    full = _prediction_panel(scan_figure(_scan(certain), str(tmp_path / "c.png")))
    red = np.asarray(CLASS_RGBA[3][:3])
    is_red = lambda img: float((np.abs(img - red).max(axis=-1) < 0.05).mean())
    assert is_red(full) > 0.2 and is_red(faint) < 0.005         # (the legend's patch only)
    assert _scan(near_uniform).confidence().max() < 0.06 and _scan(certain).confidence().min() == 1.0


def test_where_the_pad_touched_is_marked(tmp_path):
    from lesscli.plots.render import scan_figure

    probs = np.full((4, 1, 32, 32), 0.25)
    touches = np.array([[x, y] for x in np.linspace(-10, 10, 15) for y in (-4.0, 0.0, 4.0)], np.float32)
    plain = _prediction_panel(scan_figure(_scan(probs), str(tmp_path / "a.png")))
    marked = _prediction_panel(scan_figure(_scan(probs, touches), str(tmp_path / "b.png")))
    dark = lambda img: int((img.max(axis=-1) < 0.5).sum())
    assert dark(marked) > dark(plain) + 50


def test_predict_stores_where_the_pad_touched_and_render_draws_it(tmp_path, run_less):
    from factories import random_scanset
    from imaging_factory import save_tiny_imager

    from lesscli.io.predictions import load_predictions
    from lesscli.io.scans import save_scans

    save_tiny_imager(str(tmp_path / "im.pt"))
    scans = random_scanset(n_scans=1, traj_per_scan=3, max_len=10, seed=2)
    save_scans(str(tmp_path / "s.npz"), scans)
    assert run_less("image", "predict", "im.pt", "s.npz", "-o", "p.npz", "--steps", "2").returncode == 0
    preds = load_predictions(str(tmp_path / "p.npz")).scans
    assert [p.scan for p in preds] == [0, 0]
    assert 0 < len(preds[0].touch_xy_mm) <= len(preds[1].touch_xy_mm) <= scans.n_steps
    assert set(map(tuple, preds[1].touch_xy_mm.tolist())) <= set(map(tuple, scans.pose[:, :2].tolist()))
    save_predictions(str(tmp_path / "q.npz"), PredictionSet(preds))      # written back: the same touches
    again = load_predictions(str(tmp_path / "q.npz")).scans
    np.testing.assert_array_equal(again[1].touch_xy_mm, preds[1].touch_xy_mm)
    assert run_less("render", "p.npz", "-o", "figs").returncode == 0
