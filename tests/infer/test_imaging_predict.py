"""Imaging library: targets, prefixes, growing the particle grid, the GLOBAL baseline."""

import math

import numpy as np
import pytest
from factories import random_scanset, sphere_labels
from imaging_factory import learnable_scanset, make_representation, tiny_imager

from lesscli.data.image_labels import inclusion_slice, target_volume, training_targets
from lesscli.errors import DataError, LessError
from lesscli.infer.predict import (
    PredictOptions,
    load_imager,
    predict,
    predict_forcemap,
    prefix_lengths,
    quarter_turns,
    turned,
)
from lesscli.train.config import load_config
from lesscli.train.image_fit import ImageFitConfig, fit_imager
from lesscli.types import ImageGrid


def _fit(tmp_path, train, name="less", dim=2, epochs=1):
    make_representation(str(tmp_path / f"rep_{name}.pt"), train, name=name)
    cfg = load_config(ImageFitConfig, None, [], {"image.dim": dim, "image.width": 8, "image.patch_px": 8,
                                                 "train.epochs": epochs, "train.lr": 1e-2,
                                                 "train.device": "cpu"})
    out = str(tmp_path / f"img_{name}_{dim}.pt")
    summary = fit_imager(train, None, str(tmp_path / f"rep_{name}.pt"), cfg, out)
    return out, summary


@pytest.mark.parametrize("n,steps,every,expected", [
    (10, None, None, [10]), (10, 3, None, [4, 7, 10]), (10, None, 4, [4, 8, 10]), (2, 5, None, [1, 2]),
    (0, 3, None, [0]), (9, None, 3, [3, 6, 9])])
def test_prefix_lengths(n, steps, every, expected):
    assert prefix_lengths(n, steps, every) == expected


def test_2d_target_is_the_inclusion_centre_slice():
    vol = sphere_labels(center_mm=(-9.0, 0.0, 0.0), radius_mm=5.0)
    k = inclusion_slice(vol.data)
    assert abs(vol.origin_mm[0] + k * vol.spacing_mm[0] - (-9.0)) <= vol.spacing_mm[0] / 2
    sl = target_volume(vol, 2)
    assert (sl.shape == (1, 128, 128)
            and sl.origin_mm[0] == pytest.approx(vol.origin_mm[0] + k * vol.spacing_mm[0]))
    assert np.array_equal(target_volume(vol, 2, 3).data[0], vol.data[3])
    with pytest.raises(DataError, match="slice 40"):
        target_volume(vol, 2, 40)
    assert target_volume(vol, 3) is vol


def test_training_targets_need_one_grid():
    scans = learnable_scanset(2, 0)
    scans.labels[1] = sphere_labels(shape=(6, 16, 16), spacing=(2.0, 3.8, 3.8))
    with pytest.raises(DataError, match="one label grid"):
        training_targets(scans, 3, name="x.npz")


def test_grow_covers_a_larger_phantom(tmp_path):
    train = learnable_scanset(4, 0)
    path, _ = _fit(tmp_path, train)
    large = learnable_scanset(1, 1, shape=(6, 32, 32), spacing=(2.0, 3.8, 3.8))   # 122 mm field of view
    # reach x < -45
    large.pose[:, 0] = np.where(large.pose[:, 0] < -20, large.pose[:, 0] - 25, large.pose[:, 0])
    results = {}
    for grow in (False, True):
        imager, ckpt = load_imager(path)
        results[grow] = predict(imager, ckpt, large, PredictOptions(grow=grow))
    small, grown = results[False], results[True]
    assert small.meta["particles"] == 121 and grown.meta["particles"] > 121
    assert small.meta["width"] == 8                    # the decoder's width: metrics can --group-by width
    assert grown.scans[0].probs.shape == (4, 1, 32, 32)
    (_, _, x0), (_, _, dx) = grown.scans[0].origin_mm, grown.scans[0].spacing_mm
    far = x0 + dx * np.arange(32) < -40                    # columns beyond the 60 mm grid, touched
    assert np.allclose(small.scans[0].entropy[0][:, far], math.log(4), atol=1e-3)
    assert grown.scans[0].entropy[0][:, far].mean() < math.log(4) - 1e-3


def test_global_baseline_fit_and_predict(tmp_path):
    train = learnable_scanset(3, 0)
    path, summary = _fit(tmp_path, train, name="global", dim=3)
    assert summary["decoder"] == "global" and summary["encoder"] == "global"
    imager, ckpt = load_imager(path)
    preds = predict(imager, ckpt, learnable_scanset(1, 2), PredictOptions(every=40))
    assert preds.meta["particles"] == 1 and [p.steps for p in preds.scans] == [40, 80, 96]
    for p in preds.scans:
        assert p.probs.shape == (4, 6, 32, 32)
        assert np.allclose(p.probs.astype(np.float32).sum(axis=0), 1.0, atol=1e-2)


def _turned_image(img: np.ndarray, quarters: int) -> np.ndarray:
    """An image (..., H, W) on a grid centred on the insert's axis (axis -2: y, axis -1: x, both rising
    with the index), turned by ``quarters`` x 90 degrees counter-clockwise in the x-y plane (x onto y):
    each pixel takes the value of the pixel that the turn carries onto it, from coordinates."""
    h, w = img.shape[-2:]
    y, x = np.meshgrid(np.arange(h) - (h - 1) / 2, np.arange(w) - (w - 1) / 2, indexing="ij")
    c, s = round(math.cos(-quarters * math.pi / 2)), round(math.sin(-quarters * math.pi / 2))
    xs, ys = c * x - s * y, s * x + c * y                                  # the source point
    return img[..., np.rint(ys + (h - 1) / 2).astype(int), np.rint(xs + (w - 1) / 2).astype(int)]


@pytest.mark.parametrize("encoder", ["less", "global"])
def test_turn_average_follows_a_turned_scan_and_the_model_alone_does_not(encoder):
    imager, stats, config = tiny_imager(dim=3, encoder=encoder)
    ckpt = {"config": config, "norm_stats": stats}
    scans = random_scanset(n_scans=2, max_len=30, seed=3, with_labels=False)
    probs = {(t, q): [p.probs for p in predict(imager, ckpt, turned(scans, q) if q else scans,
                                               PredictOptions(turns=t)).scans]
             for t in (1, 4) for q in (0, 1)}
    for a, b in zip(probs[4, 0], probs[4, 1]):
        np.testing.assert_allclose(b, _turned_image(a, 1), atol=1e-5)      # the average is turn-equivariant
    assert max(np.abs(b - _turned_image(a, 1)).max() for a, b in zip(probs[1, 0], probs[1, 1])) > 1e-2
    for a, b in zip(probs[1, 0], probs[4, 0]):
        assert b.shape == a.shape and np.allclose(b.sum(axis=0), 1.0, atol=1e-5) and not np.allclose(a, b)


def test_turns_need_a_centred_square_grid_and_a_learned_imager():
    off_centre = ImageGrid((1, 48, 48), (0.0, -20.0, -23.5), (0.9, 1.0, 1.0))
    imager, stats, config = tiny_imager(dim=2, grid=off_centre)
    scans = random_scanset(n_scans=1, seed=3, with_labels=False)
    with pytest.raises(LessError,
                       match=r"scan 0: --turns needs a square label grid centred on the insert's axis"):
        predict(imager, {"config": config, "norm_stats": stats}, scans, PredictOptions(turns=2))
    with pytest.raises(LessError, match="turns must be one of 1, 2, 4"):
        quarter_turns(3)
    with pytest.raises(LessError, match=r"fm\.pt: --turns averages a learned imager's"):
        predict_forcemap({"config": {}}, scans, PredictOptions(turns=4), "fm.pt")
