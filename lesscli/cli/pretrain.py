"""``less pretrain DATA -o rep.pt``: self-supervised force-prediction pretraining (LESS or GLOBAL)."""

from __future__ import annotations

import click

from lesscli.cli.common import format_option, output_option


@click.command("pretrain")
@click.argument("data")
@output_option(help="Best checkpoint (.pt); beside it <stem>.last.pt (for --resume) and <stem>.log.jsonl.")
@click.option("--val", "val_path", default=None, help="Validation scan set: selects the best epoch.")
@click.option("--model", "model_name", default=None, help="Encoder: less (particles) or global.  [default: less]")
@click.option("--receptive-field-mm", type=float, default=None, help="Receptive-field radius.  [default: 10]")
@click.option("--spacing-mm", type=float, default=None, help="Particle spacing.  [default: 6]")
@click.option("--grid-extent-mm", type=float, default=None, help="Side of the particle grid.  [default: 60]")
@click.option("--max-steps", type=int, default=None, help="Cap on steps per particle (0 = none).  [default: 0]")
@click.option("--dim", type=int, default=None, help="State width d_z.  [default: 128; paper: 1024]")
@click.option("--epochs", type=int, default=None, help="Epochs.  [default: 100]")
@click.option("--batch-size", type=int, default=None, help="Scans per batch.  [default: 2]")
@click.option("--lr", type=float, default=None, help="Adam learning rate (cosine decay).  [default: 1e-4]")
@click.option("--seed", type=int, default=None, help="Seed for initialisation and sampling.  [default: 0]")
@click.option("--device", default=None, help="auto, cpu, cuda or cuda:N.  [default: auto]")
@click.option("--config", "config_path", default=None, help="TOML file with [model], [train], [ssl] tables.")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a setting, e.g. --set train.lr=3e-4 --set k_query=8 (repeatable).")
@click.option("--resume", is_flag=True, help="Continue from <stem>.last.pt with the same settings.")
@format_option
def cli(data: str, output: str, val_path: str | None, model_name, receptive_field_mm, spacing_mm, grid_extent_mm,
        max_steps, dim, epochs, batch_size, lr, seed, device, config_path, overrides, resume, fmt) -> None:
    """Pretrain a tactile representation by predicting forces (self-supervised).

    DATA is a scan set (.npz, a directory of shards, or '-'). Normalisation statistics come from
    DATA only and are stored in the checkpoint. The best epoch is chosen by the validation loss
    (--val), or by the training loss when no validation set is given; never by test data. A
    summary record (with the validation force error against predicting the mean) goes to stdout.

    Under torchrun the same command trains with DistributedDataParallel; rank 0 writes.

    Example: less pretrain split/train.npz --val split/val.npz -o rep.pt --epochs 50
    """
    from lesscli.cli.common import LOG, progress
    from lesscli.io.records import emit_records
    from lesscli.io.scans import append_history, load_scans
    from lesscli.train import distributed
    from lesscli.train.config import PretrainConfig, load_config
    from lesscli.train.pretrain import pretrain

    explicit = {"model.name": model_name, "model.receptive_field_mm": receptive_field_mm,
                "model.spacing_mm": spacing_mm, "model.grid_extent_mm": grid_extent_mm,
                "model.max_steps_per_particle": max_steps, "model.dim": dim, "train.epochs": epochs,
                "train.batch_size": batch_size, "train.lr": lr, "train.seed": seed, "train.device": device}
    cfg = load_config(PretrainConfig, config_path, overrides, explicit)
    train = load_scans(data)
    val = load_scans(val_path) if val_path else None
    env = distributed.setup(cfg.train.device)
    try:
        history = append_history({}, seed=cfg.train.seed)["history"]
        bar = progress if env.is_main else (lambda it, **_: it)
        summary = pretrain(train, val, cfg, output, env=env, resume=resume, history=history, progress=bar,
                           names=(data, val_path or ""))
    finally:
        distributed.teardown(env)
    if not env.is_main:
        return
    if output == "-":
        LOG.warning("pretrain summary: %s", summary)
    else:
        emit_records([summary], fmt)
