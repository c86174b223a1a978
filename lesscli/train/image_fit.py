"""Fit an image decoder (2D or 3D) on a pretrained representation with the Dice-Focal loss.

The representation's encoder and normalisation statistics are reused unchanged; by default the
encoder is frozen (``finetune`` trains both). Training goes through the shared loop
(:func:`lesscli.train.loop.fit`): validation, best checkpoint, resume, NaN guard, JSON-lines log,
torchrun. The checkpoint keeps the encoder under ``encoder.*`` and its config under
``config["encoder"]``, so ``load_representation`` opens an imaging checkpoint too. With a frozen
encoder its states are computed once per scan and only the decoder runs in the epochs
(:mod:`lesscli.train.state_cache`); the training is the same up to float round-off.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from lesscli.data.compat import check_match, model_signature, signature
from lesscli.data.image_labels import AUTO_SLICE, ImageDataset, collate_images, training_targets
from lesscli.io.checkpoint import load_checkpoint, save_checkpoint
from lesscli.io.labels import INCLUSION, N_CLASSES
from lesscli.io.predictions import Labelling
from lesscli.io.scans import ScanSet
from lesscli.models.imager import DECODERS, DEFAULT_DECODER, Imager, grid_to_dict
from lesscli.models.imaging_loss import ALPHA_POWER, DICE_PER, GAMMA, LAMBDA, imaging_loss
from lesscli.models.registry import build_decoder, lookup
from lesscli.train import distributed
from lesscli.train.config import LoopConfig, SettingError, check_rules, to_dict
from lesscli.train.loop import FitResult, data_identity, fit
from lesscli.train.representation import load_representation
from lesscli.train.state_cache import CachedImager, cache_states, collate_states
from lesscli.train.watch import Watch


@dataclass
class ImageModelConfig:
    """Decoder and targets."""

    dim: int = 3                  # 2: image (slice), 3: volume
    # patch | global; "" pairs with the encoder (less -> patch, global -> global)
    decoder: str = ""
    width: int = 32               # channels of the decoder's first feature map (docs/guide/training.md)
    patch_px: int = 32            # patch side in label pixels (4 * 2^k, k >= 1)
    stitch: str = "sum"           # overlapping patch logits: sum (paper) or mean
    context: int = 0              # k x k convolution over the particle grid before decoding (odd; 0: none)
    finetune: bool = False        # train the representation too
    encoder_lr: float | None = None  # with finetune: the representation's learning rate; None: train.lr
    slice: int = AUTO_SLICE       # 2D label slice; -1 = through the inclusion centre
    select: str = "f1"            # best epoch on --val: inclusion "f1" (ties: loss) or "loss"
    threshold: float | None = None  # inclusion only above this probability at predict; None: chosen on --val
    min_volume_mm3: float | None = None  # smaller inclusion regions dropped at predict; None: chosen on --val
    # labels from probabilities smoothed across each slice (mm); None: chosen on --val
    smooth_mm: float | None = None


@dataclass
class LossConfig:
    lam: float = LAMBDA
    gamma: float = GAMMA
    alpha_power: float = ALPHA_POWER   # class weights ~ frequency^-p: 1 inverse (paper), 0.5 sqrt, 0 uniform
    dice_per: str = "batch"            # Dice over the whole batch (paper) or per scan, averaged


@dataclass
class ImageFitConfig:
    image: ImageModelConfig = field(default_factory=ImageModelConfig)
    train: LoopConfig = field(default_factory=lambda: LoopConfig(epochs=300))
    loss: LossConfig = field(default_factory=LossConfig)


_RULES = [("image.dim", lambda v: v in (2, 3), "2 or 3"), ("image.width", lambda v: v >= 8, ">= 8"),
          ("image.patch_px", lambda v: v >= 8 and (v // 4) & (v // 4 - 1) == 0 and v % 4 == 0,
           "8, 16, 32, ..."),
          ("image.stitch", lambda v: v in ("sum", "mean"), "sum or mean"),
          ("image.context", lambda v: v == 0 or (v > 0 and v % 2 == 1), "0 or odd"),
          ("image.select", lambda v: v in ("f1", "loss"), "f1 or loss"),
          ("loss.lam", lambda v: 0 <= v <= 1, "in [0, 1]"),
          ("loss.gamma", lambda v: v == 0 or v >= 1, "0 or >= 1"),
          ("loss.alpha_power", lambda v: 0 <= v <= 2, "in [0, 2]"),
          ("loss.dice_per", lambda v: v in DICE_PER, " or ".join(DICE_PER)),
          ("image.min_volume_mm3", lambda v: v is None or v >= 0, "unset or >= 0"),
          ("image.smooth_mm", lambda v: v is None or v >= 0, "unset or >= 0"),
          ("train.epochs", lambda v: v >= 1, ">= 1"), ("train.batch_size", lambda v: v >= 1, ">= 1"),
          ("train.lr", lambda v: v > 0, "> 0"),
          ("image.encoder_lr", lambda v: v is None or v > 0, "unset or > 0")]


def check_config(cfg: ImageFitConfig) -> ImageFitConfig:
    """Raise LessError naming the first out-of-range setting."""
    check_rules(cfg, _RULES)
    if cfg.image.decoder and cfg.image.decoder not in DECODERS:
        raise SettingError("image.decoder", cfg.image.decoder, f"one of {', '.join(sorted(DECODERS))} "
                           "(or unset: the encoder's own)")
    if cfg.image.encoder_lr is not None and not cfg.image.finetune:
        raise SettingError("image.encoder_lr", cfg.image.encoder_lr,
                           "unset unless --finetune trains the representation")
    return cfg


def decoder_settings(cfg: ImageFitConfig, encoder_name: str, d_z: int, grid) -> dict:
    """Name and constructor arguments of the decoder for this encoder and grid."""
    image = cfg.image
    name = image.decoder or DEFAULT_DECODER.get(encoder_name, "patch")
    common = {"d_z": int(d_z), "n_classes": N_CLASSES, "dim": image.dim, "width": image.width}
    extra = lookup(DECODERS, name, "decoder").grid_settings(grid, image.patch_px, image.stitch, image.context)
    return {"name": name, **common, **extra}


def _loss(logits: torch.Tensor, target: torch.Tensor, cfg: LossConfig) -> torch.Tensor:
    return imaging_loss(logits, target, lam=cfg.lam, gamma=cfg.gamma, alpha_power=cfg.alpha_power,
                        dice_per=cfg.dice_per).total


def image_loss_fn(cfg: LossConfig):
    """Loss callable for the loop: forward the inputs, score the logits against the targets."""
    def loss_fn(model, batch, generator) -> torch.Tensor:
        return _loss(model(batch.inputs), batch.target, cfg)
    return loss_fn


def _f1(tp: int, fp: int, fn: int) -> float:
    return 2 * tp / (2 * tp + fp + fn) if tp + fp + fn else float("nan")


def validation_pass(model: torch.nn.Module, loader, device: torch.device, cfg: LossConfig) -> dict:
    """One pass: mean loss (weighted by batch size), micro inclusion F1 (argmax) and its counts."""
    total, n, tp, fp, fn = 0.0, 0, 0, 0, 0
    for batch in loader:
        batch = batch.to(device)
        logits = model(batch.inputs)
        total += float(_loss(logits, batch.target, cfg)) * batch.size
        n += batch.size
        pred, true = logits.argmax(dim=1) == INCLUSION, batch.target == INCLUSION
        tp += int((pred & true).sum())
        fp += int((pred & ~true).sum())
        fn += int((~pred & true).sum())
    return {"loss": total / max(1, n), "inclusion_f1": _f1(tp, fp, fn), "true_inclusion": tp + fn > 0}


def image_val_fn(cfg: LossConfig, by_f1: bool):
    """The loop's validation: loss and, when ``by_f1``, the inclusion F1 as the score (one pass)."""
    def val_fn(model, loader, device) -> tuple[float, float | None]:
        out = validation_pass(model, loader, device, cfg)
        return out["loss"], out["inclusion_f1"] if by_f1 else None
    return val_fn


def inclusion_f1(model: torch.nn.Module, dataset, batch_size: int, device: torch.device, cfg: LossConfig,
                 collate_fn: Callable = collate_images) -> dict:
    """Micro inclusion F1 (argmax labels) over a dataset, and the F1 of predicting no inclusion (0)."""
    loader = torch.utils.data.DataLoader(dataset, batch_size=batch_size, collate_fn=collate_fn)
    model = model.to(device).eval()
    with torch.no_grad():
        out = validation_pass(model, loader, device, cfg)
    return {"inclusion_f1": out["inclusion_f1"],
            "no_inclusion_f1": 0.0 if out["true_inclusion"] else float("nan")}


# Labelling rules tried on the validation set. The best micro inclusion F1 wins; rules within
# LABEL_F1_TOLERANCE of it (below the F1's scatter between validation draws) are told apart by their
# sizing: the smallest mean diameter error (ties: the least smoothing, the lowest threshold, then the
# largest minimum volume, since regions the validation scans cannot tell apart are specks, not
# inclusions). None: argmax; thresholds below 0.5 label a class that is likely but not the likeliest, so an
# unsure model is not forced to predict nothing; 0 mm^3: no region rule; 0 mm: no smoothing. The smoothing
# widths (one to
# five pixels of the label grids, 0.48-0.95 mm) even out patch seams and single-pixel spurs; much wider
# ones would round off the smallest inclusions (docs/results/sizing.md).
THRESHOLD_CHOICES = (None, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
MIN_VOLUME_CHOICES_MM3 = (0.0, 50.0, 100.0, 150.0)
SMOOTH_CHOICES_MM = (0.0, 1.0, 1.5, 2.0, 2.5)
LABEL_F1_TOLERANCE = 0.01


def _diameter_or_zero(mask: np.ndarray, spacing_mm) -> float:
    """Inclusion diameter (:func:`lesscli.metrics.diameter_mm`, mm) of a 2D/3D mask; 0 when empty, so
    that a missed inclusion costs its true diameter and a false one its own."""
    from lesscli.metrics import diameter_mm

    d = diameter_mm(mask.reshape((-1, *mask.shape[-2:])), np.asarray(spacing_mm, float))
    return 0.0 if d is None else d


def _menu_masks(probs: np.ndarray, choices: list, spacing_mm):
    """The inclusion mask of every (smoothing, threshold, minimum volume) rule in ``choices``, in order
    (smoothing-major), each step computed once per smoothing and threshold: the masks of
    :func:`~lesscli.io.predictions.labels_from_probs`, rule by rule."""
    from lesscli.io.predictions import drop_specks, smoothed, thresholded

    cache: dict = {}
    for sm, th, mv in choices:
        if sm not in cache:
            smooth = smoothed(probs, sm, spacing_mm)
            cache.clear()
            cache[sm] = (smooth, smooth[:2].argmax(axis=0).astype(np.uint8), {})
        smooth, tissue, by_threshold = cache[sm]
        if th not in by_threshold:
            by_threshold[th] = thresholded(smooth, th, tissue)
        yield drop_specks(by_threshold[th], tissue, mv, spacing_mm) == INCLUSION


def _tie_order(choice: tuple) -> tuple[float, float, float]:
    """Sort key of a (smooth_mm, threshold, min_volume_mm3) choice among equals: the least smoothing, the
    lowest threshold (None, the argmax, lowest of all), then the largest minimum volume."""
    smooth_mm, threshold, min_volume = choice
    return float(smooth_mm), -math.inf if threshold is None else float(threshold), -float(min_volume)


def choose_labelling(model: torch.nn.Module, dataset, batch_size: int, device: torch.device, spacing_mm,
                     collate_fn: Callable = collate_images, thresholds=THRESHOLD_CHOICES,
                     volumes=MIN_VOLUME_CHOICES_MM3, smooths=SMOOTH_CHOICES_MM,
                     tolerance: float = LABEL_F1_TOLERANCE) -> tuple[Labelling, dict, dict]:
    """The labelling rule (smoothing, threshold, minimum inclusion volume) that labels ``dataset`` best.

    Every combination of ``smooths`` x ``thresholds`` x ``volumes`` labels the validation volumes
    with :func:`~lesscli.io.predictions.labels_from_probs`, the rule ``less image predict`` applies.
    The one with the best micro F1 wins, unless others within ``tolerance`` of it size the
    inclusions better: then the one of those with the smallest mean diameter error over the scans
    (an empty mask has diameter 0) does; ties go to the least smoothing, the lowest threshold, then
    the largest minimum volume.

    Returns:
        (the rule, {str(smooth_mm): {str(threshold): {str(min_volume_mm3): F1}}}, the same table of
        the mean diameter error in mm).
    """
    choices = [(sm, th, float(mv)) for sm in smooths for th in thresholds for mv in volumes]
    counts = np.zeros((len(choices), 3), dtype=np.int64)                       # tp, fp, fn
    diameter_errors: list[list[float]] = [[] for _ in choices]
    loader = torch.utils.data.DataLoader(dataset, batch_size=batch_size, collate_fn=collate_fn)
    model = model.to(device).eval()
    with torch.no_grad():
        for batch in loader:
            batch = batch.to(device)
            probs = torch.softmax(model(batch.inputs).float(), dim=1).cpu().numpy()
            for p, target in zip(probs, batch.target.cpu().numpy()):
                true = target == INCLUSION
                true_diameter = _diameter_or_zero(true, spacing_mm)
                # rules often give the same mask: measure it once
                diameters: dict[bytes, float] = {}
                for i, pred in enumerate(_menu_masks(p, choices, spacing_mm)):
                    counts[i] += ((pred & true).sum(), (pred & ~true).sum(), (~pred & true).sum())
                    key = np.packbits(pred).tobytes()
                    if key not in diameters:
                        diameters[key] = _diameter_or_zero(pred, spacing_mm)
                    diameter_errors[i].append(abs(diameters[key] - true_diameter))
    scores = [_f1(*map(int, c)) for c in counts]
    sizing = [float(np.mean(e)) if e else float("nan") for e in diameter_errors]
    ranked = [-1.0 if np.isnan(f) else f for f in scores]
    near = [i for i, f in enumerate(ranked) if f >= max(ranked) - tolerance]
    best = min(near,
               key=lambda i: (float("inf") if np.isnan(sizing[i]) else sizing[i], *_tie_order(choices[i])))

    def table(values):
        return {f"{sm:g}": {str(th): {f"{mv:g}": v for (s_, t, mv),
                                      v in zip(choices, values) if (s_, t) == (sm, th)}
                            for th in thresholds} for sm in smooths}
    smooth_mm, threshold, min_volume = choices[best]
    return Labelling(threshold, min_volume, float(smooth_mm)), table(scores), table(sizing)


@dataclass
class FitInputs:
    """What the training loop runs on: the model, its data sets and how batches are collated."""

    model: torch.nn.Module
    train_set: object
    val_set: object | None
    collate: Callable


def fit_inputs(model: Imager, train_set: ImageDataset, val_set: ImageDataset | None, batch_size: int,
               device: torch.device, cache: bool) -> FitInputs:
    """The loop's inputs: cached encoder states (and a model that reads them) when ``cache``."""
    if not cache:
        return FitInputs(model, train_set, val_set, collate_images)
    cached_val = cache_states(model, val_set, batch_size, device) if val_set is not None else None
    return FitInputs(CachedImager(model), cache_states(model, train_set, batch_size, device), cached_val,
                     collate_states)


def fit_imager(train: ScanSet, val: ScanSet | None, rep_path: str, cfg: ImageFitConfig, output: str, *,
               env: distributed.DistEnv | None = None, resume: bool = False, history: list | None = None,
               watch: Watch | None = None, names: tuple[str, str] = ("train", "val"),
               cache: bool = True) -> dict:
    """Train an imaging model on ``train`` (best by ``val``) and write it to ``output``.

    ``cache`` (frozen encoder only) computes the encoder's states once per scan instead of
    in every epoch; ``False`` re-runs the encoder per batch (same training up to round-off).

    Returns:
        A summary record (epochs, best epoch and loss, validation inclusion F1 when ``val`` is given).
    """
    env = env or distributed.DistEnv()
    check_config(cfg)
    t0 = time.perf_counter()
    encoder, rep = load_representation(rep_path, map_location="cpu")
    check_match(model_signature(rep), train, rep_path, names[0])
    stats = {**rep["norm_stats"], "data": signature(train)}      # the frame the imager is fitted in
    targets, grid = training_targets(train, cfg.image.dim, cfg.image.slice, names[0])
    train_set = ImageDataset(train, stats, targets, names[0])
    val_set, by_f1 = None, False
    if val is not None and val.n_scans:
        val_targets, _ = training_targets(val, cfg.image.dim, cfg.image.slice, names[1])
        val_set = ImageDataset(val, stats, val_targets, names[1])
        by_f1 = cfg.image.select == "f1" and any(bool((t == INCLUSION).any()) for t in val_targets)
    enc_cfg = encoder.config()
    dec = decoder_settings(cfg, enc_cfg["name"], encoder.dim, grid)
    model = Imager(encoder, build_decoder(dec, cfg.train.seed), grid, frozen=not cfg.image.finetune,
                   encoder_lr=cfg.image.encoder_lr)
    config = {**to_dict(cfg), "encoder": enc_cfg, "decoder": dec, "grid": grid_to_dict(grid),
              "representation": {"path": rep_path, "config": rep.get("config", {})}}
    inputs = fit_inputs(model, train_set, val_set, cfg.train.batch_size, env.device,
                        cache and not cfg.image.finetune)
    model, train_set, val_set, collate = inputs.model, inputs.train_set, inputs.val_set, inputs.collate
    result: FitResult = fit(model, image_loss_fn(cfg.loss), train_set, val_set, cfg.train,
                            collate_fn=collate, output=output, config=config, norm_stats=stats, env=env,
                            resume=resume, history=[*(h for h in rep.get("history", []) if "epoch" not in h),
                                                    *(history or [])],
                            watch=watch, val_fn=image_val_fn(cfg.loss, by_f1),
                            data=data_identity(train, stats, names[0]))
    summary = {"output": output, "dim": cfg.image.dim, "decoder": dec["name"], "encoder": enc_cfg["name"],
               "frozen": not cfg.image.finetune, "trainable_parameters": sum(
                   p.numel() for p in model.parameters() if p.requires_grad),
               "epochs": cfg.train.epochs, "best_epoch": result.best_epoch + 1, "best_loss": result.best_loss,
               "selected_by": "val_f1" if by_f1 else "val_loss" if val_set is not None else "train_loss"}
    if val_set is not None and result.best_state is not None:
        model.load_state_dict(result.best_state)
        summary.update({f"val_{k}": v for k, v in
                        inclusion_f1(model, val_set, cfg.train.batch_size, env.device, cfg.loss,
                                     collate).items()})
        image = cfg.image
        if by_f1 and None in (image.threshold, image.min_volume_mm3, image.smooth_mm) and env.is_main:
            labelling, scores, sizing = choose_labelling(
                model, val_set, cfg.train.batch_size, env.device, grid.spacing_mm, collate,
                THRESHOLD_CHOICES if image.threshold is None else (image.threshold,),
                MIN_VOLUME_CHOICES_MM3 if image.min_volume_mm3 is None else (image.min_volume_mm3,),
                SMOOTH_CHOICES_MM if image.smooth_mm is None else (image.smooth_mm,))
            store_labelling(output, labelling)
            summary.update({**labelling.to_dict(), "val_f1_by_labelling": scores,
                            "val_diameter_error_mm_by_labelling": sizing})
    summary["seconds"] = round(time.perf_counter() - t0, 2)
    return summary



def store_labelling(path: str, labelling: Labelling) -> None:
    """Record the chosen labelling rule in the imaging checkpoint's ``config['image']``."""
    ckpt = load_checkpoint(path)
    ckpt["config"]["image"].update(labelling.to_dict())
    save_checkpoint(path, ckpt["model_state"], ckpt["config"], ckpt["norm_stats"], ckpt["history"],
                    ckpt.get("extra"))
