"""``less pretrain DATA -o rep.pt``: self-supervised force-prediction pretraining (LESS or GLOBAL)."""

from __future__ import annotations

import click

from lesscli.cli.common import format_option, output_option
from lesscli.cli.training import training_options

# setting -> the option that sets it (named in a usage error)
FLAGS = {"model.name": "--model", "model.receptive_field_mm": "--receptive-field-mm",
         "model.spacing_mm": "--spacing-mm", "model.grid_extent_mm": "--grid-extent-mm",
         "model.max_steps_per_particle": "--max-steps", "model.dim": "--dim"}


@click.command("pretrain")
@click.argument("data", type=click.Path())
@output_option(help="Best checkpoint (.pt); beside it <stem>.last.pt (for --resume) and <stem>.log.jsonl.",
               lock=True)
@click.option("--val", "val_path", type=click.Path(), default=None,
              help="Validation scan set: selects the best epoch.")
@click.option("--model", "model_name", default=None, metavar="NAME",
              help="Encoder: less or global (the paper's pair: particles, or one state for the whole scan), "
                   "less-taxel or global-taxel (each with a taxel stiffness map).  [default: less]")
@click.option("--receptive-field-mm", type=float, default=None, help="Receptive-field radius.  [default: 10]")
@click.option("--spacing-mm", type=float, default=None, help="Particle spacing.  [default: 6]")
@click.option("--grid-extent-mm", type=float, default=None, help="Side of the particle grid.  [default: 60]")
@click.option("--max-steps", type=int, default=None,
              help="Cap on steps per particle (0 = none).  [default: 0]")
@click.option("--dim", type=int, default=None, help="State width d_z.  [default: 128; paper: 1024]")
@training_options("100, the paper's (hours on a CPU at paper size; --epochs 5 for a first look)",
                  "[model], [train], [ssl]", "--set train.lr=3e-4 --set k_query=8")
@format_option()
def cli(data: str, output: str, val_path: str | None, model_name, receptive_field_mm, spacing_mm,
        grid_extent_mm, max_steps, dim, fmt, **train_opts) -> None:
    """Pretrain a tactile representation by predicting forces (self-supervised).

    DATA is a scan set (.npz, a directory of shards, or '-'). Normalisation statistics come from
    DATA only and are stored in the checkpoint. The best epoch is chosen by the validation loss
    (--val), or by the training loss when no validation set is given; never by test data. A
    summary record (with the validation force error against predicting the mean) goes to stdout.

    Under torchrun the same command trains with DistributedDataParallel; rank 0 writes.

    Example: less pretrain split/train.npz --val split/val.npz -o rep.pt --epochs 50
    """
    from lesscli.cli.training import train_and_emit, training_config
    from lesscli.train.config import PretrainConfig, check_pretrain_config
    from lesscli.train.pretrain import pretrain

    explicit = {"model.name": model_name, "model.receptive_field_mm": receptive_field_mm,
                "model.spacing_mm": spacing_mm, "model.grid_extent_mm": grid_extent_mm,
                "model.max_steps_per_particle": max_steps, "model.dim": dim}
    cfg = training_config(PretrainConfig, explicit, train_opts, check_pretrain_config, FLAGS)
    train_and_emit(lambda train, val,
                   **kw: pretrain(train, val, cfg, output, resume=train_opts["resume"], **kw), data, val_path,
                   cfg, output, fmt, train_opts)
