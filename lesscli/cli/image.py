"""``less image fit|predict``: train an image decoder on a representation (or calibrate the force-map
reference); predict label images."""

from __future__ import annotations

import click

from lesscli.cli.common import (
    Group,
    checked_output,
    device_option,
    format_option,
    labelling_options,
    output_option,
    threads_option,
)
from lesscli.cli.training import training_options


@click.group("image", cls=Group)
def cli() -> None:
    """Tactile imaging: 2D/3D label images with per-pixel uncertainty."""


@cli.command("fit")
@click.argument("data", type=click.Path())
@click.option("--model", "model", type=click.Choice(["less", "forcemap"]), default="less", show_default=True,
              help="less: a learned decoder on --rep; forcemap: calibrate the classical force-map reference.")
@click.option("--rep", "rep_path", type=click.Path(), default=None,
              help="Representation checkpoint from 'less pretrain' (required for learned models).")
@output_option(help="Best imaging checkpoint (.pt); beside it <stem>.last.pt (--resume) and "
                    "<stem>.log.jsonl.",
               lock=True)
@click.option("--val", "val_path", type=click.Path(), default=None,
              help="Validation scan set: selects the best epoch.")
@click.option("--select", type=click.Choice(["f1", "loss"]), default=None,
              help="Best epoch on --val by inclusion F1 (ties: loss) or by loss.  [default: f1]")
@click.option("--dim", type=click.Choice(["2", "3"]), default=None,
              help="2: slice image, 3: volume.  [default: 3]")
@click.option("--finetune", is_flag=True, default=None,
              help="Train the representation too (default: frozen).")
@click.option("--slice", "slice_index", type=int, default=None,
              help="2D: label slice index (default: through the inclusion centre).")
@click.option("--decoder", default=None, help="patch or global (default: pairs with the encoder).")
@training_options("300, the paper's (hours on a CPU at paper size; --epochs 5 for a first look)",
                  "[image], [train], [loss]", "--set image.width=64 --set loss.gamma=1")
@format_option()
def fit_cmd(data, model, rep_path, output, val_path, select, dim, finetune, slice_index, decoder, fmt,
            **train_opts) -> None:
    """Fit an image decoder on DATA's label volumes with the Dice-Focal loss.

    The representation (--rep) is frozen unless --finetune; its normalisation statistics are
    reused. 3D targets are the label volumes; 2D targets are the slice through the inclusion
    centre (or --slice). The best epoch is chosen on --val by its inclusion F1, ties broken by the
    loss (--select loss: by the loss alone; without --val: the training loss). Under torchrun
    the same command trains with DistributedDataParallel; rank 0 writes. A summary record goes to
    stdout.

    --model forcemap calibrates the classical force-map imager instead (smoothing width, threshold,
    size and depth rules, class prior; docs/guide/training.md), the reference for learned results.

    Example: less image fit split/train.npz --val split/val.npz --rep rep.pt -o imager.pt --dim 3
    """
    if model == "forcemap":
        return _fit_forcemap(data, output, dim, slice_index, fmt, rep=rep_path, val=val_path,
                             finetune=finetune, decoder=decoder, select=select, resume=train_opts["resume"],
                             tensorboard=train_opts["tensorboard"])
    if not rep_path:
        raise click.UsageError("--rep is required for learned models (--model less)")
    from lesscli.cli.training import train_and_emit, training_config
    from lesscli.train.image_fit import ImageFitConfig, check_config, fit_imager

    explicit = {"image.dim": int(dim) if dim else None, "image.finetune": finetune,
                "image.slice": slice_index, "image.select": select, "image.decoder": decoder}
    cfg = training_config(ImageFitConfig, explicit, train_opts, check_config,
                          {"image.dim": "--dim", "image.slice": "--slice", "image.select": "--select",
                           "image.decoder": "--decoder"})
    resume = train_opts["resume"]
    train_and_emit(lambda train, val,
                   **kw: fit_imager(train, val, rep_path, cfg, output, resume=resume, **kw), data, val_path,
                   cfg, output, fmt, train_opts)


def _fit_forcemap(data, output, dim, slice_index, fmt, **learned_only) -> None:
    from lesscli.cli.common import print_config_requested

    given = [f"--{k}" for k, v in learned_only.items() if v] + ["--print-config"] * print_config_requested()
    if given:
        raise click.UsageError(f"{', '.join(given)} only apply to learned models, not --model forcemap")
    from lesscli.cli.common import emit_summary
    from lesscli.io.scans import append_history
    from lesscli.train.forcemap_fit import fit_forcemap
    from lesscli.train.run import training_scans

    history = append_history({})["history"]
    emit_summary([fit_forcemap(training_scans(data), output, int(dim or 3), slice_index, data, history)],
                 output, fmt)


@cli.command("predict")
@click.argument("model", type=click.Path())
@click.argument("data", type=click.Path())
@output_option(help="Prediction file (less.pred/1 .npz; '-' for stdout).", lock=True)
@labelling_options()
@click.option("--steps", type=click.IntRange(min=1), default=None,
              help="Image N evenly spaced prefixes of each scan's sequence.")
@click.option("--every", type=click.IntRange(min=1), default=None,
              help="Image every K-th prefix (and the whole).")
@click.option("--grow", is_flag=True, help="Extend the particle grid over larger label grids (same spacing).")
@click.option("--slice", "slice_index", type=int, default=None, help="2D: label slice (default: as trained).")
@click.option("--nifti", "nifti_dir", type=click.Path(), default=None, callback=checked_output(folder=True),
              help="Also write label and entropy NIfTI volumes here.")
@click.option("--batch-size", type=click.IntRange(min=1), default=4, show_default=True,
              help="Scans imaged together (memory against speed).")
@click.option("--turns", type=click.Choice(["1", "2", "4"]), default="1", show_default=True,
              help="Average the images of the scan turned by each half (2) or quarter (4) turn about the "
                   "insert's axis (learned imagers; that many times the time).")
@device_option()
@threads_option()
@format_option()
def predict_cmd(model, data, output, threshold, min_volume_mm3, smooth_mm, steps, every, grow, slice_index,
                nifti_dir, batch_size, turns, device, threads, fmt) -> None:
    """Predict label images of every scan in DATA with an imaging checkpoint MODEL.

    Per scan: class probabilities, labels, per-pixel Shannon entropy (nats), the truth when DATA
    has labels, and geometry. A summary record goes to stdout (unless -o -).

    Example: less image predict imager.pt split/test.npz -o pred.npz --steps 5
    """
    if steps and every:
        raise click.UsageError("--steps and --every are exclusive")
    import time

    import numpy as np

    from lesscli.cli.common import emit_summary, progress
    from lesscli.infer.predict import PredictOptions, predict_file, write_nifti
    from lesscli.io.atomic import atomic_group
    from lesscli.io.predictions import save_predictions
    from lesscli.io.scans import append_history
    from lesscli.threads import apply_threads, deterministic_kernels
    from lesscli.train.distributed import resolve_device

    t0 = time.perf_counter()
    n_threads = apply_threads("throughput", override=threads)     # whole scans in batches
    opts = PredictOptions(threshold=threshold, steps=steps, every=every, grow=grow, batch_size=batch_size,
                          slice_index=slice_index, min_volume_mm3=min_volume_mm3, smooth_mm=smooth_mm,
                          turns=int(turns))
    dev = resolve_device(device)
    deterministic_kernels(dev)
    preds, ckpt, scans = predict_file(model, data, opts, dev, progress=progress)
    preds.meta.update({"imager": model, "set": data,
                       "history": append_history({"history": [
        h for h in ckpt.get("history", []) if "epoch" not in h]})["history"]})
    with atomic_group():                 # the prediction file and its NIfTI volumes appear together, or none
        save_predictions(output, preds)
        paths = write_nifti(preds, nifti_dir) if nifti_dir else []
    summary = {"output": output, "scans": scans.n_scans, "predictions": len(preds.scans),
               "dim": preds.meta["dim"], "particles": preds.meta["particles"],
               "mean_entropy_nats": float(np.mean([p.entropy.mean() for p in preds.scans])) if preds.scans
               else None,
               "nifti_files": len(paths), "threads": n_threads, "seconds": round(time.perf_counter() - t0, 2)}
    emit_summary([summary], output, fmt)
