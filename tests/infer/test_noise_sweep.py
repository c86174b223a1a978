"""Pose-noise sweep: the noise model, the aggregation over repeats, and the command end to end."""

import json
from dataclasses import replace

import numpy as np
import pytest
from imaging_factory import learnable_scanset, make_representation

from lesscli.infer.noise import NoiseLevel, grid_levels, noisy_scans, sweep, unit_draws
from lesscli.io.predictions import PredictionSet, ScanPrediction
from lesscli.io.scans import save_scans

ONE_THREAD = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def _png_is_not_blank(path):
    from matplotlib.image import imread

    img = imread(str(path))
    assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
    assert float(img[..., :3].std()) > 0.02   # more than a flat background


def test_noise_is_iid_gaussian_on_position_and_angles_in_the_phantom_frame():
    scans = learnable_scanset(4, seed=1, steps_per_traj=50)
    (draw,) = unit_draws(scans.n_steps, 1, seed=3)
    noisy = noisy_scans(scans, NoiseLevel(pos_mm=2.0, ang_rad=0.1), draw)
    delta = noisy.pose.astype(np.float64) - scans.pose
    n = scans.n_steps
    assert n > 2000
    # sigma per coordinate within 4 standard errors of the asked sigma, zero mean, no correlation
    for axis, sigma in enumerate([2.0] * 3 + [0.1] * 3):
        assert abs(delta[:, axis].std() - sigma) < 4 * sigma / np.sqrt(2 * n)
        assert abs(delta[:, axis].mean()) < 4 * sigma / np.sqrt(n)
    assert abs(np.corrcoef(delta[:, 0], delta[:, 1])[0, 1]) < 4 / np.sqrt(n)
    np.testing.assert_array_equal(noisy.force, scans.force)
    np.testing.assert_array_equal(noisy.traj_offsets, scans.traj_offsets)


def test_zero_noise_is_identity_and_draws_are_seeded():
    scans = learnable_scanset(2, seed=0)
    (draw,) = unit_draws(scans.n_steps, 1, seed=0)
    np.testing.assert_array_equal(noisy_scans(scans, NoiseLevel(0.0, 0.0), draw).pose, scans.pose)
    a, b = unit_draws(10, 2, seed=5), unit_draws(10, 2, seed=5)
    np.testing.assert_array_equal(a[1], b[1])
    assert not np.allclose(a[0], a[1])
    assert not np.allclose(unit_draws(10, 1, seed=6)[0], a[0])


def test_grid_levels_is_every_combination_angle_major():
    levels = grid_levels([0, 1], [0, 0.1, 0.2])
    assert len(levels) == 6 and levels[0] == NoiseLevel(0.0, 0.0) and levels[1] == NoiseLevel(1.0, 0.0)
    assert levels[2] == NoiseLevel(0.0, 0.1)


def _shifting_predictor(spacing_px_mm):
    """Predict the truth shifted in x by the mean absolute x error of the poses (a stand-in model)."""
    clean = {}

    def predict_fn(scans):
        if "pose" not in clean:
            clean["pose"] = scans.pose.copy()
        err_mm = float(np.abs(scans.pose[:, 0] - clean["pose"][:, 0]).mean())
        shift = round(err_mm / spacing_px_mm)
        preds = []
        for s in range(scans.n_scans):
            truth = scans.label_of(s)
            label = np.roll(truth.data, shift, axis=2)
            probs = np.eye(4, dtype=np.float32)[label].transpose(3, 0, 1, 2)
            preds.append(ScanPrediction(probs, truth.origin_mm, truth.spacing_mm, truth=truth.data,
                                        label=label))
        return PredictionSet(preds, {"dim": 3})

    return predict_fn


def test_sweep_aggregates_repeats_and_runs_the_clean_cell_once():
    scans = learnable_scanset(3, seed=2)
    spacing = scans.labels[0].spacing_mm[2]
    calls = []
    predictor = _shifting_predictor(spacing)

    def predict_fn(noisy):
        calls.append(noisy)
        return predictor(noisy)

    levels = grid_levels([0.0, 2.0, 7.0], [0.0])
    rows = sweep(predict_fn, scans, levels, repeats=3, seed=0, dim=3)
    assert [r["repeats"] for r in rows] == [1, 3, 3] and len(calls) == 7
    clean, mid, far = rows
    assert clean["f1_micro"] == pytest.approx(1.0) and clean["f1_micro_std"] == 0.0
    assert clean["com_error_mm"] == pytest.approx(0.0, abs=1e-9)
    assert 0.0 <= far["f1_micro"] < mid["f1_micro"] < 1.0
    # 7 mm noise -> mean |error| 7 sqrt(2/pi) = 5.6 mm (+- 0.2) -> a shift of round(5.6 / 1.9) = 3 voxels
    assert far["com_error_mm"] == pytest.approx(3 * spacing, rel=1e-6)
    assert far["f1_micro_std"] == pytest.approx(0.0, abs=1e-12)


@pytest.fixture
def imager(tmp_path, run_less):
    save_scans(str(tmp_path / "train.npz"), learnable_scanset(6, 10))
    save_scans(str(tmp_path / "test.npz"), learnable_scanset(2, 32))
    save_scans(str(tmp_path / "nolabels.npz"),
               replace(learnable_scanset(2, 32), scan_label=-np.ones(2, np.int64), labels=[]))
    make_representation(str(tmp_path / "rep.pt"), learnable_scanset(6, 10), dim=8)
    proc = run_less("image", "fit", "train.npz", "--rep", "rep.pt", "-o", "img.pt", "--dim", "2", "--epochs",
                    "4", "--lr", "1e-2", "--device", "cpu", "--set", "image.width=8", "--set",
                    "image.patch_px=8", "--format", "jsonl", env=ONE_THREAD)
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    return tmp_path / "img.pt"


def test_noise_sweep_command_writes_one_record_per_cell_and_a_plot(tmp_path, run_less, imager):
    proc = run_less("noise-sweep", "img.pt", "test.npz", "--pos-mm", "0,2", "--ang-rad", "0,0.1", "--repeats",
                    "2", "--seed", "1", "--plot", "noise.png", "--device", "cpu", "--format", "jsonl",
                    env=ONE_THREAD)
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert [(r["pos_mm"], r["ang_rad"]) for r in rows] == [(0, 0), (2, 0), (0, 0.1), (2, 0.1)]
    assert [r["repeats"] for r in rows] == [1, 2, 2, 2]
    assert all(r["dim"] == 2 and r["model"] == "less" for r in rows)
    assert all(r["f1_micro"] is None or 0.0 <= r["f1_micro"] <= 1.0 for r in rows)
    _png_is_not_blank(tmp_path / "noise.png")
    again = run_less("noise-sweep", "img.pt", "test.npz", "--pos-mm", "0,2", "--ang-rad", "0,0.1",
                     "--repeats", "2", "--seed", "1", "--device", "cpu", "--format", "jsonl", env=ONE_THREAD)
    assert again.stdout == proc.stdout                       # seeded: the same records


def test_noise_sweep_rejects_bad_input_with_one_line(tmp_path, run_less, imager):
    proc = run_less("noise-sweep", "img.pt", "nolabels.npz", "--device", "cpu")
    assert proc.returncode == 1 and b"nolabels.npz" in proc.stderr and b"label" in proc.stderr
    assert b"Traceback" not in proc.stderr
    proc = run_less("noise-sweep", "img.pt", "test.npz", "--pos-mm", "0,-1")
    assert proc.returncode == 2 and b"--pos-mm" in proc.stderr
    assert not (tmp_path / "noise.png").exists()
