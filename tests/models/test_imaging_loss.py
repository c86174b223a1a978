"""Imaging loss: hand-derived values, guards, gradients, dtypes, optional MONAI cross-check."""

import math

import pytest
import torch

from lesscli.models.imaging_loss import (
    DICE_EPS,
    ETA_DELTA,
    class_weights,
    dice_loss,
    focal_loss,
    imaging_loss,
)


def _two_voxels():
    """Voxel 0 is class 0 with p = (1/2, 1/2); voxel 1 is class 1 with p = (1/4, 3/4)."""
    logits = torch.tensor([[[0.0, 0.0], [0.0, math.log(3.0)]]]).transpose(1, 2)   # (1, C=2, S=2)
    target = torch.tensor([[0, 1]])
    return logits, target


def test_hand_derived_two_voxels():
    logits, target = _two_voxels()
    out = imaging_loss(logits, target)
    # alpha: one voxel per class -> (1/2, 1/2)
    focal = (0.5 * 0.25 * math.log(2.0) + 0.5 * 0.0625 * math.log(4.0 / 3.0)) / 2
    dice0 = (2 * 0.5 + DICE_EPS) / (0.75 + 1 + DICE_EPS)
    dice1 = (2 * 0.75 + DICE_EPS) / (1.25 + 1 + DICE_EPS)
    dice = 1 - (dice0 + dice1) / 2
    eta = dice / (focal + ETA_DELTA)
    assert out.focal.item() == pytest.approx(focal, rel=1e-6)
    assert out.dice.item() == pytest.approx(dice, rel=1e-6)
    assert out.eta.item() == pytest.approx(eta, rel=1e-6)
    assert out.total.item() == pytest.approx(0.5 * dice + 0.5 * eta * focal, rel=1e-6)


def test_alpha_is_inverse_frequency_normalised():
    y = torch.nn.functional.one_hot(torch.tensor([[0, 0, 0, 1]]), 2).movedim(-1, 1).float()
    assert class_weights(y).tolist() == pytest.approx([0.25, 0.75])


def test_alpha_power_generalises_inverse_frequency():
    y = torch.nn.functional.one_hot(torch.tensor([[0, 0, 0, 0, 1, 2]]), 4).movedim(-1, 1).float()
    # counts 4, 1, 1, 0: power 0.5 -> 1/2, 1, 1 normalised; power 0 -> uniform over present classes
    assert class_weights(y, 0.5).tolist() == pytest.approx([0.2, 0.4, 0.4, 0.0])
    assert class_weights(y, 0.0).tolist() == pytest.approx([1 / 3, 1 / 3, 1 / 3, 0.0])
    assert class_weights(y, 1.0).tolist() == pytest.approx([1 / 9, 4 / 9, 4 / 9, 0.0])


def test_alpha_ignores_absent_classes():
    codes = torch.tensor([[0, 0, 0, 1]])
    y2 = torch.nn.functional.one_hot(codes, 2).movedim(-1, 1).float()
    y4 = torch.nn.functional.one_hot(codes, 4).movedim(-1, 1).float()
    a2, a4 = class_weights(y2), class_weights(y4)
    assert a4[:2].tolist() == pytest.approx(a2.tolist())
    assert a4[2:].tolist() == [0.0, 0.0]


def test_focal_weights_only_true_class():
    logits, target = _two_voxels()
    logp = torch.log_softmax(logits, 1)
    y = torch.nn.functional.one_hot(target, 2).movedim(-1, 1).float()
    alpha = torch.tensor([1.0, 0.0])
    expected = 0.25 * math.log(2.0) / 2     # only voxel 0 counts
    assert focal_loss(logp, y, alpha, gamma=2.0).item() == pytest.approx(expected, rel=1e-6)
    assert focal_loss(logp, y, alpha, gamma=0.0).item() == pytest.approx(math.log(2.0) / 2, rel=1e-6)
    with pytest.raises(ValueError, match="gamma"):
        focal_loss(logp, y, alpha, gamma=0.5)


def test_class_absent_from_truth_and_prediction_scores_one():
    # class 2 never true and never argmax: its Dice score is 1, so the loss equals the 2-class loss * 2/3
    logits = torch.tensor([[[2.0, -1.0, -5.0], [-1.0, 2.0, -5.0]]]).transpose(1, 2)   # (1, 3, 2)
    target = torch.tensor([[0, 1]])
    probs = torch.softmax(logits, 1)
    y = torch.nn.functional.one_hot(target, 3).movedim(-1, 1).float()
    d3 = dice_loss(probs, y)
    p = probs[:, :2].reshape(2, 2)
    scores = [(2 * p[c, c] + DICE_EPS) / (p[c].sum() + 1 + DICE_EPS) for c in range(2)]
    assert d3.item() == pytest.approx(1 - (scores[0] + scores[1] + 1.0).item() / 3, rel=1e-6)


def test_class_absent_from_truth_but_predicted_is_charged():
    # voxel 0 argmax = class 2
    logits = torch.tensor([[[2.0, -1.0, 5.0], [-1.0, 2.0, -5.0]]]).transpose(1, 2)
    target = torch.tensor([[0, 1]])
    probs = torch.softmax(logits, 1)
    y = torch.nn.functional.one_hot(target, 3).movedim(-1, 1).float()
    p2 = probs[0, 2].sum()
    p = probs[0]
    s0 = (2 * p[0, 0] + DICE_EPS) / (p[0].sum() + 1 + DICE_EPS)
    s1 = (2 * p[1, 1] + DICE_EPS) / (p[1].sum() + 1 + DICE_EPS)
    s2 = DICE_EPS / (p2 + DICE_EPS)
    assert dice_loss(probs, y).item() == pytest.approx(1 - ((s0 + s1 + s2) / 3).item(), rel=1e-6)


def test_dice_per_scan_weighs_a_small_inclusion_like_a_large_one():
    # scan 0: a 1-voxel inclusion drawn over 4 voxels; scan 1: a 12-voxel inclusion drawn exactly (2 classes)
    target = torch.zeros(2, 16, dtype=torch.long)
    target[0, 0] = 1
    target[1, :12] = 1
    probs = torch.zeros(2, 2, 16)
    probs[:, 1] = target.float()
    probs[0, 1, :4] = 1.0
    probs[:, 0] = 1.0 - probs[:, 1]
    y = torch.nn.functional.one_hot(target, 2).movedim(-1, 1).float()

    def score(inter, p_sum, t_sum):
        return (2 * inter + DICE_EPS) / (p_sum + t_sum + DICE_EPS)

    per_scan = [score(12, 12, 15), score(1, 4, 1), score(4, 4, 4), score(12, 12, 12)]   # (scan, class)
    batch = [score(16, 16, 19), score(13, 16, 13)]
    assert dice_loss(probs, y, per="scan").item() == pytest.approx(1 - sum(per_scan) / 4, rel=1e-6)
    assert dice_loss(probs, y).item() == pytest.approx(1 - sum(batch) / 2, rel=1e-6)
    assert dice_loss(probs, y, per="scan").item() > 1.5 * dice_loss(probs, y).item()   # 0.178 vs 0.095
    with pytest.raises(ValueError, match="per must be"):
        dice_loss(probs, y, per="voxel")


def test_dice_per_scan_applies_the_empty_class_rule_per_scan():
    # class 1 absent from scan 0's truth and argmax (score 1 there), present in scan 1
    # (2, C=2, S=2)
    logits = torch.tensor([[[3.0, -3.0], [3.0, -3.0]], [[-3.0, 3.0], [3.0, -3.0]]]).transpose(1, 2)
    target = torch.tensor([[0, 0], [1, 0]])
    probs = torch.softmax(logits, 1)
    y = torch.nn.functional.one_hot(target, 2).movedim(-1, 1).float()
    p = probs
    s00 = (2 * p[0, 0].sum() + DICE_EPS) / (p[0, 0].sum() + 2 + DICE_EPS)
    s10 = (2 * p[1, 0, 1] + DICE_EPS) / (p[1, 0].sum() + 1 + DICE_EPS)
    s11 = (2 * p[1, 1, 0] + DICE_EPS) / (p[1, 1].sum() + 1 + DICE_EPS)
    expected = 1 - (s00 + 1.0 + s10 + s11) / 4
    assert dice_loss(probs, y, per="scan").item() == pytest.approx(expected.item(), rel=1e-6)
    logits = logits.clone().requires_grad_(True)
    out = imaging_loss(logits, target, dice_per="scan")
    out.total.backward()
    assert torch.isfinite(out.total) and torch.isfinite(logits.grad).all()


def _grad_of(logits, target):
    logits = logits.clone().requires_grad_(True)
    out = imaging_loss(logits, target)
    out.total.backward()
    return out, logits.grad


@pytest.mark.parametrize("case", ["extreme", "all_background", "absent_class", "single_voxel"])
def test_finite_values_and_gradients(case):
    gen = torch.Generator().manual_seed(0)
    shape = (2, 4, 3, 6, 6)
    logits = torch.randn(shape, generator=gen)
    target = torch.randint(0, 4, (2, 3, 6, 6), generator=gen)
    if case == "extreme":
        logits = torch.where(torch.rand(shape, generator=gen) > 0.5, 1e4, -1e4)
    elif case == "all_background":
        target = torch.zeros_like(target)
    elif case == "absent_class":
        target = target.clamp(max=2)          # class 3 absent from the batch
    elif case == "single_voxel":
        target = torch.ones_like(target)
        target[1, 2, 3, 4] = 3
    out, grad = _grad_of(logits, target)
    for value in (out.total, out.dice, out.focal, out.eta):
        assert torch.isfinite(value)
    assert torch.isfinite(grad).all()
    assert grad.abs().sum() > 0


def test_single_voxel_inclusion_gets_the_largest_weight():
    target = torch.ones(1, 4, 4, dtype=torch.long)
    target[0, 0, 0] = 0
    target[0, 1:, 0] = 0
    target[0, 2, 2] = 3
    y = torch.nn.functional.one_hot(target, 4).movedim(-1, 1).float()
    alpha = class_weights(y)
    assert int(alpha.argmax()) == 3 and alpha[2] == 0


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_low_precision_inputs_match_float32(dtype):
    gen = torch.Generator().manual_seed(1)
    logits = 3 * torch.randn(2, 4, 5, 7, 7, generator=gen)
    target = torch.randint(0, 4, (2, 5, 7, 7), generator=gen)
    low = logits.to(dtype)
    ref = imaging_loss(low.float(), target)
    got = imaging_loss(low, target)
    assert got.total.dtype == torch.float32
    assert got.total.item() == pytest.approx(ref.total.item(), rel=1e-6)
    assert got.total.item() == pytest.approx(imaging_loss(logits, target).total.item(), rel=2e-2)
    low.requires_grad_(True)
    imaging_loss(low, target).total.backward()
    assert low.grad.dtype == dtype and torch.isfinite(low.grad.float()).all()


def test_shape_and_code_errors():
    with pytest.raises(ValueError, match="disagree"):
        imaging_loss(torch.zeros(1, 2, 3), torch.zeros(1, 4, dtype=torch.long))
    with pytest.raises(ValueError, match="codes"):
        imaging_loss(torch.zeros(1, 2, 3), torch.full((1, 3), 2))


def test_monai_cross_check_float64():
    """Dice and focal terms against MONAI's DiceLoss and softmax FocalLoss in float64.

    MONAI's combined DiceFocalLoss uses a sigmoid focal term even with softmax Dice, so only the
    separate terms are compared.
    """
    monai_losses = pytest.importorskip("monai.losses")
    gen = torch.Generator().manual_seed(2)
    logits = torch.randn(2, 4, 3, 5, 5, generator=gen, dtype=torch.float64)
    target = torch.randint(0, 4, (2, 3, 5, 5), generator=gen)
    target[0, 0, 0, :4] = torch.arange(4)     # every class present, so the empty-class rule is not involved
    y = torch.nn.functional.one_hot(target, 4).movedim(-1, 1).double()
    probs = torch.softmax(logits, 1)
    ours_dice = dice_loss(probs, y)
    theirs_dice = monai_losses.DiceLoss(batch=True, smooth_nr=DICE_EPS, smooth_dr=DICE_EPS)(probs, y)
    assert ours_dice.item() == pytest.approx(theirs_dice.item(), rel=1e-9)
    target[1, 0, 0, :4] = torch.arange(4)     # per scan too
    y = torch.nn.functional.one_hot(target, 4).movedim(-1, 1).double()
    theirs_scan = monai_losses.DiceLoss(batch=False, smooth_nr=DICE_EPS, smooth_dr=DICE_EPS)(probs, y)
    assert dice_loss(probs, y, per="scan").item() == pytest.approx(theirs_scan.item(), rel=1e-9)
    alpha = class_weights(y)
    ours_focal = focal_loss(torch.log_softmax(logits, 1), y, alpha, gamma=2.0)
    theirs = monai_losses.FocalLoss(gamma=2.0, weight=alpha, use_softmax=True, reduction="none")(logits, y)
    # MONAI keeps the class weights in float32, hence the looser tolerance
    assert ours_focal.item() == pytest.approx((theirs.sum() / target.numel()).item(), rel=1e-7)
