"""Figures exist, are not blank, and show the classes and the uncertainty."""

import json

import numpy as np
import pytest
from factories import sphere_labels

from lesscli.io.predictions import PredictionSet, ScanPrediction, save_predictions
from lesscli.plots.palette import CLASS_RGBA
from lesscli.plots.render import compare_figure, group_scans, scan_figure, strip_figure

SHAPE, SPACING = (6, 32, 32), (2.0, 1.9, 1.9)


def _prediction(dim: int, steps: int = 10, noise: float = 0.5, seed: int = 0) -> ScanPrediction:
    truth = sphere_labels(center_mm=(-6.0, 2.0, -5.0), radius_mm=6.0, shape=SHAPE, spacing=SPACING).data
    origin = np.array([-(SHAPE[0] - 1) * SPACING[0], -(SHAPE[1] - 1) / 2 * SPACING[1],
                       -(SHAPE[2] - 1) / 2 * SPACING[2]])
    if dim == 2:
        truth, origin = truth[3:4], origin + [3 * SPACING[0], 0, 0]
    rng = np.random.default_rng(seed)
    logits = 3.0 * np.eye(4)[truth].transpose(3, 0, 1, 2) + noise * rng.normal(size=(4, *truth.shape))
    logits[:, :, :, 20:] = 0.0                               # an untouched strip: uniform probabilities
    probs = np.exp(logits) / np.exp(logits).sum(axis=0)
    return ScanPrediction(probs.astype(np.float32), origin, np.array(SPACING), truth=truth, insert="St12C13",
                          steps=steps)


def _read(path):
    import matplotlib.image

    return matplotlib.image.imread(path)[..., :3]


def _has_colour(img, rgba, tol=0.02):
    return bool((np.abs(img - np.asarray(rgba[:3])).max(axis=-1) < tol).any())


@pytest.mark.parametrize("dim", [2, 3])
def test_scan_figure_is_not_blank(tmp_path, dim):
    path = scan_figure(_prediction(dim), str(tmp_path / "f.png"), "title")
    img = _read(path)
    assert img.shape[0] > 200 and img.shape[1] > 600
    assert img.std() > 0.05
    assert _has_colour(img, CLASS_RGBA[3]) and _has_colour(img, CLASS_RGBA[1])
    if dim == 3:      # top view plus two slices: three rows, so a taller figure than 2D
        assert img.shape[0] > _read(scan_figure(_prediction(2), str(tmp_path / "g.png"))).shape[0] * 1.8


def test_strip_figure_shows_each_prefix(tmp_path):
    preds = [_prediction(3, steps=k, noise=2.0 / k, seed=k) for k in (1, 2, 4)]
    img = _read(strip_figure(preds, str(tmp_path / "s.png")))
    assert img.shape[1] > 4 * 250 and img.std() > 0.05 and _has_colour(img, CLASS_RGBA[3])


def test_group_scans_joins_rising_prefixes():
    preds = [_prediction(2, steps=k) for k in (1, 2, 3)] + [_prediction(2, steps=1)]
    assert group_scans(preds) == [[0, 1, 2], [3]]


def test_cli_render(tmp_path, run_less):
    preds = [_prediction(3, steps=k) for k in (5, 10)] + [_prediction(2, steps=7)]
    save_predictions(str(tmp_path / "p.npz"), PredictionSet(preds, {"dim": 3}))
    proc = run_less("render", "p.npz", "-o", "out", "--format", "jsonl")
    assert proc.returncode == 0, proc.stderr.decode()
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert [(r["scan"], r["kind"]) for r in rows] == [(0, "panels"), (0, "strip"), (1, "panels")]
    for r in rows:
        assert _read(str(tmp_path / r["figure"])).std() > 0.05
    proc = run_less("render", "p.npz", "-o", "out2", "--scan", "5")
    assert proc.returncode == 1 and b"scan 5" in proc.stderr and not (tmp_path / "out2").exists()


def test_compare_figure_has_a_column_per_model(tmp_path):
    preds = [_prediction(3, seed=k) for k in range(2)]
    one = _read(compare_figure(preds[:1], ["a"], str(tmp_path / "one.png")))
    two = _read(compare_figure(preds, ["a", "b"], str(tmp_path / "two.png")))
    assert two.shape[1] > one.shape[1] * 1.3 and two.std() > 0.05 and _has_colour(two, CLASS_RGBA[3])


def test_cli_render_compares_files_of_the_same_scans(tmp_path, run_less):
    for name, seed in (("a", 0), ("b", 1)):
        preds = [_prediction(3, steps=k, seed=seed) for k in (5, 10)] + [_prediction(2, steps=7, seed=seed)]
        save_predictions(str(tmp_path / f"{name}.npz"), PredictionSet(preds, {"dim": 3, "model": f"m{name}"}))
    save_predictions(str(tmp_path / "c.npz"), PredictionSet([_prediction(3)], {"dim": 3}))
    proc = run_less("render", "a.npz", "b.npz", "-o", "cmp", "--format", "jsonl")
    assert proc.returncode == 0, proc.stderr.decode()
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert [(r["scan"], r["kind"], r["models"]) for r in rows] == [(0, "compare", ["ma", "mb"]),
                                                                   (1, "compare", ["ma", "mb"])]
    assert all(_read(str(tmp_path / r["figure"])).std() > 0.05 for r in rows)
    proc = run_less("render", "a.npz", "c.npz", "-o", "bad")
    assert proc.returncode == 1 and b"c.npz" in proc.stderr and not (tmp_path / "bad").exists()
