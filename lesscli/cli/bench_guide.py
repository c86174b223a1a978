"""``less bench guide``: closed-loop palpation with the simulator; F1 against the number of touches.

The strategies, the touch pool and the summary row are described in :mod:`lesscli.bench.guide`.
"""

from __future__ import annotations

import click

from lesscli.bench.guide import TEST_INSERTS, GuideBench, run_guide, train_model
from lesscli.cli.common import checked_output, format_option, renamed_option, seed_option


@click.command("guide")
@click.option("--quick", is_flag=True, help="Smaller model, budget and seeds (minutes).")
@click.option("--model", "model_path", type=click.Path(), default=None,
              help="Imaging checkpoint (default: train a small 2D model).")
@renamed_option("--work", "--work-dir", "work", type=click.Path(), default=".less-bench-guide",
                show_default=True, help="Cache folder for the trained model.")
@click.option("--touches", "budget", type=click.IntRange(2), default=None,
              help="Touch budget (default 60, quick 30).")
@click.option("--start", "n_start", type=click.IntRange(1), default=3, show_default=True,
              help="Random first touches.")
@click.option("--seeds", type=click.IntRange(1), default=None, help="Seeds per phantom (default 3, quick 1).")
@click.option("--eval-every", type=click.IntRange(1), default=3, show_default=True,
              help="Score the image every N touches.")
@click.option("--batch", type=click.IntRange(1), default=3, show_default=True,
              help="Guided touches per round.")
@click.option("--plot", "plot_path", type=click.Path(), default=None, callback=checked_output(),
              help="F1 vs touches PNG.")
@seed_option()
@format_option()
def cli(quick, model_path, work, budget, n_start, seeds, eval_every, batch, plot_path, seed, fmt) -> None:
    """Closed loop: F1 vs touches for guided, raster and random touch order (3 held-out phantoms)."""
    from lesscli.io.records import emit_records

    bench = GuideBench(budget=budget or (30 if quick else 60), start=n_start,
                       seeds=seeds or (1 if quick else 3), eval_every=eval_every, batch=batch, seed=seed)
    rows, means = run_guide(model_path or train_model(work, quick, seed), bench)
    if plot_path:
        from lesscli.plots.sweeps import touches_figure

        touches_figure(plot_path, means, f"{len(TEST_INSERTS)} phantoms x {bench.seeds} seeds")
    emit_records(rows, fmt)
