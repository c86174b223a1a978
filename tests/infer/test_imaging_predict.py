"""Imaging library: targets, prefixes, growing the particle grid, the GLOBAL baseline."""

import math

import numpy as np
import pytest
from factories import sphere_labels
from imaging_factory import learnable_scanset, make_representation

from lesscli.data.image_labels import inclusion_slice, target_volume, training_targets
from lesscli.errors import DataError
from lesscli.infer.predict import PredictOptions, load_imager, predict, prefix_lengths
from lesscli.train.config import load_config
from lesscli.train.image_fit import ImageFitConfig, fit_imager


def _fit(tmp_path, train, name="less", dim=2, epochs=1):
    make_representation(str(tmp_path / f"rep_{name}.pt"), train, name=name)
    cfg = load_config(ImageFitConfig, None, [], {"image.dim": dim, "image.width": 8, "image.patch_px": 8,
                                                 "train.epochs": epochs, "train.lr": 1e-2, "train.device": "cpu"})
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
    assert sl.shape == (1, 128, 128) and sl.origin_mm[0] == pytest.approx(vol.origin_mm[0] + k * vol.spacing_mm[0])
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
    large.pose[:, 0] = np.where(large.pose[:, 0] < -20, large.pose[:, 0] - 25, large.pose[:, 0])   # reach x < -45
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
