"""``less plot log RUN.log.jsonl ... -o curves.png``: training curves of runs, overlaid and labelled."""

from __future__ import annotations

import click

from lesscli.cli.common import Group, checked_figure, format_option


@click.group("plot", cls=Group)
def cli() -> None:
    """Figures from the files other commands write."""


@cli.command("log")
@click.argument("logs", nargs=-1, required=True, type=click.Path(dir_okay=False), metavar="RUN.log.jsonl...")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), callback=checked_figure,
              help="Figure to write, in the format its extension names: .png, .pdf or .svg ('-': PNG on "
                   "stdout).")
@click.option("--label", "labels", multiple=True, metavar="NAME",
              help="Name of each run in the legend, in the order of the logs (default: the path without "
                   ".log.jsonl).")
@format_option()
def log_cmd(logs: tuple[str, ...], output: str, labels: tuple[str, ...], fmt: str | None) -> None:
    """Training and validation curves of one or more runs (the <stem>.log.jsonl beside a checkpoint).

    Panels, for what the logs hold: loss (training solid, validation dashed), the validation force
    error against the predict-the-mean baseline (pretrain with --val), and the validation imaging F1
    of the inclusion (image fit). Runs are overlaid, one colour each, so the seeds of an experiment
    compare in one picture. One summary record per run goes to stdout (epochs, last training loss,
    best validation loss, F1 and force ratio; to stderr with -o -).

    Example: less plot log runs/rep_s0.log.jsonl runs/rep_s1.log.jsonl -o curves.pdf
    """
    from lesscli.cli.common import emit_summary
    from lesscli.plots.curves import plot_logs

    emit_summary(plot_logs(logs, output, labels), output, fmt)
