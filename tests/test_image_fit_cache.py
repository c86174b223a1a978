"""A frozen-encoder fit on cached encoder states trains exactly as the per-batch encoder path."""

import pytest
import torch
from imaging_factory import learnable_scanset, make_representation

from lesscli.train.checkpoint import load_checkpoint
from lesscli.train.config import LoopConfig
from lesscli.train.image_fit import ImageFitConfig, ImageModelConfig, build_decoder, fit_imager

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


def test_threshold_is_chosen_on_validation_voxels():
    """Inclusion voxels at p = 0.95, false ones at p = 0.65: any threshold in [0.65, 0.95) scores F1 = 1,
    argmax and 0.5 / 0.6 do not, and ties keep the lowest threshold (0.7)."""
    from lesscli.train.image_fit import choose_threshold

    class Item:
        def __init__(self, logits, target):
            self.inputs, self.target = logits, target

        def to(self, device):
            return self

    target = torch.zeros(1, 1, 2, 2, dtype=torch.long)
    target[0, 0, 0, 0] = 3
    probs = torch.full((1, 4, 1, 2, 2), 0.35 / 3)
    probs[:, 3] = 0.65
    probs[0, 3, 0, 0, 0] = 0.95
    probs[0, :3, 0, 0, 0] = 0.05 / 3
    logits = probs.log()
    threshold, scores = choose_threshold(torch.nn.Identity(), [Item(logits, target)], 1, torch.device("cpu"),
                                         collate_fn=lambda items: items[0])
    assert threshold == 0.7 and scores["0.7"] == 1.0 and scores["None"] < 1.0
