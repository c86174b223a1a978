"""Imaging loss for class-imbalanced label images: lambda Dice + (1 - lambda) eta Focal.

Definitions (paper appendix "Imaging Class Imbalance"), with N voxels over the batch and C classes::

    L       = lambda * L_dice + (1 - lambda) * eta * L_focal
    eta     = L_dice / (L_focal + delta)                      (both detached: eta is a number, not a path)
    L_focal = -1/N sum_v sum_c alpha_c y_vc (1 - p_vc)^gamma log p_vc
    L_dice  = 1 - 1/C sum_c (2 sum_v p_vc y_vc + eps) / (sum_v p_vc + sum_v y_vc + eps)

Numerical rules added to the published formulation: logits are upcast to float32 before the softmax
and every sum, and ``log p`` comes from ``log_softmax``; ``alpha_c`` is taken over the classes present
in the truth only (:func:`class_weights`); sums run over the whole batch, or per scan
(``dice_per="scan"``); a class absent from both the truth and the prediction has a Dice score of exactly
1 and no gradient (:func:`dice_loss`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

DICE_EPS = 1e-6     # epsilon in the Dice numerator and denominator (paper value)
ETA_DELTA = 1e-8    # delta in eta = Dice / (Focal + delta) (paper value)
LAMBDA = 0.5        # weight of the Dice term
GAMMA = 2.0         # focal focusing parameter
ALPHA_POWER = 1.0   # alpha_c ~ frequency_c^-ALPHA_POWER (1: inverse class frequency, the paper)
DICE_PER = ("batch", "scan")   # Dice summed over the whole batch (the paper), or per scan and averaged


@dataclass
class ImagingLoss:
    """Loss terms of one batch (0-d float32 tensors). ``total`` carries the gradient."""

    total: torch.Tensor
    dice: torch.Tensor
    focal: torch.Tensor
    eta: torch.Tensor


def _one_hot(target: torch.Tensor, n_classes: int) -> torch.Tensor:
    """(B, *S) long codes -> (B, C, *S) float32 one-hot."""
    if target.dtype not in (torch.int64, torch.int32, torch.uint8, torch.int16, torch.int8):
        raise ValueError(f"target must hold integer class codes, got dtype {target.dtype}")
    codes = target.long()
    if codes.numel() and (int(codes.min()) < 0 or int(codes.max()) >= n_classes):
        raise ValueError(f"target codes must lie in 0..{n_classes - 1}")
    return F.one_hot(codes, n_classes).movedim(-1, 1).to(torch.float32)


def class_weights(y: torch.Tensor, power: float = ALPHA_POWER) -> torch.Tensor:
    """alpha_c: inverse class frequency (to ``power``) over the classes present in ``y``, summing to 1.

    ``power`` 1 is the paper's inverse frequency, 0.5 its square root, 0 uniform weights; with eta
    rescaling the focal term only these relative weights matter, and p = 1 makes background errors nearly
    free. An absent class gets alpha 0 (its focal term is 0 anyway), so it cannot blow up the
    normalisation and collapse the other weights.

    Args:
        y: (B, C, *S) one-hot truth.
        power: p in alpha_c ~ count_c^-p (1: inverse frequency; 0: uniform over present classes).

    Returns:
        (C,) float32; 0 for a class absent from ``y``.
    """
    counts = y.transpose(0, 1).reshape(y.shape[1], -1).sum(dim=1)
    present = counts > 0
    inv = torch.where(present, counts.clamp_min(1.0).pow(-float(power)), torch.zeros_like(counts))
    return inv / inv.sum().clamp_min(torch.finfo(torch.float32).tiny)


def dice_loss(probs: torch.Tensor, y: torch.Tensor, eps: float = DICE_EPS,
              per: str = "batch") -> torch.Tensor:
    """Soft multi-class Dice loss.

    Empty-class rule: a class absent from both the truth and the argmax prediction (predicted at a voxel
    where its probability equals the voxel's maximum) scores exactly 1 (the eps/eps limit of the formula)
    with no gradient. A class absent from the truth but predicted keeps the formula, whose score
    eps / (sum_v p_vc + eps) ~ 0 charges the false positives. Per scan, a small inclusion's over-marking
    counts as much as a large one's, where the batch sum lets the batch's largest inclusion outweigh it.

    Args:
        probs: (B, C, *S) float32 class probabilities.
        y: (B, C, *S) float32 one-hot truth.
        eps: smoothing constant in numerator and denominator.
        per: ``"batch"``: sums over the batch and spatial axes together; ``"scan"``: one score per
            scan and class (the empty-class rule applied per scan), averaged.

    Returns:
        0-d float32: 1 - mean over C classes (and scans) of the Dice score.
    """
    if per not in DICE_PER:
        raise ValueError(f"per must be one of {DICE_PER}, got {per!r}")
    n_scans, n_classes = probs.shape[:2]
    if per == "batch":
        p = probs.transpose(0, 1).reshape(1, n_classes, -1)
        t = y.transpose(0, 1).reshape(1, n_classes, -1)
    else:
        p, t = probs.reshape(n_scans, n_classes, -1), y.reshape(n_scans, n_classes, -1)
    inter, p_sum, t_sum = (p * t).sum(dim=2), p.sum(dim=2), t.sum(dim=2)
    score = (2.0 * inter + eps) / (p_sum + t_sum + eps)
    pd = p.detach()
    predicted = (pd >= pd.amax(dim=1, keepdim=True)).any(dim=2)    # class is the (tied) argmax somewhere
    empty = (t_sum == 0) & ~predicted
    score = torch.where(empty, torch.ones_like(score), score)
    return 1.0 - score.mean()


def focal_loss(log_probs: torch.Tensor, y: torch.Tensor, alpha: torch.Tensor,
               gamma: float = GAMMA) -> torch.Tensor:
    """Class-weighted focal loss averaged over all voxels of the batch.

    Args:
        log_probs: (B, C, *S) float32 log-softmax of the logits.
        y: (B, C, *S) one-hot truth.
        alpha: (C,) class weights.
        gamma: focusing parameter (0, or >= 1 so that the gradient at p = 1 stays finite).

    Returns:
        0-d float32.
    """
    if gamma != 0 and gamma < 1:
        raise ValueError(f"gamma must be 0 or >= 1 (got {gamma}); (1 - p)^gamma has an infinite slope at p = "
                         "1")
    n_voxels = y.numel() // y.shape[1]
    # only the true class of each voxel contributes: gather it instead of multiplying by zeros, so that
    # -inf-like log-probabilities of other classes never meet a 0 weight
    true_class = y.argmax(dim=1, keepdim=True)
    log_pt = log_probs.gather(1, true_class).squeeze(1)
    pt = log_pt.exp()
    weight = alpha[true_class.squeeze(1)]
    modulator = (1.0 - pt).clamp_min(0.0) ** gamma if gamma else torch.ones_like(pt)
    return -(weight * modulator * log_pt).sum() / max(n_voxels, 1)


def imaging_loss(logits: torch.Tensor, target: torch.Tensor, lam: float = LAMBDA, gamma: float = GAMMA,
                 eps: float = DICE_EPS, delta: float = ETA_DELTA, alpha_power: float = ALPHA_POWER,
                 dice_per: str = "batch") -> ImagingLoss:
    """lambda Dice + (1 - lambda) eta Focal for a batch of label images or volumes.

    Args:
        logits: (B, C, *S) logits in any floating dtype (upcast to float32 here).
        target: (B, *S) integer class codes 0..C-1.
        lam: weight of the Dice term (lambda).
        gamma: focal focusing parameter.
        eps: Dice smoothing constant.
        delta: eta's denominator guard.
        alpha_power: exponent p of the class weights alpha_c ~ frequency_c^-p.
        dice_per: ``"batch"`` (the paper) or ``"scan"``: see :func:`dice_loss`.

    Returns:
        ImagingLoss with the total (differentiable) and its detached terms.
    """
    if logits.shape[0] != target.shape[0] or logits.shape[2:] != target.shape[1:]:
        raise ValueError(f"logits {tuple(logits.shape)} and target {tuple(target.shape)} disagree; "
                         "expected (B, C, *S) and (B, *S)")
    logits32 = logits.to(torch.float32)
    log_probs = F.log_softmax(logits32, dim=1)
    probs = log_probs.exp()
    y = _one_hot(target, logits.shape[1])
    alpha = class_weights(y, alpha_power)
    dice = dice_loss(probs, y, eps, dice_per)
    focal = focal_loss(log_probs, y, alpha, gamma)
    eta = dice.detach() / (focal.detach() + delta)
    total = lam * dice + (1.0 - lam) * eta * focal
    return ImagingLoss(total=total, dice=dice.detach(), focal=focal.detach(), eta=eta)
