"""A frozen-encoder fit on cached encoder states trains exactly as the per-batch encoder path."""

import numpy as np
import pytest
import torch
from imaging_factory import learnable_scanset, make_representation

from lesscli.io.checkpoint import load_checkpoint
from lesscli.models.registry import build_decoder
from lesscli.train.config import LoopConfig
from lesscli.train.image_fit import ImageFitConfig, ImageModelConfig, fit_imager

ROUND_OFF_ATOL = 1e-5      # float32 encoder outputs from differently padded batches


def _fit(tmp_path, name, rep, train, val, cache):
    cfg = ImageFitConfig(image=ImageModelConfig(dim=2, width=8, patch_px=8),
                         train=LoopConfig(epochs=2, batch_size=3, lr=1e-2, seed=5, device="cpu"))
    out = str(tmp_path / f"{name}.pt")
    summary = fit_imager(train, val, rep, cfg, out, cache=cache)
    return summary, load_checkpoint(out)["model_state"], load_checkpoint(out.replace(".pt", ".last.pt"))


@pytest.mark.parametrize("encoder", ["less", "global"])
def test_cached_states_give_the_same_decoder(tmp_path, encoder):
    train, val = learnable_scanset(7, 3), learnable_scanset(2, 4)
    rep = str(tmp_path / "rep.pt")
    make_representation(rep, train, name=encoder, dim=8)
    plain, best_plain, last_plain = _fit(tmp_path, "plain", rep, train, val, cache=False)
    cached, best_cached, last_cached = _fit(tmp_path, "cached", rep, train, val, cache=True)
    assert best_cached.keys() == best_plain.keys() and any(k.startswith("encoder.") for k in best_cached)
    decoder_keys = [k for k in last_plain["model_state"] if k.startswith("decoder.")]
    assert decoder_keys
    start = build_decoder(last_plain["config"]["decoder"], seed=5).state_dict()
    assert any(not torch.allclose(start[k.removeprefix("decoder.")], last_plain["model_state"][k])
               for k in decoder_keys), "training did not move the decoder"
    for key in decoder_keys:
        torch.testing.assert_close(last_cached["model_state"][key], last_plain["model_state"][key],
                                   atol=ROUND_OFF_ATOL, rtol=1e-4)
    for key in best_plain:
        torch.testing.assert_close(best_cached[key], best_plain[key], atol=ROUND_OFF_ATOL, rtol=1e-4)
    assert [h["train_loss"] for h in last_cached["history"]] == pytest.approx(
        [h["train_loss"] for h in last_plain["history"]], rel=1e-5)
    assert cached["best_epoch"] == plain["best_epoch"]
    assert cached["val_inclusion_f1"] == pytest.approx(plain["val_inclusion_f1"], nan_ok=True)


@pytest.mark.parametrize("select", ["f1", "loss"])
def test_best_epoch_is_the_best_validation_f1_or_loss(tmp_path, select):
    train, val = learnable_scanset(7, 3), learnable_scanset(3, 4)
    rep = str(tmp_path / "rep.pt")
    make_representation(rep, train, name="less", dim=8)
    cfg = ImageFitConfig(image=ImageModelConfig(dim=2, width=8, patch_px=8, select=select),
                         train=LoopConfig(epochs=6, batch_size=3, lr=3e-2, seed=1, device="cpu"))
    out = str(tmp_path / "img.pt")
    summary = fit_imager(train, val, rep, cfg, out)
    history = [h for h in load_checkpoint(out)["history"] if "val_loss" in h]
    assert len(history) == 6
    if select == "f1":
        assert summary["selected_by"] == "val_f1"
        scored = [h for h in history if "val_score" in h]
        assert scored, "no epoch had a defined validation F1"
        best = max(scored, key=lambda h: (h["val_score"], -h["val_loss"]))
        assert summary["val_inclusion_f1"] == pytest.approx(best["val_score"])
    else:
        assert summary["selected_by"] == "val_loss" and all("val_score" not in h for h in history)
        best = min(history, key=lambda h: h["val_loss"])
    assert summary["best_epoch"] == best["epoch"]


class _Item:
    """A validation batch of given logits and target, already on the device."""

    def __init__(self, logits, target):
        self.inputs, self.target = logits, target

    def to(self, device):
        return self


def test_threshold_is_chosen_on_validation_voxels():
    """Inclusion voxels at p = 0.95, false ones at p = 0.65: any threshold in [0.65, 0.95) scores F1 = 1,
    argmax and 0.5 / 0.6 do not, and ties keep the lowest threshold (0.7)."""
    from lesscli.train.image_fit import choose_labelling

    target = torch.zeros(1, 1, 2, 2, dtype=torch.long)
    target[0, 0, 0, 0] = 3
    probs = torch.full((1, 4, 1, 2, 2), 0.35 / 3)
    probs[:, 3] = 0.65
    probs[0, 3, 0, 0, 0] = 0.95
    probs[0, :3, 0, 0, 0] = 0.05 / 3
    logits = probs.log()
    rule, scores, _ = choose_labelling(torch.nn.Identity(), [_Item(logits, target)], 1, torch.device("cpu"),
                                       (1.0, 1.0, 1.0), collate_fn=lambda items: items[0], smooths=(0.0,))
    scores = scores["0"]
    assert (rule.threshold, rule.min_volume_mm3) == (0.7, 0.0) and scores["0.7"]["0"] == 1.0
    assert scores["None"]["0"] < 1.0


def test_minimum_volume_is_chosen_on_validation_regions():
    """A true 3 x 3 x 3 inclusion (27 mm^3) and a false 2-voxel speck, both at p = 0.9: no threshold
    separates them, a 50 mm^3 minimum drops the true one too, 0 < min <= 27 keeps only the true one."""
    from lesscli.train.image_fit import choose_labelling

    target = torch.ones(1, 8, 8, 8, dtype=torch.long)
    target[0, 1:4, 1:4, 1:4] = 3
    probs = torch.full((1, 4, 8, 8, 8), 0.0)
    probs[:, 1] = 1.0
    stiff = target[0] == 3
    stiff[6, 6, 5:7] = True                                               # the speck, far from the body
    probs[0, :, stiff] = torch.tensor([0.0, 0.1, 0.0, 0.9])[:, None]
    logits = (probs + 1e-6).log()
    rule, scores, _ = choose_labelling(
        torch.nn.Identity(), [_Item(logits, target)], 1, torch.device("cpu"), (1.0, 1.0, 1.0),
        collate_fn=lambda items: items[0], volumes=(0.0, 10.0, 50.0), smooths=(0.0,))
    scores = scores["0"]
    assert (rule.threshold, rule.min_volume_mm3) == (None, 10.0) and scores["None"]["10"] == 1.0
    assert scores["None"]["0"] < 1.0 and scores["None"]["50"] == 0.0


def test_near_best_labellings_are_told_apart_by_their_sizing():
    """A 10 x 10 inclusion at p = 0.95 but one inner voxel at 0.75, and a false voxel 24 mm away at 0.75:
    up to 0.7 the speck is kept (F1 200/201, diameter 24 mm too large), from 0.8 the inner voxel is lost
    (F1 198/199, diameter exact). Within the tolerance the exact size wins; with none, the F1 (and the
    first of the tied rules, argmax); of tied minimum volumes, the largest."""
    from lesscli.train.image_fit import LABEL_F1_TOLERANCE, choose_labelling

    target = torch.ones(1, 1, 30, 30, dtype=torch.long)
    target[0, 0, 2:12, 2:12] = 3
    probs = torch.zeros(1, 4, 1, 30, 30)
    probs[:, 1] = 1.0
    stiff = target[0] == 3
    stiff[0, 28, 28] = True
    probs[0, :, stiff] = torch.tensor([0.0, 0.05, 0.0, 0.95])[:, None]
    for r, c in ((6, 6), (28, 28)):
        probs[0, :, 0, r, c] = torch.tensor([0.0, 0.25, 0.0, 0.75])
    logits = (probs + 1e-6).log()

    def choose(volumes=(0.0,), **kw):
        rule, scores, sizing = choose_labelling(
            torch.nn.Identity(), [_Item(logits, target)], 1, torch.device("cpu"), (1.0, 1.0, 1.0),
            collate_fn=lambda items: items[0], volumes=volumes, smooths=(0.0,), **kw)
        return rule, scores["0"], sizing["0"]

    rule, scores, sizing = choose()
    assert scores["0.7"]["0"] - scores["0.8"]["0"] < LABEL_F1_TOLERANCE
    assert rule.threshold == 0.8 and sizing["0.8"]["0"] == 0.0
    assert sizing["0.7"]["0"] == pytest.approx(float(np.hypot(26, 26) - np.hypot(9, 9)))
    assert choose(tolerance=0.0)[0].threshold is None
    rule = choose(volumes=(0.0, 0.5))[0]
    # a region rule that changes nothing here: kept
    assert (rule.threshold, rule.min_volume_mm3) == (0.8, 0.5)


@pytest.mark.parametrize("min_volume, kept", [(0.0, True), (4.0, True), (4.5, False)])
def test_region_rule_measures_volume_in_mm3(min_volume, kept):
    """A 2-voxel inclusion region at 2 x 1 x 1 mm voxels is 4 mm^3; below the minimum it takes the
    likelier of background and insert, and a 27-voxel region (54 mm^3) stays."""
    from lesscli.io.predictions import labels_from_probs

    probs = np.zeros((4, 6, 6, 6), dtype=np.float32)
    probs[0] = 0.6                                                        # background likelier than insert
    probs[1] = 0.4
    body = np.zeros((6, 6, 6), bool)
    body[0:3, 0:3, 0:3] = True
    speck = np.zeros((6, 6, 6), bool)
    speck[5, 5, 4:6] = True
    for region in (body, speck):
        probs[:, region] = np.array([0.05, 0.05, 0.0, 0.9])[:, None]
    labels = labels_from_probs(probs, None, min_volume, (2.0, 1.0, 1.0))
    assert (labels[body] == 3).all()
    assert (labels[speck] == 3).all() if kept else (labels[speck] == 0).all()
    assert (labels[~body & ~speck] == 0).all()


def test_smoothing_is_a_gaussian_across_each_slice():
    """A unit spike in one slice, smoothed 1 mm at 2 x 0.5 mm pixels (sigma 2 and 0.5 pixels, the sampled
    kernel cut at 4 sigma and normalised): its peak is 1 / (S(2) S(0.5)) with S(s) = sum exp(-k^2 / 2s^2),
    neighbouring rows fall by exp(-1 / 8), other slices stay untouched and every voxel stays a
    distribution."""
    from lesscli.io.predictions import smoothed

    spike = np.zeros((2, 3, 21, 21), np.float32)
    spike[1, 1, 10, 10] = 1.0
    spike[0] = 1.0 - spike[1]

    def kernel_sum(sigma):
        k = np.arange(-int(4 * sigma + 0.5), int(4 * sigma + 0.5) + 1)
        return np.exp(-k**2 / (2 * sigma**2)).sum()

    out = smoothed(spike, 1.0, (1.8, 0.5, 2.0))
    assert out[1, 1, 10, 10] == pytest.approx(1 / (kernel_sum(2.0) * kernel_sum(0.5)), rel=1e-5)
    assert out[1, 1, 11, 10] / out[1, 1, 10, 10] == pytest.approx(np.exp(-1 / 8), rel=1e-5)
    assert (out[1, [0, 2]] == 0).all() and np.allclose(out.sum(axis=0), 1.0, atol=1e-6)
    assert (smoothed(spike, 0.0, (1.8, 0.5, 2.0)) == spike).all()


def test_smoothing_drops_a_spur_and_keeps_the_body():
    """A 9 x 9 pixel inclusion with a one-pixel spur off its corner, all at p = 0.9: unsmoothed the spur is
    inclusion, smoothed by one pixel it is not, and the body's 7 x 7 interior still is."""
    from lesscli.io.predictions import labels_from_probs

    probs = np.zeros((4, 1, 30, 30), np.float32)
    probs[1] = 1.0
    stiff = np.zeros((1, 30, 30), bool)
    stiff[0, 10:19, 10:19] = True
    stiff[0, 19, 19] = True
    probs[:, stiff] = np.array([0.0, 0.1, 0.0, 0.9], np.float32)[:, None]
    plain = labels_from_probs(probs, None, 0.0, (1.0, 1.0, 1.0))
    smooth = labels_from_probs(probs, None, 0.0, (1.0, 1.0, 1.0), smooth_mm=1.0)
    assert plain[0, 19, 19] == 3 and smooth[0, 19, 19] == 1
    assert (smooth[0, 11:18, 11:18] == 3).all()


def test_smoothing_is_chosen_when_it_sizes_better():
    """A true disc (radius 6 pixels) drawn at p = 0.9 with one-pixel spurs on its rim: unsmoothed they
    are false inclusion and widen the disc; smoothed by 1 mm they go, F1 rises and the size comes right,
    so the rule takes the smoothing; offered only 0 mm, it cannot."""
    from lesscli.train.image_fit import choose_labelling

    yy, xx = np.mgrid[:32, :32]
    disc = (yy - 15.5)**2 + (xx - 15.5)**2 <= 36
    target = torch.ones(1, 1, 32, 32, dtype=torch.long)
    target[0, 0][torch.from_numpy(disc)] = 3
    stiff = disc.copy()
    for r, c in ((15, 22), (8, 15), (23, 16), (15, 8), (10, 21)):
        stiff[r, c] = True                                                # spurs just outside the rim
    probs = torch.zeros(1, 4, 1, 32, 32)
    probs[:, 1] = 1.0
    probs[0, :, 0, torch.from_numpy(stiff)] = torch.tensor([0.0, 0.1, 0.0, 0.9])[:, None]
    logits = (probs + 1e-6).log()

    def choose(smooths):
        return choose_labelling(torch.nn.Identity(), [_Item(logits, target)], 1, torch.device("cpu"),
                                (1.0, 1.0, 1.0), collate_fn=lambda items: items[0], thresholds=(None,),
                                volumes=(0.0,), smooths=smooths, tolerance=0.0)

    rule, scores, sizing = choose((0.0, 1.0))
    assert rule.smooth_mm == 1.0 and scores["1"]["None"]["0"] > scores["0"]["None"]["0"]
    assert sizing["1"]["None"]["0"] < sizing["0"]["None"]["0"]
    assert choose((0.0,))[0].smooth_mm == 0.0
